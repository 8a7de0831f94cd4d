"""The FastAPI application: ``create_app(settings=None)``, served with ``uvicorn --factory service.app:create_app``.

Importing this module builds nothing; the models are loaded and warmed by the lifespan
(:mod:`service.lifecycle`).
"""

from __future__ import annotations

from fastapi import FastAPI

from service.errors import install_error_handlers
from service.http.auth import ApiKeyMiddleware
from service.http.body_limit import BodyLimitMiddleware
from service.http.handshake_log import install_handshake_log
from service.http.log_redaction import install_redaction
from service.http.logs import ensure_service_logging
from service.http.queue_gate import QueueGateMiddleware
from service.http.request_metrics import MetricsMiddleware
from service.lifecycle import lifespan
from service.metrics import Metrics
from service.ratelimit import RateLimiter
from service.routes import docs, health, metrics, models, stream, styles, transition, viewer
from service.settings import Settings, get_settings
from service.state import ServiceState
from service.streaming.connection import RawSendMiddleware
from service.styles import StoreLane
from service.viewer.page import mount_page

DESCRIPTION = """Real-time stylized motion transitions (RSMT, SIGGRAPH 2023).

HTTP for model information, style registration and whole transitions; WebSocket `/v1/stream` for
frame-by-frame streaming of many characters (wire details: docs/protocol.md). Every error is
`{"error": {"code", "message"}}`.
"""


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app; ``settings`` default to the ``RSMT_*`` environment."""
    settings = settings or get_settings()
    ensure_service_logging(settings.log_level, settings.log_format)
    install_redaction(settings.all_keys)  # no key in any log line, whoever configured logging
    install_handshake_log()  # refused handshakes at info, not uvicorn's error
    app = FastAPI(title="RSMT motion transition service", version="1", description=DESCRIPTION, lifespan=lifespan,
                  docs_url=None, redoc_url=None)  # served by routes.docs, from local files
    app.state.service = ServiceState(settings=settings, metrics=Metrics(),
                                     limiter=RateLimiter(settings.rate_limit_per_s, settings.rate_limit_burst,
                                                         max_keys=settings.rate_limit_max_tracked),
                                     auth_failures=RateLimiter(settings.auth_failure_rate_per_s,
                                                               settings.auth_failure_burst,
                                                               max_keys=settings.rate_limit_max_tracked),
                                     store_lane=StoreLane(4, settings.style_store_timeout_s),
                                     message_budgets=RateLimiter(settings.ws_key_messages_per_s,
                                                                 int(2 * settings.ws_key_messages_per_s),
                                                                 max_keys=settings.rate_limit_max_tracked))
    app.dependency_overrides[get_settings] = lambda: settings
    install_error_handlers(app)
    # Added last = outermost: metrics see every request, including 413s.
    app.add_middleware(BodyLimitMiddleware, max_bytes=settings.max_body_bytes)
    app.add_middleware(RawSendMiddleware)
    # After the key check, before the body: a request for model work that a full queue would refuse.
    app.add_middleware(QueueGateMiddleware)
    # Outside the body cap: a request without a valid key is answered before any of its body is read.
    app.add_middleware(ApiKeyMiddleware, keys=settings.all_keys, open_docs=settings.open_docs_and_metrics)
    app.add_middleware(MetricsMiddleware, metrics=app.state.service.metrics)
    for module in (health, models, styles, transition, stream, metrics, viewer):
        app.include_router(module.router)
    mount_page(app)  # the web viewer's page at /viewer/ (its helper routes are routes.viewer)
    docs.install(app)  # /docs and /redoc without a CDN, and / -> /viewer/
    return app
