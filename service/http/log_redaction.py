"""API keys never reach a log line: a :class:`logging.Filter` that rewrites every record it sees.

uvicorn logs each WebSocket handshake (at info) and, with the access log on, every request line with its
query string, so a client's ``?token=KEY`` would be written in plain text. :class:`RedactKeys` replaces, in a
record's message and in its string fields, ``token=...`` query values, ``X-API-Key`` / ``Authorization``
header values and every configured key (:func:`redact_keys`) with ``[redacted]``.

Percent-encoding hides nothing: the server decodes query names and values before it reads ``token``, so a
query pair whose name decodes to ``token`` (``?%74oken=%6b%65%79...``) has its value redacted however it is
spelled, and any run of text that decodes (once or more) to something holding a configured key is redacted
whole.

It is installed on the handlers :func:`service.http.logs.log_config` configures (``rsmt serve``), on the
handlers :func:`service.http.logs.ensure_service_logging` adds, and by :func:`install_redaction` on uvicorn's
own loggers and handlers (plain ``uvicorn --factory``).
"""

from __future__ import annotations

import logging
import re
from urllib.parse import unquote, unquote_plus

REDACTED = "[redacted]"
_PATTERNS = (
    re.compile(r"(?i)([?&;]token=)[^&\s\"'#]+"),
    re.compile(r"(?i)((?:x-api-key|authorization)[\"']?\s*[:=,]\s*[\"']?(?:bearer\s+)?)[^\s\"',)]+"),
)
#: One query pair (``?name=value``, ``&name=value``) as it appears in a logged URL, still percent-encoded.
_QUERY_PAIR = re.compile(r"([?&;])([^=&;?#\s\"']*)=([^&;#\s\"']*)")
#: A run of text that holds a percent-escape (a path or query part, a header value): decoded before the key check.
_ENCODED_RUN = re.compile(r"[^\s\"'?&=;/,()]*%[0-9A-Fa-f]{2}[^\s\"'?&=;/,()]*")
_keys: set[str] = set()


def redact_keys(keys: list[str]) -> None:
    """Also replace each of ``keys`` (the configured API keys), wherever it appears."""
    _keys.update(k for k in keys if k)


def redact(text: str) -> str:
    for pattern in _PATTERNS:
        text = pattern.sub(lambda m: m.group(1) + REDACTED, text)
    if "=" in text:
        text = _QUERY_PAIR.sub(_redact_pair, text)
    for key in _keys:
        if key in text:
            text = text.replace(key, REDACTED)
    if "%" in text and _keys:
        text = _ENCODED_RUN.sub(lambda m: REDACTED if _holds_key(_decoded(m.group(0))) else m.group(0), text)
    return text


def _decoded(text: str, plus: bool = False) -> str:
    """``text`` percent-decoded until it no longer changes (a few rounds: a doubly encoded key is a key too)."""
    for _ in range(4):
        clean = unquote_plus(text) if plus else unquote(text)
        if clean == text:
            break
        text = clean
    return text


def _holds_key(text: str) -> bool:
    return any(key in text for key in _keys)


def _redact_pair(match: re.Match[str]) -> str:
    """A query pair with its value redacted when its name decodes to ``token`` or its value to a key."""
    lead, name, value = match.group(1), match.group(2), match.group(3)
    if value == REDACTED or not ("%" in name or "+" in name or "%" in value or "+" in value):
        return match.group(0)  # a plain pair: the patterns and the key replacement see it as it is
    if _decoded(name, plus=True).strip().lower() == "token" or _holds_key(_decoded(value, plus=True)):
        return f"{lead}{name}={REDACTED}"
    return match.group(0)


class RedactKeys(logging.Filter):
    """Rewrites a record's message (its arguments merged in) and string fields without keys; drops nothing."""

    def filter(self, record: logging.LogRecord) -> bool:
        try:
            message = record.getMessage()
        except Exception:  # a malformed record is logging's to report, not ours
            return True
        clean = redact(message)
        if clean != message or record.args:
            record.msg, record.args = clean, None
        for name, value in list(record.__dict__.items()):
            if isinstance(value, str) and name not in ("msg", "name", "levelname", "pathname", "filename", "module",
                                                        "funcName", "processName", "threadName", "taskName"):
                cleaned = redact(value)
                if cleaned != value:
                    setattr(record, name, cleaned)
        return True


_FILTER = RedactKeys()
UVICORN_LOGGERS = ("uvicorn", "uvicorn.error", "uvicorn.access", "uvicorn.asgi")


def install_redaction(keys: list[str]) -> None:
    """Redact ``keys`` (and ``token=`` values) in uvicorn's records and on every handler they reach."""
    redact_keys(keys)
    for name in UVICORN_LOGGERS:
        logger = logging.getLogger(name)
        if _FILTER not in logger.filters:
            logger.addFilter(_FILTER)
        for handler in logger.handlers:
            if _FILTER not in handler.filters:
                handler.addFilter(_FILTER)
    for handler in logging.getLogger().handlers:
        if _FILTER not in handler.filters:
            handler.addFilter(_FILTER)


def redaction_filter() -> RedactKeys:
    """The one filter instance (for ``logging.config`` factories)."""
    return _FILTER
