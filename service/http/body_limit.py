"""Request body cap: bodies over ``max_body_bytes`` get 413 ``payload_too_large`` before they are parsed."""

from __future__ import annotations

from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.errors import error_response


class _TooLarge(HTTPException):
    """Raised from ``receive``; FastAPI passes HTTP exceptions through its body parsing unchanged."""


def _length(value: bytes) -> int:
    try:
        return int(value)
    except ValueError:
        return -1


class BodyLimitMiddleware:
    """Checks ``Content-Length`` up front and counts streamed (chunked) bodies as they arrive."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.text = (f"the request body exceeds {max_bytes} bytes; send less (e.g. a shorter clip, or register "
                     "the style once with POST /v1/styles and send its style_id)")

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
        elif self._declares_too_much(scope):
            await self._reject(scope, receive, send)
        else:
            await self._counting(scope, receive, send)

    def _declares_too_much(self, scope: Scope) -> bool:
        """A ``Content-Length`` over the cap (one that is not a number is left to the server)."""
        return any(name == b"content-length" and _length(value) > self.max_bytes for name, value in scope.get("headers", ()))

    async def _counting(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Run the app with a ``receive`` that counts the body; 413 if it grows over the cap before a response started."""
        limit = self.max_bytes
        received = 0
        started = False

        async def counting_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise _TooLarge(413, self.text)
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counting_receive, tracking_send)
        except _TooLarge:
            if started:
                raise
            await self._reject(scope, receive, send)

    async def _reject(self, scope: Scope, receive: Receive, send: Send) -> None:
        metrics = getattr(getattr(getattr(scope.get("app"), "state", None), "service", None), "metrics", None)
        if metrics is not None:
            metrics.errors.labels("payload_too_large").inc()
        await error_response("payload_too_large", self.text)(scope, receive, send)
