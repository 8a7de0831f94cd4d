"""Refused WebSocket handshakes are logged at info, not as an error.

The stream route refuses a handshake (no key, rate limit, shutting down, ...) with an HTTP error answer
through ASGI's ``websocket.http.response`` extension. uvicorn's websockets-sansio and wsproto protocols then
see an app that returned with the handshake not completed and log "ASGI callable returned without completing
handshake." at ERROR on ``uvicorn.error``, once per refusal, although the client got its 401/429/503. The
service's route always accepts or refuses (:mod:`service.routes.stream`), so :class:`RefusedHandshakeAtInfo`
turns that one message into an info line saying what happened. uvicorn 0.55 and later no longer log that
error and say "connection rejected (401 Unauthorized)" at info themselves; the filter then finds nothing to do.
"""

from __future__ import annotations

import logging

_UVICORN_MESSAGE = "ASGI callable returned without completing handshake."


class RefusedHandshakeAtInfo(logging.Filter):
    """On ``uvicorn.error``: the refused-handshake message at INFO (dropped when the logger is above INFO)."""

    def __init__(self, logger: logging.Logger) -> None:
        super().__init__()
        self.logger = logger

    def filter(self, record: logging.LogRecord) -> bool:
        if record.msg != _UVICORN_MESSAGE or record.levelno <= logging.INFO:
            return True
        record.levelno, record.levelname = logging.INFO, "INFO"
        record.msg, record.args = "WebSocket handshake refused with an HTTP error answer", None
        return self.logger.isEnabledFor(logging.INFO)


def install_handshake_log() -> None:
    logger = logging.getLogger("uvicorn.error")
    if not any(isinstance(f, RefusedHandshakeAtInfo) for f in logger.filters):
        logger.addFilter(RefusedHandshakeAtInfo(logger))
