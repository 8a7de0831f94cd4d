"""HTTP clients of the contract over httpx: :class:`Client` (sync) and :class:`AsyncClient`.

Both retry 429 (honouring ``Retry-After``), 503 and a connection refused or dropped before the answer (not
for a DELETE) with backoff (:class:`RetryPolicy`), raise
:class:`RsmtError` with the server's machine code otherwise, and return numpy arrays
(:class:`Poses`) for transitions. What is sent and how answers read lives in
:mod:`rsmt_client.http_protocol`; these classes only move requests and wait.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Self, TypeVar

import httpx

from rsmt_client import http_protocol as ops
from rsmt_client._retry import RetryHook, RetryPolicy
from rsmt_client.errors import RsmtError
from rsmt_client.http_protocol import DEFAULT_URL, ClientState, Operation, Request

if TYPE_CHECKING:
    from rsmt_client.motion import Poses

__all__ = ["DEFAULT_URL", "AsyncClient", "Client"]
T = TypeVar("T")


class _Settings:
    """The settings both clients expose, kept in their shared :class:`ClientState`."""

    _state: ClientState

    @property
    def url(self) -> str:
        return self._state.url

    @property
    def api_key(self) -> str | None:
        return self._state.api_key

    @property
    def retry(self) -> RetryPolicy:
        return self._state.retry

    @retry.setter
    def retry(self, policy: RetryPolicy) -> None:
        self._state.retry = policy

    @property
    def on_retry(self) -> RetryHook | None:
        return self._state.on_retry

    @on_retry.setter
    def on_retry(self, hook: RetryHook | None) -> None:
        self._state.on_retry = hook


class Client(_Settings):
    """Synchronous client: ``with Client(url, api_key=...) as c: c.transition(...)``."""

    def __init__(self, url: str = DEFAULT_URL, api_key: str | None = None, timeout: float = 60.0,
                 retry: RetryPolicy | None = None, on_retry: RetryHook | None = None,
                 transport: httpx.BaseTransport | None = None, sleep: Callable[[float], None] = time.sleep) -> None:
        self._state = ClientState(url, api_key, retry or RetryPolicy(), on_retry)
        self._sleep = sleep
        self._http = httpx.Client(base_url=self._state.url, headers=self._state.headers(), timeout=timeout,
                                  transport=transport, trust_env=False)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def request(self, method: str, path: str, **kw: Any) -> httpx.Response:
        """One request with the retry policy; raises :class:`RsmtError` for any error status."""
        retrying = self._state.retrying()
        while True:
            try:
                resp = self._http.request(method, path, **kw)
            except (httpx.ConnectError, httpx.ConnectTimeout) as exc:
                wait = ops.wait_after_refusal(retrying, self.url, exc)
            except ops.DROPPED as exc:
                wait = ops.wait_after_drop(retrying, method, self.url, exc)
            else:
                answered = ops.wait_after_response(retrying, resp)
                if answered is None:
                    return resp
                wait = answered
            self._sleep(wait)

    def _run(self, op: Operation[T]) -> T:
        """Carry the operation's requests; an error answer is thrown into it (it may recover, else it propagates)."""
        try:
            req: Request = next(op)
            while True:
                try:
                    resp = self.request(req.method, req.path, json=req.json, params=req.params)
                except RsmtError as exc:
                    req = op.throw(exc)
                else:
                    req = op.send(resp)
        except StopIteration as done:
            return done.value

    # ------------------------------------------------------------------ endpoints
    def live(self) -> bool:
        return self._run(ops.live())

    def ready(self) -> bool:
        """True once every model is loaded and warmed (no retries: a 503 answers False)."""
        try:
            return self._http.get("/v1/health/ready").status_code == 200
        except httpx.TransportError:
            return False

    def model(self, name: str | None = None) -> dict[str, Any]:
        """``GET /v1/model`` (or ``/v1/models/{name}``); the default model's answer is kept for BVH output."""
        return self._run(ops.model(self._state, name))

    def models(self) -> dict[str, Any]:
        return self._run(ops.models())

    def register_style(self, motion: Any, name: str | None = None, model: str | None = None) -> dict[str, Any]:
        """``POST /v1/styles``: register a style clip (a BVH path or text, payload, Poses or Clip).

        Returns ``{"style_id", "name", "frames", "cached"}``. The server keeps styles in memory only, per API
        key (evicted when the key holds too many, lost on restart): this client keeps the clips of its last
        256 registrations, and a transition by ``style_id`` that meets ``unknown_style`` registers the clip
        again and retries once.
        """
        return self._run(ops.register_style(self._state, motion, name, model))

    def register_style_clips(self, motions: Sequence[Any], name: str | None = None,
                             model: str | None = None) -> dict[str, Any]:
        """``POST /v1/styles`` with 1 to 5 clips of one style (each as :meth:`register_style` takes one), encoded
        together into one style: the same clips in any order get the same ``style_id``, used like any other.
        Returns ``{"style_id", "name", "frames", "clips", "cached"}``; registered again on ``unknown_style`` too."""
        return self._run(ops.register_style_clips(self._state, motions, name, model))

    def styles(self, model: str | None = None) -> list[dict[str, Any]]:
        return self._run(ops.styles(model))

    def demo(self, name: str, model: str | None = None) -> Poses:
        """A demo take of the web viewer as :class:`Poses` on the model's rig (``poses.save_bvh(path, c.model())``
        writes it): the default model's are walks it generates itself, ``walk-STYLE[-turn-left|-turn-right]``."""
        return self._run(ops.demo(self._state, name, model))

    def demos(self, model: str | None = None) -> list[dict[str, Any]]:
        """The names (and a line each) of the demo takes :meth:`demo` gives."""
        return self._run(ops.demos(model))

    def style(self, style_id: str) -> dict[str, Any]:
        return self._run(ops.style(style_id))

    def delete_style(self, style_id: str) -> None:
        self._run(ops.delete_style(self._state, style_id))

    def transition(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
                   seed: int | None = None, deterministic: bool = False, model: str | None = None,
                   exact_arrival: bool | None = None, style_strength: float | None = None) -> Poses:
        """``POST /v1/transition``: the ``frames`` generated poses as float32 arrays (``target``: a Motion, or a
        :class:`rsmt_client.placement.TargetAt` place and facing; ``style_strength``: the style moved from the
        model's neutral style by this factor; None: the server's setting)."""
        return self._run(ops.transition(self._state, context, target, frames, style_id, style, seed, deterministic, model,
                                        exact_arrival, style_strength))

    def transition_bvh(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
                       seed: int | None = None, deterministic: bool = False, model: str | None = None,
                       exact_arrival: bool | None = None, style_strength: float | None = None) -> str:
        """``POST /v1/transition`` with ``output: bvh``: the server's BVH text of exactly ``frames`` frames."""
        return self._run(ops.transition_bvh(self._state, context, target, frames, style_id, style, seed, deterministic,
                                            model, exact_arrival, style_strength))


