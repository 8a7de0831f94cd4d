"""The error envelope ``{"error": {"code", "message"}}``, its HTTP statuses, the handlers that produce it, and
the contract code of each error the engine raises."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import orjson
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError, WebSocketRequestValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.responses import Response

from model.inference.errors import EngineError, SkeletonMismatch, TooFewFrames, TooManyFrames
from service.shape_hints import motion_errors, raw_bvh_body_hint

log = logging.getLogger(__name__)
CLIENT_CLOSED_REQUEST = 499

# Every machine code of docs/protocol.md, with its HTTP status.
STATUS: dict[str, int] = {
    "invalid_json": 400,
    "validation_error": 422,
    "bad_motion": 422,
    "skeleton_mismatch": 422,
    "too_few_frames": 422,
    "too_many_frames": 422,
    "payload_too_large": 413,
    "unknown_style": 404,
    "unknown_model": 404,
    "unknown_character": 404,
    "character_exists": 409,
    "too_many_characters": 429,
    "rate_limited": 429,
    "unauthorized": 401,
    "not_ready": 503,
    "shutting_down": 503,
    "overloaded": 503,  # a model's work queue is full (RSMT_QUEUE_LIMIT); with Retry-After
    "style_store_unavailable": 503,  # RSMT_STYLE_STORE (Redis) cannot be reached; with Retry-After
    "internal": 500,
    # HTTP-only codes for requests that reach no route.
    "not_found": 404,
    "method_not_allowed": 405,
    "unsupported_media_type": 415,
}


class ServiceError(Exception):
    """An error with a contract code; HTTP handlers turn it into the envelope, WebSockets into an ``error`` message."""

    def __init__(self, code: str, message: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        if code not in STATUS:
            raise ValueError(f"unknown error code {code!r}")
        self.code = code
        self.message = message
        self.headers = headers or {}

    @property
    def status(self) -> int:
        return STATUS[self.code]


class ClientGone(Exception):
    """The HTTP client of a queued job disconnected before it started: the job is dropped, and the answer
    nobody reads is an empty 499 (nginx's "client closed request"), visible only in the request metrics."""


# The engine's errors by contract code; any other (a length out of range) is a validation_error.
ENGINE_CODES: dict[type[EngineError], str] = {
    SkeletonMismatch: "skeleton_mismatch",
    TooFewFrames: "too_few_frames",
    TooManyFrames: "too_many_frames",
}


def from_engine(exc: EngineError) -> ServiceError:
    """The contract's error for what the engine refused; the engine's message is kept."""
    code = next((c for kind, c in ENGINE_CODES.items() if isinstance(exc, kind)), "validation_error")
    return ServiceError(code, str(exc))


def envelope(code: str, message: str) -> dict[str, Any]:
    return {"error": {"code": code, "message": message}}


def error_response(code: str, message: str, headers: dict[str, str] | None = None) -> Response:
    return Response(orjson.dumps(envelope(code, message)), status_code=STATUS[code], headers=headers,
                    media_type="application/json")


def _count(request: Request, code: str) -> None:
    state = getattr(request.app.state, "service", None)
    metrics = getattr(state, "metrics", None)
    if metrics is not None:
        metrics.errors.labels(code=code).inc()


def describe_validation(errors: Sequence[Mapping[str, Any]], limit: int = 5, builtin_names: Iterable[str] = ()) -> str:
    """One readable line per pydantic error: ``frames: Input should be greater than or equal to 1``; an error on
    a Motion names what to send instead (``builtin_names``: the built-in styles a name in ``style`` may mean)."""
    parts, rest = motion_errors(errors, builtin_names)
    for err in rest:
        loc = ".".join(str(p) for p in err.get("loc", ()) if p not in ("body",)) or "body"
        parts.append(f"{loc}: {err.get('msg', 'invalid')}")
    more = len(parts) - limit
    parts = parts[:limit]
    if more > 0:
        parts.append(f"... and {more} more")
    return "; ".join(parts)


def _json_media_type(content_type: str | None) -> bool:
    media = (content_type or "").split(";", 1)[0].strip().lower()
    return media == "application/json" or (media.startswith("application/") and media.endswith("+json"))


def _whole_body(error: Mapping[str, Any]) -> bool:
    """An error about the body as a whole (its type), not about a field in it."""
    return tuple(error.get("loc", ())) == ("body",)


def _raw_bvh_hint(body: Any) -> str:
    """The wrapper a BVH file sent as the whole body needed (``""`` for another body)."""
    start = body[:64] if isinstance(body, bytes | bytearray) else str(body)[:64].encode() if isinstance(body, str) else b""
    return raw_bvh_body_hint(bytes(start))


def _builtin_names(request: Request) -> list[str]:
    """The built-in styles of the loaded models (none while they load)."""
    registry = getattr(getattr(request.app.state, "service", None), "registry", None)
    return [name for model in registry for name in model.engine.bundle.styles] if registry is not None else []


def install_error_handlers(app: FastAPI) -> None:
    """Every error, including FastAPI's own validation and routing errors, leaves in the envelope."""

    @app.exception_handler(ServiceError)
    async def _service_error(request: Request, exc: ServiceError) -> Response:
        _count(request, exc.code)
        return error_response(exc.code, exc.message, exc.headers)

    @app.exception_handler(ClientGone)
    async def _client_gone(request: Request, exc: ClientGone) -> Response:
        return Response(status_code=CLIENT_CLOSED_REQUEST)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> Response:
        errors = list(exc.errors())
        # A body that is not JSON at all is a 400; a JSON body of the wrong shape is a 422.
        invalid = [e for e in errors if e.get("type") == "json_invalid"]
        if invalid:
            detail = (invalid[0].get("ctx") or {}).get("error") or invalid[0].get("msg", "")
            code, message = "invalid_json", f"the request body is not valid JSON: {detail}" + _raw_bvh_hint(exc.body)
        elif not _json_media_type(request.headers.get("content-type")) and any(_whole_body(e) for e in errors):
            # FastAPI reads a body as JSON only when it says it is: anything else arrives as text, "not a dict".
            sent = request.headers.get("content-type")
            code = "unsupported_media_type"
            message = (f"the request body must be JSON sent with Content-Type: application/json; this request has "
                       f"{'Content-Type: ' + sent[:100] if sent else 'no Content-Type'} (curl: -H 'content-type: "
                       "application/json'); BVH text goes inside that JSON as a Motion, {\"bvh\": \"<the BVH file's "
                       "text>\"}" + _raw_bvh_hint(exc.body))
        else:
            code, message = "validation_error", describe_validation(errors, builtin_names=_builtin_names(request))
        _count(request, code)
        return error_response(code, message)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> Response:
        code = {404: "not_found", 405: "method_not_allowed", 413: "payload_too_large", 415: "unsupported_media_type",
                400: "invalid_json", 401: "unauthorized", 429: "rate_limited", 503: "not_ready"}.get(exc.status_code)
        if code is None:
            code = "validation_error" if 400 <= exc.status_code < 500 else "internal"
        _count(request, code)
        response = error_response(code, str(exc.detail), getattr(exc, "headers", None))
        response.status_code = exc.status_code
        return response

    @app.exception_handler(WebSocketRequestValidationError)
    async def _ws_validation(websocket: Any, exc: WebSocketRequestValidationError) -> None:  # pragma: no cover
        await websocket.close(code=1008, reason=describe_validation(list(exc.errors()))[:120])

    @app.exception_handler(Exception)
    async def _internal(request: Request, exc: Exception) -> Response:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        _count(request, "internal")
        return error_response("internal", "internal error; the server log has the details")
