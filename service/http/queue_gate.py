"""Queue gate: a request for model work that would find the work queue full is refused before its body is read.

:class:`~service.work_queue.WorkQueue` refuses a job at once when ``RSMT_QUEUE_LIMIT`` jobs already wait,
but the route only asks it after FastAPI has read, decoded and validated the request body: under a burst
of large bodies, refusing cost the event loop the same parsing as serving. :class:`QueueGateMiddleware`
asks first, from the request line alone, for the routes that queue model work (:data:`GATED`), and answers
503 ``overloaded`` with ``Retry-After`` (or ``shutting_down`` once the queues are closed) in the same JSON
envelope as the queue itself. The route's own check stays: the queue may fill between the two.

The queue only sees a request once its body has been read and validated, so a burst arriving at once
would all find it empty: the gate also counts the requests it has let in whose bodies have arrived and that
are not yet answered, and refuses once they are as many as the queues hold (``RSMT_REQUEST_THREADS`` running
plus ``RSMT_QUEUE_LIMIT`` waiting, summed over the models). A request still sending its body is not counted,
so that clients stalling in their bodies cannot fill the queue without ever reaching it. Which model a
request wants is in its body, so the gate refuses on the queues' own state only when every served model's
queue would refuse (with one model: when its queue is full).

Both counts are per API key, as the queue's bound is (:mod:`service.work_queue`): one key's burst fills its
own share and is refused, never another key's request. With keys off every request has the one owner.

The body that was not read is left to the server: uvicorn discards what is left of it as it arrives and
keeps the connection open (bounded by the body cap and ``RSMT_BODY_TIMEOUT_S``). Closing the connection
instead would reset it while the client is still writing, and most clients (browsers, ``requests``,
``httpx``) write the whole body before reading, so they would report a reset connection rather than
the 503 and its ``Retry-After``. A client that stops sending once it has the answer is closed by the body
timeout.
"""

from __future__ import annotations

from collections import Counter
from typing import TYPE_CHECKING

from starlette.datastructures import Headers
from starlette.routing import compile_path, get_route_path
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.caller import ANONYMOUS, Caller
from service.errors import ServiceError, error_response
from service.http.auth import key_from
from service.http.request_metrics import ROUTE_TEMPLATE

if TYPE_CHECKING:
    from service.registry import Registry
    from service.state import ServiceState

#: The routes whose handlers queue model work (``LoadedModel.run``), as (method, path template).
GATED = (("POST", "/v1/transition"), ("POST", "/v1/styles"), ("POST", "/v1/viewer/clip"),
         ("GET", "/v1/viewer/demos/{name}"))


class QueueGateMiddleware:
    """Answers 503 ``overloaded`` (or ``shutting_down``) before the body for a :data:`GATED` route when the
    model queue(s) would refuse the request's key's job anyway, or when as many such requests of its key as the
    queues hold for one key (running and waiting) are already in the app; every other request passes untouched."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self._routes = [(method, template, compile_path(template)[0]) for method, template in GATED]
        self.in_flight: Counter[str] = Counter()  # per owner: gated requests let in, bodies read, not yet answered

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        template = self._gated_template(scope) if scope["type"] == "http" else None
        if template is None:
            await self.app(scope, receive, send)
            return
        state: ServiceState = scope["app"].state.service
        owner = _owner(state, scope)
        exc = None if state.registry is None else self._refusal(state.registry, owner)
        if exc is not None:
            scope[ROUTE_TEMPLATE] = template  # the request metric's label, as if the router had seen it
            state.metrics.errors.labels(exc.code).inc()
            await error_response(exc.code, exc.message, exc.headers)(scope, receive, send)
            return
        await self._admitted(scope, receive, send, owner)

    async def _admitted(self, scope: Scope, receive: Receive, send: Send, owner: str) -> None:
        """Run the request; it counts in :attr:`in_flight` from the end of its body (a client still sending,
        or one stalling, holds no place: the body timeout bounds it) until its answer starts (the model work
        is done by then, and a slow reader of a large answer holds no place either)."""
        counted = False

        def release() -> None:
            nonlocal counted
            if counted:
                counted = False
                self.in_flight[owner] -= 1
                if self.in_flight[owner] <= 0:
                    del self.in_flight[owner]

        async def counting_receive() -> Message:
            nonlocal counted
            message = await receive()
            if message["type"] == "http.request" and not message.get("more_body", False) and not counted:
                counted = True
                self.in_flight[owner] += 1
            return message

        async def releasing_send(message: Message) -> None:
            if message["type"] == "http.response.start":
                release()
            await send(message)

        try:
            await self.app(scope, counting_receive, releasing_send)
        finally:
            release()

    def _refusal(self, registry: Registry, owner: str) -> ServiceError | None:
        """The queue's refusal when every served model's queue would refuse a job of ``owner`` now, or when the
        requests of ``owner`` let in with their bodies read fill its part of every queue (they reach it only after
        validation: without this a burst arriving at once would all pass); None otherwise."""
        models = list(registry)
        target = registry.get()
        if all(m.queue.would_refuse(owner) for m in models):
            return target.queue.refusal(owner)
        if self.in_flight[owner] >= sum(m.queue.threads + (m.queue.limit or 0) for m in models):
            return target.queue.reject(owner)
        return None

    def _gated_template(self, scope: Scope) -> str | None:
        method, path = scope["method"], get_route_path(scope)
        for gated_method, template, pattern in self._routes:
            if method == gated_method and pattern.match(path):
                return template
        return None


def _owner(state: ServiceState, scope: Scope) -> str:
    """Whose share of the queues a request counts in: its API key's owner digest, as the route's caller
    (:func:`service.http.auth.check_access`; :class:`~service.http.auth.ApiKeyMiddleware` has checked the key
    by now), or the one owner when keys are off."""
    if not state.settings.auth_enabled:
        return ANONYMOUS
    return Caller.from_key(key_from(Headers(scope=scope)), admin=False).owner