class AsyncClient(_Settings):
    """Asynchronous client: ``async with AsyncClient(url) as c: await c.transition(...)``; the methods of :class:`Client`."""

    def __init__(self, url: str = DEFAULT_URL, api_key: str | None = None, timeout: float = 60.0,
                 retry: RetryPolicy | None = None, on_retry: RetryHook | None = None,
                 transport: httpx.AsyncBaseTransport | None = None) -> None:
        self._state = ClientState(url, api_key, retry or RetryPolicy(), on_retry)
        self._http = httpx.AsyncClient(base_url=self._state.url, headers=self._state.headers(), timeout=timeout,
                                       transport=transport, trust_env=False)

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        await self._http.aclose()

    async def request(self, method: str, path: str, **kw: Any) -> httpx.Response:
        retrying = self._state.retrying()
        while True:
            try:
                resp = await self._http.request(method, path, **kw)
            except (httpx.ConnectError, httpx.ConnectTimeout) as exc:
                wait = ops.wait_after_refusal(retrying, self.url, exc)
            except ops.DROPPED as exc:
                wait = ops.wait_after_drop(retrying, method, self.url, exc)
            else:
                answered = ops.wait_after_response(retrying, resp)
                if answered is None:
                    return resp
                wait = answered
            import asyncio  # only the async client needs it: not loaded with Client

            await asyncio.sleep(wait)

    async def _run(self, op: Operation[T]) -> T:
        try:
            req: Request = next(op)
            while True:
                try:
                    resp = await self.request(req.method, req.path, json=req.json, params=req.params)
                except RsmtError as exc:
                    req = op.throw(exc)
                else:
                    req = op.send(resp)
        except StopIteration as done:
            return done.value

    async def live(self) -> bool:
        return await self._run(ops.live())

    async def ready(self) -> bool:
        try:
            return (await self._http.get("/v1/health/ready")).status_code == 200
        except httpx.TransportError:
            return False

    async def model(self, name: str | None = None) -> dict[str, Any]:
        return await self._run(ops.model(self._state, name))

    async def models(self) -> dict[str, Any]:
        return await self._run(ops.models())

    async def register_style(self, motion: Any, name: str | None = None, model: str | None = None) -> dict[str, Any]:
        return await self._run(ops.register_style(self._state, motion, name, model))

    async def register_style_clips(self, motions: Sequence[Any], name: str | None = None,
                                   model: str | None = None) -> dict[str, Any]:
        return await self._run(ops.register_style_clips(self._state, motions, name, model))

    async def styles(self, model: str | None = None) -> list[dict[str, Any]]:
        return await self._run(ops.styles(model))

    async def demo(self, name: str, model: str | None = None) -> Poses:
        return await self._run(ops.demo(self._state, name, model))

    async def demos(self, model: str | None = None) -> list[dict[str, Any]]:
        return await self._run(ops.demos(model))

    async def style(self, style_id: str) -> dict[str, Any]:
        return await self._run(ops.style(style_id))

    async def delete_style(self, style_id: str) -> None:
        await self._run(ops.delete_style(self._state, style_id))

    async def transition(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
                         seed: int | None = None, deterministic: bool = False, model: str | None = None,
                         exact_arrival: bool | None = None, style_strength: float | None = None) -> Poses:
        return await self._run(ops.transition(self._state, context, target, frames, style_id, style, seed, deterministic,
                                              model, exact_arrival, style_strength))

    async def transition_bvh(self, context: Any, target: Any, frames: int, style_id: str | None = None,
                             style: Any = None, seed: int | None = None, deterministic: bool = False,
                             model: str | None = None, exact_arrival: bool | None = None,
                             style_strength: float | None = None) -> str:
        return await self._run(ops.transition_bvh(self._state, context, target, frames, style_id, style, seed,
                                                  deterministic, model, exact_arrival, style_strength))
