"""HTTP clients of the contract over httpx: :class:`Client` (sync) and :class:`AsyncClient`.

Both retry 429 (honouring ``Retry-After``) and 503 with backoff (:class:`RetryPolicy`), raise
:class:`RsmtError` with the server's machine code otherwise, and return numpy arrays
(:class:`Poses`) for transitions.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Mapping
from typing import Any, Self

import httpx

from rsmt_client._retry import RetryPolicy
from rsmt_client.errors import RsmtError
from rsmt_client.motion import Poses, motion_payload

DEFAULT_URL = "http://127.0.0.1:8000"
RetryHook = Callable[[int, float, "httpx.Response | None"], None]


def error_from_response(resp: httpx.Response) -> RsmtError:
    """The contract's ``{"error": {"code", "message"}}`` as an :class:`RsmtError` (any body survives)."""
    from rsmt_client._retry import parse_retry_after

    code, message = "http_error", resp.text[:500] or resp.reason_phrase
    try:
        body = resp.json()
        err = body.get("error") if isinstance(body, dict) else None
        if isinstance(err, dict):
            code, message = str(err.get("code", code)), str(err.get("message", message))
    except ValueError:
        pass
    return RsmtError(code, message, status=resp.status_code, retry_after=parse_retry_after(resp.headers.get("retry-after")))


def _headers(api_key: str | None) -> dict[str, str]:
    headers = {"User-Agent": "rsmt-client/0.1", "Accept": "application/json"}
    if api_key:
        headers["X-API-Key"] = api_key
    return headers


def _transition_body(context: Any, target: Any, frames: int, style_id: str | None, style: Any, seed: int | None,
                     deterministic: bool, output: str, model: str | None, exact_arrival: bool = False) -> dict[str, Any]:
    if (style_id is None) == (style is None):
        raise ValueError("give exactly one of style_id or style")
    body: dict[str, Any] = {"context": motion_payload(context), "target": motion_payload(target), "frames": int(frames),
                            "deterministic": bool(deterministic), "output": output}
    if style_id is not None:
        body["style_id"] = style_id
    else:
        body["style"] = motion_payload(style)
    if seed is not None:
        body["seed"] = int(seed)
    if model is not None:
        body["model"] = model
    if exact_arrival:  # sent only when asked, so older servers keep accepting the request
        body["exact_arrival"] = True
    return body


def _poses(data: Mapping[str, Any], joints: tuple[str, ...] | None) -> Poses:
    return Poses.from_frames(data["frames"], float(data["fps"]), joints=joints, style_id=data.get("style_id"),
                             model=data.get("model"), timing_ms=dict(data.get("timing_ms") or {}))


class _Common:
    def __init__(self, url: str, api_key: str | None, retry: RetryPolicy | None, on_retry: RetryHook | None) -> None:
        self.url = url.rstrip("/")
        self.api_key = api_key
        self.retry = retry or RetryPolicy()
        self.on_retry = on_retry
        self._model_info: dict[str, Any] | None = None

    def _check(self, resp: httpx.Response) -> httpx.Response:
        if resp.status_code >= 400:
            raise error_from_response(resp)
        return resp

    def _joints(self) -> tuple[str, ...] | None:
        info = self._model_info
        return tuple(j["name"] for j in info["skeleton"]["joints"]) if info else None


class Client(_Common):
    """Synchronous client: ``with Client(url, api_key=...) as c: c.transition(...)``."""

    def __init__(self, url: str = DEFAULT_URL, api_key: str | None = None, timeout: float = 60.0,
                 retry: RetryPolicy | None = None, on_retry: RetryHook | None = None,
                 transport: httpx.BaseTransport | None = None, sleep: Callable[[float], None] = time.sleep) -> None:
        super().__init__(url, api_key, retry, on_retry)
        self._sleep = sleep
        self._http = httpx.Client(base_url=self.url, headers=_headers(api_key), timeout=timeout, transport=transport,
                                  trust_env=False)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def request(self, method: str, path: str, **kw: Any) -> httpx.Response:
        """One request with the retry policy; raises :class:`RsmtError` for any error status."""
        retry = 0
        while True:
            try:
                resp = self._http.request(method, path, **kw)
            except (httpx.ConnectError, httpx.ConnectTimeout) as exc:
                wait = self.retry.wait(retry, None, None)
                if wait is None:
                    raise RsmtError("connection", f"cannot reach {self.url}: {exc}") from exc
                resp = None
            else:
                wait = self.retry.wait(retry, resp.status_code, resp.headers) if resp.status_code >= 400 else None
                if wait is None:
                    return self._check(resp)
            if self.on_retry is not None:
                self.on_retry(retry, wait, resp)
            self._sleep(wait)
            retry += 1

    # ------------------------------------------------------------------ endpoints
    def live(self) -> bool:
        return self.request("GET", "/v1/health/live").status_code == 200

    def ready(self) -> bool:
        """True once every model is loaded and warmed (no retries: a 503 answers False)."""
        try:
            return self._http.get("/v1/health/ready").status_code == 200
        except httpx.TransportError:
            return False

    def model(self, name: str | None = None) -> dict[str, Any]:
        """``GET /v1/model`` (or ``/v1/models/{name}``); the default model's answer is kept for BVH output."""
        info = self.request("GET", "/v1/model" if name is None else f"/v1/models/{name}").json()
        if name is None:
            self._model_info = info
        return info

    def models(self) -> dict[str, Any]:
        return self.request("GET", "/v1/models").json()

    def register_style(self, motion: Any, name: str | None = None, model: str | None = None) -> dict[str, Any]:
        """``POST /v1/styles``: register a style clip (a BVH path or text, payload, Poses or Clip).

        Returns ``{"style_id", "name", "frames", "cached"}``.
        """
        body: dict[str, Any] = {"name": name or _default_name(motion), "motion": motion_payload(motion)}
        if model is not None:
            body["model"] = model
        return self.request("POST", "/v1/styles", json=body).json()

    def styles(self, model: str | None = None) -> list[dict[str, Any]]:
        return self.request("GET", "/v1/styles", params={"model": model} if model else None).json()["styles"]

    def style(self, style_id: str) -> dict[str, Any]:
        return self.request("GET", f"/v1/styles/{style_id}").json()

    def delete_style(self, style_id: str) -> None:
        self.request("DELETE", f"/v1/styles/{style_id}")

    def transition(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
                   seed: int | None = None, deterministic: bool = False, model: str | None = None,
                   exact_arrival: bool = False) -> Poses:
        """``POST /v1/transition``: the ``frames`` generated poses as float32 arrays."""
        body = _transition_body(context, target, frames, style_id, style, seed, deterministic, "json", model,
                                exact_arrival)
        data = self.request("POST", "/v1/transition", json=body).json()
        if self._model_info is None and model is None:
            self.model()
        return _poses(data, self._joints() if model is None else None)

    def transition_bvh(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
                       seed: int | None = None, deterministic: bool = False, model: str | None = None,
                       exact_arrival: bool = False) -> str:
        """``POST /v1/transition`` with ``output: bvh``: the server's BVH text of exactly ``frames`` frames."""
        body = _transition_body(context, target, frames, style_id, style, seed, deterministic, "bvh", model,
                                exact_arrival)
        return self.request("POST", "/v1/transition", json=body).json()["bvh"]


