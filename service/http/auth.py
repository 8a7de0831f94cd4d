"""API keys: ``X-API-Key`` or ``Authorization: Bearer`` on HTTP; the same or ``?token=`` on the WebSocket handshake.

Keys are off unless ``RSMT_API_KEYS`` (or ``RSMT_ADMIN_API_KEYS``) lists some. Comparison is constant-time.
:class:`ApiKeyMiddleware` refuses a request without a valid key before its body is read, rate-limiting such
failures per client address; the route dependency checks the key again, applies the per-key rate limit and
says which :class:`~service.caller.Caller` the request acts as.
"""

from __future__ import annotations

import hmac
from collections.abc import Mapping
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Receive, Scope, Send

from service.caller import Caller
from service.errors import ServiceError, error_response
from service.http.addresses import address_key
from service.ratelimit import retry_after_header
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


def refuse(state: ServiceState, key: str | None, client: str) -> ServiceError:
    """The error for a request without a valid key: ``unauthorized``, or ``rate_limited`` (with Retry-After)
    once ``client`` has failed more than ``RSMT_AUTH_FAILURE_BURST`` times (refilled at the set rate)."""
    wait = state.auth_failures.take(address_key(client))  # an IPv6 client by its /64, as the connection cap
    if wait > 0:
        return ServiceError("rate_limited", f"too many requests without a valid API key from {client}; retry in "
                                            f"{wait:.2f} s", headers=retry_after_header(wait))
    return _unauthorized(key)


def check_access(state: ServiceState, key: str | None, client: str) -> Caller:
    """The caller (the owner of the styles it registers) of a request from ``client``; raise ``unauthorized``
    or ``rate_limited`` (with Retry-After)."""
    settings = state.settings
    if settings.auth_enabled and not is_valid(key, settings.all_keys):
        raise refuse(state, key, client)
    # With keys on, the key is valid here and the bucket is its own; without, the client address's.
    wait = state.limiter.take(key if settings.auth_enabled and key is not None else client)
    if wait > 0:
        raise ServiceError("rate_limited", f"rate limit of {settings.rate_limit_per_s:g} requests/s "
                                           f"(burst {settings.rate_limit_burst}) exceeded; retry in {wait:.2f} s",
                           headers=retry_after_header(wait))
    if not settings.auth_enabled:
        return Caller()
    return Caller.from_key(key, is_valid(key, settings.admin_api_keys))


async def require_access(
    request: Request,
    _key: Annotated[str | None, Depends(_api_key_header)],
    _bearer_credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> Caller:
    """Route dependency: API key (when keys are on) and the per-key rate limit; the caller it acts as."""
    client = request.client.host if request.client else "unknown"
    return check_access(request.app.state.service, key_from(request.headers), client)


CallerDep = Annotated[Caller, Depends(require_access)]


# Routes outside /v1 that describe or measure the service (with their sub-paths, e.g. /docs/static/...).
DOCS_AND_METRICS = ("/metrics", "/docs", "/redoc", "/openapi.json")
OPEN_V1 = ("/v1/health",)  # the probes


class ApiKeyMiddleware:
    """With keys on, answers an HTTP request to a key-protected path that lacks a valid key with 401 (429 once
    its address has failed too often) before any of its body is read or parsed.

    Key-protected: every ``/v1`` path but the health probes (the routes check the key again, with the per-key
    rate limit), and ``/metrics`` and the API docs unless ``RSMT_OPEN_DOCS_AND_METRICS`` opens them; the
    viewer's page stays open. The WebSocket handshake is checked by its route (:func:`check_access`)."""

    def __init__(self, app: ASGIApp, keys: list[str], open_docs: bool) -> None:
        self.app = app
        self.keys = keys
        self.open_docs = open_docs

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if self.keys and scope["type"] == "http" and self._protected(_path(scope)):
            key = key_from(Headers(scope=scope))
            if not is_valid(key, self.keys):
                state: ServiceState = scope["app"].state.service
                client = scope.get("client")
                exc = refuse(state, key, client[0] if client else "unknown")
                state.metrics.errors.labels(exc.code).inc()
                await error_response(exc.code, exc.message, exc.headers)(scope, receive, send)
                return
        await self.app(scope, receive, send)

    def _protected(self, path: str) -> bool:
        if path == "/v1" or path.startswith("/v1/"):
            return not any(path == p or path.startswith(p + "/") for p in OPEN_V1)
        return not self.open_docs and any(path == p or path.startswith(p + "/") for p in DOCS_AND_METRICS)


def _path(scope: Scope) -> str:
    path, root = str(scope.get("path", "")), str(scope.get("root_path", ""))
    if root and path.startswith(root):
        path = path[len(root):]
    return path
