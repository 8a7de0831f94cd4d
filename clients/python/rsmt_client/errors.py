"""Errors the clients raise: every server error keeps its machine ``code`` (docs/protocol.md, Errors)."""

from __future__ import annotations


class RsmtError(Exception):
    """An error from the service or on the way to it.

    Attributes:
        code: the contract's machine code (``rate_limited``, ``unknown_style``, ...), or a client-side
            one: ``connection`` (no connection could be made), ``protocol`` (an unexpected message),
            ``closed`` (the WebSocket closed), ``timeout``, ``message_too_large`` (a WebSocket message
            over the server's ``hello.limits.max_message_bytes``, refused before it was sent).
        message: what went wrong and how to fix it, as the server wrote it.
        status: the HTTP status, when there was one.
        retry_after: seconds the server asked us to wait (``Retry-After``), when it did.
        character, request_id: echoed by WebSocket ``error`` messages.
        close_code: the WebSocket close code, for ``closed``.
    """

    def __init__(self, code: str, message: str, *, status: int | None = None, retry_after: float | None = None,
                 character: str | None = None, request_id: object = None, close_code: int | None = None) -> None:
        super().__init__(f"{code}: {message}" if status is None else f"{status} {code}: {message}")
        self.code = code
        self.message = message
        self.status = status
        self.retry_after = retry_after
        self.character = character
        self.request_id = request_id
        self.close_code = close_code