class AsyncClient(_Common):
    """Asynchronous client: ``async with AsyncClient(url) as c: await c.transition(...)``."""

    def __init__(self, url: str = DEFAULT_URL, api_key: str | None = None, timeout: float = 60.0,
                 retry: RetryPolicy | None = None, on_retry: RetryHook | None = None,
                 transport: httpx.AsyncBaseTransport | None = None) -> None:
        super().__init__(url, api_key, retry, on_retry)
        self._http = httpx.AsyncClient(base_url=self.url, headers=_headers(api_key), timeout=timeout,
                                       transport=transport, trust_env=False)

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        await self._http.aclose()

    async def request(self, method: str, path: str, **kw: Any) -> httpx.Response:
        retry = 0
        while True:
            try:
                resp = await self._http.request(method, path, **kw)
            except (httpx.ConnectError, httpx.ConnectTimeout) as exc:
                wait = self.retry.wait(retry, None, None)
                if wait is None:
                    raise RsmtError("connection", f"cannot reach {self.url}: {exc}") from exc
                resp = None
            else:
                wait = self.retry.wait(retry, resp.status_code, resp.headers) if resp.status_code >= 400 else None
                if wait is None:
                    return self._check(resp)
            if self.on_retry is not None:
                self.on_retry(retry, wait, resp)
            await asyncio.sleep(wait)
            retry += 1

    async def live(self) -> bool:
        return (await self.request("GET", "/v1/health/live")).status_code == 200

    async def ready(self) -> bool:
        try:
            return (await self._http.get("/v1/health/ready")).status_code == 200
        except httpx.TransportError:
            return False

    async def model(self, name: str | None = None) -> dict[str, Any]:
        info = (await self.request("GET", "/v1/model" if name is None else f"/v1/models/{name}")).json()
        if name is None:
            self._model_info = info
        return info

    async def models(self) -> dict[str, Any]:
        return (await self.request("GET", "/v1/models")).json()

    async def register_style(self, motion: Any, name: str | None = None, model: str | None = None) -> dict[str, Any]:
        body: dict[str, Any] = {"name": name or _default_name(motion), "motion": motion_payload(motion)}
        if model is not None:
            body["model"] = model
        return (await self.request("POST", "/v1/styles", json=body)).json()

    async def styles(self, model: str | None = None) -> list[dict[str, Any]]:
        return (await self.request("GET", "/v1/styles", params={"model": model} if model else None)).json()["styles"]

    async def style(self, style_id: str) -> dict[str, Any]:
        return (await self.request("GET", f"/v1/styles/{style_id}")).json()

    async def delete_style(self, style_id: str) -> None:
        await self.request("DELETE", f"/v1/styles/{style_id}")

    async def transition(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
                         seed: int | None = None, deterministic: bool = False, model: str | None = None,
                         exact_arrival: bool = False) -> Poses:
        body = _transition_body(context, target, frames, style_id, style, seed, deterministic, "json", model,
                                exact_arrival)
        data = (await self.request("POST", "/v1/transition", json=body)).json()
        if self._model_info is None and model is None:
            await self.model()
        return _poses(data, self._joints() if model is None else None)

    async def transition_bvh(self, context: Any, target: Any, frames: int, style_id: str | None = None,
                             style: Any = None, seed: int | None = None, deterministic: bool = False,
                             model: str | None = None, exact_arrival: bool = False) -> str:
        body = _transition_body(context, target, frames, style_id, style, seed, deterministic, "bvh", model,
                                exact_arrival)
        return (await self.request("POST", "/v1/transition", json=body)).json()["bvh"]


def _default_name(motion: Any) -> str:
    from pathlib import Path

    if isinstance(motion, Path) or (isinstance(motion, str) and motion.lower().endswith(".bvh")
                                    and "\n" not in motion):
        return Path(motion).stem
    return "style"
