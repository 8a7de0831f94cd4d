"""API keys: ``X-API-Key`` or ``Authorization: Bearer`` on HTTP; the same or ``?token=`` on the WebSocket handshake.

Keys are off unless ``RSMT_API_KEYS`` lists some. Comparison is constant-time. The per-key rate
limit is applied here too, so every protected route gets both from one dependency.
"""

from __future__ import annotations

import hmac
from collections.abc import Mapping
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Receive, Scope, Send

from service.errors import ServiceError, error_response
from service.http.ratelimit import retry_after_header
from service.state import ServiceState

_api_key_header = APIKeyHeader(name="X-API-Key", auto_error=False, description="an API key (when keys are on)")
_bearer = HTTPBearer(auto_error=False, description="the same API key as a bearer token")


def key_from(headers: Mapping[str, str], query: Mapping[str, str] | None = None) -> str | None:
    """The presented key: ``X-API-Key``, else a bearer token, else (WebSocket only) ``?token=``."""
    key = headers.get("x-api-key")
    if key:
        return key
    auth = headers.get("authorization", "")
    scheme, _, token = auth.partition(" ")
    if scheme.lower() == "bearer" and token.strip():
        return token.strip()
    if query is not None and query.get("token"):
        return query["token"]
    return None


def is_valid(key: str | None, keys: list[str]) -> bool:
    if key is None:
        return False
    presented = key.encode()
    ok = False
    for k in keys:  # no early exit: the time taken does not reveal which key matched
        ok |= hmac.compare_digest(presented, k.encode())
    return ok


def _unauthorized(key: str | None) -> ServiceError:
    what = "no API key" if key is None else "an unknown API key"
    return ServiceError("unauthorized", f"{what} was presented: send it as `X-API-Key: KEY` or "
                                        "`Authorization: Bearer KEY` (WebSocket: also `?token=KEY`)",
                        headers={"WWW-Authenticate": "Bearer"})


def check_access(state: ServiceState, key: str | None, client: str) -> None:
    """Raise ``unauthorized`` or ``rate_limited`` (with Retry-After) for a request from ``client``."""
    settings = state.settings
    if settings.auth_enabled and not is_valid(key, settings.api_keys):
        raise _unauthorized(key)
    # With keys on, the key is valid here and the bucket is its own; without, the client address's.
    wait = state.limiter.take(key if settings.auth_enabled and key is not None else client)
    if wait > 0:
        raise ServiceError("rate_limited", f"rate limit of {settings.rate_limit_per_s:g} requests/s "
                                           f"(burst {settings.rate_limit_burst}) exceeded; retry in {wait:.2f} s",
                           headers=retry_after_header(wait))


async def require_access(
    request: Request,
    _key: Annotated[str | None, Depends(_api_key_header)],
    _bearer_credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> None:
    """Route dependency: API key (when keys are on) and the per-key rate limit."""
    client = request.client.host if request.client else "unknown"
    check_access(request.app.state.service, key_from(request.headers), client)


# Routes outside /v1 that describe or measure the service (with their sub-paths, e.g. /docs/static/...).
DOCS_AND_METRICS = ("/metrics", "/docs", "/redoc", "/openapi.json")


class DocsAndMetricsKeyMiddleware:
    """With keys on, ``/metrics`` and the API docs need a key too (no rate limit), unless
    ``RSMT_OPEN_DOCS_AND_METRICS`` opens them; the health probes and the viewer's page stay open."""

    def __init__(self, app: ASGIApp, keys: list[str], open_: bool) -> None:
        self.app = app
        self.keys = keys
        self.closed = bool(keys) and not open_

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if self.closed and scope["type"] == "http" and _is_docs_or_metrics(scope):
            key = key_from(Headers(scope=scope))
            if not is_valid(key, self.keys):
                exc = _unauthorized(key)
                await error_response(exc.code, exc.message, exc.headers)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _is_docs_or_metrics(scope: Scope) -> bool:
    path, root = str(scope.get("path", "")), str(scope.get("root_path", ""))
    if root and path.startswith(root):
        path = path[len(root):]
    return any(path == p or path.startswith(p + "/") for p in DOCS_AND_METRICS)
