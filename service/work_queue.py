"""The bounded queue in front of a model's work threads: HTTP engine work waits here, first come first served.

At most ``threads`` jobs run at once; at most ``limit`` more wait. A job that finds the queue full is
refused at once with 503 ``overloaded`` and a ``Retry-After`` estimated from the recent job times, so a
burst costs the server nothing beyond what it can serve; :mod:`service.http.queue_gate` asks
:meth:`WorkQueue.refusal` before the request's body is even read. A waiting job whose HTTP client has gone (its
connection closed before the job started) is dropped, not run. At shutdown :meth:`WorkQueue.close`
answers every waiting job 503 ``shutting_down`` at once and refuses new ones, so that only the jobs
already running (at most ``threads``) are left for the graceful shutdown to wait for.

Used from the event loop only; the jobs themselves run on the executor's threads.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import deque
from collections.abc import Awaitable, Callable
from concurrent.futures import Executor
from typing import Any, TypeVar

from starlette.types import Receive

from service.errors import ClientGone, ServiceError
from service.metrics import Metrics

log = logging.getLogger(__name__)
T = TypeVar("T")

# Outcomes counted in rsmt_work_queue_jobs_total{model, outcome}.
RUN, REJECTED, ABANDONED, SHUT_DOWN = "run", "rejected", "abandoned", "shutting_down"


def shutting_down_error(started: bool = False) -> ServiceError:
    what = ("ran past the shutdown grace and its answer is lost" if started else "was not started")
    return ServiceError("shutting_down", f"the server is shutting down and this request {what}; retry it on another "
                                         "replica (or here once it is back)")


class WorkQueue:
    """A FIFO of at most ``limit`` waiting jobs in front of ``threads`` running ones on ``executor``."""

    def __init__(self, executor: Executor, threads: int, limit: int, metrics: Metrics | None = None,
                 name: str = "model") -> None:
        self.executor = executor
        self.threads = threads
        self.limit = limit
        self.metrics = metrics
        self.name = name
        self.running = 0
        self.closed = False
        self._waiting: deque[asyncio.Future[None]] = deque()
        self._job_s = 0.05  # moving average of job times, for Retry-After

    @property
    def waiting(self) -> int:
        return len(self._waiting)

    def retry_after_s(self) -> int:
        """Whole seconds until the queue has likely room again (at least 1)."""
        backlog = (len(self._waiting) + self.running) * self._job_s / max(1, self.threads)
        return max(1, math.ceil(backlog))

    async def run(self, fn: Callable[..., T], *args: Any, gone: Callable[[], Awaitable[None]] | None = None) -> T:
        """Run ``fn(*args)`` on a work thread once a slot is free; ``gone`` (awaitable) completes when the
        caller's client disconnects, in which case a job not yet started raises :class:`ClientGone`.

        Raises ``overloaded`` (queue full) or ``shutting_down`` (closed) without waiting.
        """
        refused = self.refusal()
        if refused is not None:
            raise refused
        if self._has_free_thread():
            self.running += 1
        else:
            await self._wait_for_slot(gone)
        # From here this call holds a slot, released exactly once: when the job is done on its thread.
        self._count(RUN)
        started = time.perf_counter()
        try:
            future = asyncio.get_running_loop().run_in_executor(self.executor, fn, *args)
        except BaseException:
            self._release()
            raise
        future.add_done_callback(lambda f: self._finished(f, started))
        try:
            return await asyncio.shield(future)
        except asyncio.CancelledError:
            # uvicorn cancels the requests still running when its graceful shutdown times out: answer them
            # in JSON rather than let the server write a plain-text 500 (the job itself runs to its end).
            if self.closed:
                raise shutting_down_error(started=True) from None
            raise

    def _has_free_thread(self) -> bool:
        return self.running < self.threads and not self._waiting

    def _full(self) -> bool:
        """No free thread and ``limit`` jobs already waiting: a job arriving now is refused."""
        return not self._has_free_thread() and len(self._waiting) >= self.limit

    def refusal(self) -> ServiceError | None:
        """The error a job arriving now would get at once (``shutting_down`` or ``overloaded``), counted as
        refused; None when it would run or wait. For a check before the request's body is read
        (:mod:`service.http.queue_gate`); :meth:`run` checks again, as the queue may fill meanwhile."""
        if self.closed:
            self._count(SHUT_DOWN)
            return shutting_down_error()
        return self.reject() if self._full() else None

    def reject(self) -> ServiceError:
        """Count a job refused for want of room and return its ``overloaded`` error (with Retry-After)."""
        self._count(REJECTED)
        wait = self.retry_after_s()
        return ServiceError("overloaded", f"model {self.name!r} already has {self.limit} requests waiting "
                                          f"(RSMT_QUEUE_LIMIT) and {self.running} running; retry in about "
                                          f"{wait} s, or on another replica", headers={"Retry-After": str(wait)})

    def would_refuse(self) -> bool:
        """Whether :meth:`refusal` would refuse now (counts nothing)."""
        return self.closed or self._full()

    def _finished(self, future: asyncio.Future[Any], started: float) -> None:
        if not future.cancelled():
            future.exception()  # retrieved here too, for a caller cancelled meanwhile
        self._job_s += 0.2 * (time.perf_counter() - started - self._job_s)
        self._release()

    async def _wait_for_slot(self, gone: Callable[[], Awaitable[None]] | None) -> None:
        """Wait in line (:meth:`run` has checked there is room)."""
        ticket: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._waiting.append(ticket)
        self._gauge()
        watcher = None if gone is None else asyncio.create_task(self._watch(ticket, gone), name="work-queue-watch")
        try:
            await ticket
        except BaseException:
            if ticket.done() and not ticket.cancelled() and ticket.exception() is None:
                self._release()  # granted, then cancelled before it could start: pass the slot on
            else:
                self._forget(ticket)
            raise
        finally:
            if watcher is not None:
                watcher.cancel()

    async def _watch(self, ticket: asyncio.Future[None], gone: Callable[[], Awaitable[None]]) -> None:
        try:
            await gone()
        except Exception:  # nothing to learn from a broken receive: the job stays queued
            log.debug("watching for a disconnect failed", exc_info=True)
            return
        if not ticket.done():
            self._forget(ticket)
            self._count(ABANDONED)
            ticket.set_exception(ClientGone())

    def _forget(self, ticket: asyncio.Future[None]) -> None:
        try:
            self._waiting.remove(ticket)
        except ValueError:
            pass
        self._gauge()

    def _release(self) -> None:
        """A running job is done: hand its slot to the first waiting job, or free it."""
        while self._waiting:
            ticket = self._waiting.popleft()
            if not ticket.done():
                ticket.set_result(None)  # the slot passes on; ``running`` is unchanged
                self._gauge()
                return
        self.running -= 1
        self._gauge()

    def close(self) -> int:
        """Refuse new jobs and answer every waiting one ``shutting_down``; returns how many were waiting."""
        self.closed = True
        dropped = 0
        while self._waiting:
            ticket = self._waiting.popleft()
            if not ticket.done():
                ticket.set_exception(shutting_down_error())
                dropped += 1
        if dropped:
            self._count(SHUT_DOWN, dropped)
        self._gauge()
        return dropped

    def _count(self, outcome: str, n: int = 1) -> None:
        if self.metrics is not None:
            self.metrics.work_jobs.labels(self.name, outcome).inc(n)

    def _gauge(self) -> None:
        if self.metrics is not None:
            self.metrics.work_waiting.labels(self.name).set(len(self._waiting))


def disconnect_of(receive: Receive) -> Callable[[], Awaitable[None]]:
    """An awaitable factory that completes when the HTTP client behind ``receive`` disconnects (the body
    must have been read already: later ``http.request`` messages are ignored)."""

    async def gone() -> None:
        for _ in range(1000):  # bounded: a server would only repeat empty bodies by mistake
            message = await receive()
            if message["type"] == "http.disconnect":
                return
        await asyncio.Event().wait()  # never: keep the job queued

    return gone
