"""Request timing: every HTTP request observed in ``rsmt_http_request_duration_seconds`` by route template."""

from __future__ import annotations

import time

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.metrics import Metrics

#: Scope key for the route template of a request answered before routing (:mod:`service.http.queue_gate`).
ROUTE_TEMPLATE = "rsmt.route_template"


class MetricsMiddleware:
    """Times every HTTP request, labelled by route template (``/v1/styles/{style_id}``), not raw path."""

    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        status = [500]

        async def send_status(message: Message) -> None:
            if message["type"] == "http.response.start":
                status[0] = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_status)
        finally:
            route = getattr(scope.get("route"), "path", None) or scope.get(ROUTE_TEMPLATE) or "unmatched"
            self.metrics.request_seconds.labels(scope["method"], route, str(status[0])).observe(time.perf_counter() - start)
