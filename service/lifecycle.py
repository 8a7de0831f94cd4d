"""Startup and shutdown: load and warm the models, then mark ready; on SIGTERM mark not ready first,
close WebSockets with 1001, drain, and only then let uvicorn stop.

uvicorn's own shutdown closes open WebSockets with 1012 and runs the lifespan's shutdown only after
every connection is gone, so the first steps cannot wait for the lifespan: the lifespan wraps
uvicorn's SIGINT/SIGTERM handlers. On the first signal it starts :func:`begin_shutdown` (readiness
503, every WebSocket closed with 1001), keeps serving HTTP for ``shutdown_drain_s`` so load
balancers see the 503, then closes the models' work queues (:func:`end_drain`: HTTP work not yet
started is answered JSON 503 ``shutting_down`` at once, new work too) and hands the signal to
uvicorn, which waits up to its ``timeout_graceful_shutdown`` (``rsmt serve`` sets it to
``shutdown_grace_s``) for the requests still running: at most ``request_threads`` per model, since
nothing else is left to start. A second signal goes to uvicorn at once. Where signals cannot be
caught (not the main thread, e.g. a test client), the lifespan's shutdown runs the same steps.

When the app knows the address it is served at (``app.state.public_url``, set by ``rsmt serve``), the
ready and stopped events go to the ``service.announce`` logger, which speaks at the default level.
"""

from __future__ import annotations

import asyncio
import gc
import logging
import os
import signal
import threading
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI

from service.http.logs import ANNOUNCE
from service.state import Phase, ServiceState
from service.streaming.connection import CLOSE_GOING_AWAY

log = logging.getLogger(__name__)
announce = logging.getLogger(ANNOUNCE)
HANDLED_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    from service.registry import NoModelError, load_registry
    from service.warmup import warm_up

    state: ServiceState = app.state.service
    url: str | None = getattr(app.state, "public_url", None)
    state.phase, state.failure = Phase.STARTING, ""  # an app may be started again after a shutdown (tests)
    try:
        registry = await asyncio.to_thread(load_registry, state.settings)
    except NoModelError as exc:
        log.error("%s", exc)
        raise
    state.registry = registry
    state.metrics.watch_style_caches(lambda: [(m.name, m.engine.styles) for m in registry])
    registry.start_schedulers(state.metrics, state.settings.asap_share, state.settings.step_shares_on,
                              state.settings.step_share_batch)

    restore = install_signal_hook(state, asyncio.get_running_loop())

    async def warm_all() -> None:
        try:
            for model in registry:
                timings = await warm_up(model, state.settings.warmup_max_batch)
                log.info("warmed up", extra={"model": model.name, **timings})
        except Exception as exc:
            log.exception("warm-up failed; the service will not become ready")
            state.phase, state.failure = Phase.FAILED, f"warm-up failed: {exc!r}"
            if restore.hooked:  # under uvicorn in the main thread: exit rather than stay up unready
                os.kill(os.getpid(), signal.SIGTERM)
            return
        freeze_heap()
        if state.phase is Phase.STARTING:
            state.phase = Phase.READY
            names = [m.name for m in registry]
            if url is None:
                log.info("ready", extra={"models": names})
            else:
                announce.info("RSMT ready at %s, model%s %s; viewer %s/viewer, API docs %s/docs", url,
                              "s" if len(names) > 1 else "", ", ".join(names), url, url,
                              extra={"event": "ready", "url": url, "models": names, "viewer": f"{url}/viewer"})

    warm_task = asyncio.create_task(warm_all(), name="warm-up")
    try:
        yield
    finally:
        warm_task.cancel()
        await begin_shutdown(state)
        end_drain(state)
        await registry.stop()
        restore()
        if url is not None:
            announce.info("RSMT at %s stopped", url, extra={"event": "stopped", "url": url})


def freeze_heap() -> None:
    """Move everything alive after warm-up (models, modules, traced graphs) out of the collector's reach.

    A full collection walks every tracked object; with the models loaded that took 75-134 ms, and when it
    fell in the step thread it stalled every streamed character for four frames (measured with the
    default model, 64 characters: the whole of the p99 frame lateness). Frozen objects are never
    walked again, so later collections only see what the serving itself allocates.
    """
    gc.collect()
    gc.freeze()


async def begin_shutdown(state: ServiceState) -> None:
    """Readiness goes 503 and every WebSocket is closed with 1001 (idempotent)."""
    if state.phase is not Phase.STOPPING:
        state.phase = Phase.STOPPING
        log.info("shutting down", extra={"connections": len(state.connections)})
    connections = list(state.connections)
    if connections:
        await asyncio.gather(*(c.close(CLOSE_GOING_AWAY, "server shutting down") for c in connections),
                             return_exceptions=True)


def end_drain(state: ServiceState) -> None:
    """The drain is over: every model's queued HTTP work that has not started is answered 503 ``shutting_down``
    (JSON) now, and new work too, so the graceful shutdown waits only for the jobs already running."""
    if state.registry is not None:
        dropped = state.registry.close_queues()
        if dropped:
            log.info("queued requests refused at shutdown", extra={"requests": dropped})


class _Restore:
    """Puts the previous signal handlers back; ``hooked`` says whether any were replaced."""

    def __init__(self, fn: Callable[[], None] | None = None) -> None:
        self.fn = fn
        self.hooked = fn is not None

    def __call__(self) -> None:
        if self.fn is not None:
            self.fn()


def install_signal_hook(state: ServiceState, loop: asyncio.AbstractEventLoop) -> _Restore:
    """Put :func:`begin_shutdown` and the drain in front of the current SIGINT/SIGTERM handlers (uvicorn's)."""
    if threading.current_thread() is not threading.main_thread():
        return _Restore()
    previous = {sig: signal.getsignal(sig) for sig in HANDLED_SIGNALS}
    started = False

    def hand_over(sig: int, frame: Any) -> None:
        prev = previous[signal.Signals(sig)]
        if callable(prev):
            prev(sig, frame)
        elif prev == signal.SIG_DFL:
            signal.signal(sig, signal.SIG_DFL)
            signal.raise_signal(sig)

    async def drain(sig: int, frame: Any) -> None:
        try:
            await begin_shutdown(state)
            await asyncio.sleep(state.settings.shutdown_drain_s)
        finally:
            end_drain(state)
            hand_over(sig, frame)

    def handler(sig: int, frame: Any) -> None:
        nonlocal started
        if started:  # a second signal: no more draining, uvicorn stops now
            loop.call_soon_threadsafe(end_drain, state)
            hand_over(sig, frame)
            return
        started = True
        loop.call_soon_threadsafe(lambda: loop.create_task(drain(sig, frame), name="shutdown-drain"))

    for sig in HANDLED_SIGNALS:
        signal.signal(sig, handler)

    def restore() -> None:
        for sig, prev in previous.items():
            if signal.getsignal(sig) is handler:
                signal.signal(sig, prev)

    return _Restore(restore)
