"""Structured logging: one JSON object per line (or plain text), quiet (warnings) by default.

One logger speaks at the default level too: ``service.announce``, the service's few lines for a person
(the address, models and viewer once ready; the stop), at info unless the level is ``error``. In text
format they are the bare message; in JSON format an object like any other, with their fields.
"""

from __future__ import annotations

import json
import logging
import time

from service.http.log_redaction import redaction_filter

ANNOUNCE = "service.announce"
TEXT_FORMAT = "%(asctime)s %(levelname)s %(name)s %(message)s"
_STANDARD = set(logging.makeLogRecord({}).__dict__) | {"message", "asctime", "color_message"}


class JsonFormatter(logging.Formatter):
    """``{"ts", "level", "logger", "msg", ...extra fields}``; exceptions go in ``"exc"``."""

    def format(self, record: logging.LogRecord) -> str:
        out = {
            "ts": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created)) + f".{int(record.msecs):03d}Z",
            "level": record.levelname.lower(),
            "logger": record.name,
            "msg": record.getMessage(),
        }
        for key, value in record.__dict__.items():
            if key not in _STANDARD and not key.startswith("_"):
                out[key] = value
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str)


def log_config(level: str = "warning", fmt: str = "json") -> dict:
    """A ``logging.config.dictConfig`` for the service and uvicorn (pass it as uvicorn's ``log_config``)."""
    json_format = {"()": JsonFormatter}
    formatter = json_format if fmt == "json" else {"format": TEXT_FORMAT}
    handler = {"class": "logging.StreamHandler", "formatter": "default", "stream": "ext://sys.stderr",
               "filters": ["redact_keys"]}  # API keys never reach a line (service.http.log_redaction)
    lvl = level.upper()
    return {
        "version": 1,
        "disable_existing_loggers": False,
        "filters": {"redact_keys": {"()": redaction_filter}},
        "formatters": {"default": formatter, "announce": json_format if fmt == "json" else {"format": "%(message)s"}},
        "handlers": {"default": handler, "announce": {**handler, "formatter": "announce"}},
        "loggers": {
            ANNOUNCE: {"handlers": ["announce"], "level": _announce_level(lvl), "propagate": False},
            "service": {"handlers": ["default"], "level": lvl, "propagate": False},
            "model": {"handlers": ["default"], "level": lvl, "propagate": False},
            "uvicorn": {"handlers": ["default"], "level": lvl, "propagate": False},
            "uvicorn.error": {"level": lvl},
            "uvicorn.access": {"handlers": ["default"], "level": lvl, "propagate": False},
        },
    }


def _announce_level(level: str) -> str:
    return "ERROR" if level == "ERROR" else "INFO"


def ensure_service_logging(level: str = "warning", fmt: str = "json") -> None:
    """Give the ``service`` and ``model`` loggers the structured handler when nothing configured them
    (``uvicorn --factory`` configures only its own loggers; ``rsmt serve`` configures all).

    When the root logger already has handlers (an embedding application, or pytest's capture), the
    host's logging setup wins and nothing is changed: stopping propagation there would hide the
    ``model`` logs from it.
    """
    if logging.getLogger().handlers:
        return
    formatter: logging.Formatter = JsonFormatter() if fmt == "json" else logging.Formatter(TEXT_FORMAT)
    for name in ("service", "model"):
        logger = logging.getLogger(name)
        if logger.handlers:
            continue
        handler = logging.StreamHandler()
        handler.setFormatter(formatter)
        handler.addFilter(redaction_filter())
        logger.addHandler(handler)
        logger.setLevel(level.upper())
        logger.propagate = False
