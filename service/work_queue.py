"""The bounded queue in front of a model's threads: HTTP engine work waits here (and, without a bound, stream setup).

At most ``threads`` jobs run at once. Each API key's jobs wait in a queue of their own, in order, and a free
thread goes to the key that has used the least thread time (:mod:`service.key_turns`), so one key's burst
delays another key's job by about one job, not by the whole burst. At most ``limit`` jobs of one key wait: its
next one is refused at once with 503 ``overloaded`` and a ``Retry-After`` estimated from the recent job times,
so a burst costs the server nothing beyond what it can serve and the refusal goes to the key that floods, never
to a quiet one; :mod:`service.http.queue_gate` asks :meth:`WorkQueue.refusal` before the request's body is even
read. With API keys off every job has the one owner ``""``: one first-come queue of at most ``limit``.

A long job may give the thread back between slices of its work: a job function that returns :class:`Continue`
goes on at once on its thread while no other key's job waits, or while its key is still behind the least served
of those that wait (its turn); past that, its next slice is queued first in its key's turn and the thread goes to
whichever key's turn it is meanwhile, so another key's job waits for one slice, not a whole long job (a 120-frame
transition, say).

A waiting job whose HTTP client has gone (its connection closed before the job started) is dropped, not run.
At shutdown :meth:`WorkQueue.close` answers every waiting job 503 ``shutting_down`` at once and refuses new
ones, so that only the jobs already running (at most ``threads``) are left for the graceful shutdown to wait for.

Used from the event loop only; the jobs themselves run on the executor's threads.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import Counter, deque
from collections.abc import Awaitable, Callable
from concurrent.futures import Executor
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from starlette.types import Receive

from service.caller import ANONYMOUS
from service.errors import ClientGone, ServiceError
from service.key_turns import KeyTurns
from service.metrics import Metrics

log = logging.getLogger(__name__)
T = TypeVar("T")

# Outcomes counted in rsmt_work_queue_jobs_total{model, outcome}.
RUN, REJECTED, ABANDONED, SHUT_DOWN = "run", "rejected", "abandoned", "shutting_down"


def shutting_down_error(started: bool = False) -> ServiceError:
    what = ("ran past the shutdown grace and its answer is lost" if started else "was not started")
    return ServiceError("shutting_down", f"the server is shutting down and this request {what}; retry it on another "
                                         "replica (or here once it is back)")


@dataclass(frozen=True)
class Continue(Generic[T]):
    """What a job returns to go on later: ``fn(*args)`` (which may return another) runs on its key's next turn,
    before the key's jobs that wait; its result is the job's."""

    fn: Callable[..., T | Continue[T]]
    args: tuple[Any, ...] = ()


class WorkQueue:
    """Per-key queues of at most ``limit`` waiting jobs each (None: no bound) in front of ``threads`` running ones
    on ``executor``."""

    def __init__(self, executor: Executor, threads: int, limit: int | None, metrics: Metrics | None = None,
                 name: str = "model") -> None:
        self.executor = executor
        self.threads = threads
        self.limit = limit
        self.metrics = metrics
        self.name = name
        self.running = 0
        self.closed = False
        self._waiting: dict[str, deque[asyncio.Future[None]]] = {}  # per owner, oldest first; no empty deque
        self._resuming: dict[str, deque[asyncio.Future[None]]] = {}  # per owner: next slices of started jobs
        self._continuations: dict[asyncio.Future[Any], asyncio.Future[None]] = {}  # a slice -> its next one's ticket
        self._queued_keys: frozenset[str] = frozenset()  # owners with a ticket queued: read by the threads
        self._arrived: dict[asyncio.Future[None], int] = {}  # each waiting ticket's place in the order of arrival
        self._arrivals = 0
        self._running_of: Counter[str] = Counter()  # jobs running per owner
        self._turns = KeyTurns()  # thread time per owner with jobs waiting or running
        self._job_s = 0.05  # moving average of job times, for Retry-After

    @property
    def waiting(self) -> int:
        return sum(len(q) for q in self._waiting.values())

    def waiting_of(self, owner: str) -> int:
        """How many jobs of ``owner`` wait."""
        return len(self._waiting.get(owner, ()))

    def retry_after_s(self, owner: str = ANONYMOUS) -> int:
        """Whole seconds until ``owner``'s queue has likely room again (at least 1): its own waiting jobs, and as
        many of every other key's (their turns come in between), at the recent job time."""
        own = self.waiting_of(owner)
        ahead = sum(min(len(q), max(1, own)) for q in self._waiting.values())
        backlog = (ahead + self.running) * self._job_s / max(1, self.threads)
        return max(1, math.ceil(backlog))

    async def run(self, fn: Callable[..., T | Continue[T]], *args: Any, owner: str = ANONYMOUS,
                  gone: Callable[[], Awaitable[None]] | None = None) -> T:
        """Run ``fn(*args)`` on a thread once ``owner`` (the API key's owner digest, :class:`service.caller.Caller`)
        has its turn, and the slices it returns (:class:`Continue`) on its next turns; ``gone`` (awaitable)
        completes when the caller's client disconnects, in which case a job not yet started raises
        :class:`ClientGone`.

        Raises ``overloaded`` (``owner``'s queue full) or ``shutting_down`` (closed) without waiting.
        """
        refused = self.refusal(owner)
        if refused is not None:
            raise refused
        if self._has_free_thread():
            self.running += 1
        else:
            await self._wait(owner, self._enqueue(self._waiting, owner), gone)
        self._count(RUN)
        thread_s = 0.0
        try:
            # Each slice holds a slot, released exactly once: when it is done on its thread.
            result, ticket, seconds = await self._on_thread(fn, args, owner)
            thread_s += seconds
            while isinstance(result, Continue):
                assert ticket is not None  # queued by _finished before the slot was passed on
                await self._wait(owner, ticket, None)
                result, ticket, seconds = await self._on_thread(result.fn, result.args, owner)
                thread_s += seconds
        except asyncio.CancelledError:
            # uvicorn cancels the requests still running when its graceful shutdown times out: answer them
            # in JSON rather than let the server write a plain-text 500 (a slice runs to its end).
            if self.closed:
                raise shutting_down_error(started=True) from None
            raise
        self._job_s += 0.2 * (thread_s - self._job_s)
        return result

    async def _on_thread(self, fn: Callable[..., T | Continue[T]], args: tuple[Any, ...],
                         owner: str) -> tuple[T | Continue[T], asyncio.Future[None] | None, float]:
        """Run one slice on a thread (the caller holds a slot); its result, the ticket of the next slice when it
        returned :class:`Continue`, and its seconds on the thread."""
        self._running_of[owner] += 1
        turn_s = self._turn_s(owner)
        started = time.perf_counter()
        try:
            future: asyncio.Future[T | Continue[T]] = asyncio.get_running_loop().run_in_executor(
                self.executor, lambda: self._slices(fn, args, owner, turn_s))
        except BaseException:
            self._done(owner, 0.0)
            raise
        future.add_done_callback(lambda f: self._finished(f, owner, started))
        try:
            result = await asyncio.shield(future)
        except asyncio.CancelledError:
            future.add_done_callback(lambda f: self._drop_continuation(owner, f))  # after _finished
            raise
        return result, self._continuations.pop(future, None), time.perf_counter() - started

    def _turn_s(self, owner: str) -> float:
        """How long ``owner``'s job may go on before another key's queued job would have the turn: the thread time
        by which it is behind the least served of them (0 when none is queued: then it yields as soon as one is)."""
        others = self._queued_keys - {owner}
        if not others:
            return 0.0
        self._turns.first([owner, *others])  # each at least at the floor
        return max(0.0, min(self._turns.used[k] for k in others) - self._turns.used[owner])

    def _slices(self, fn: Callable[..., T | Continue[T]], args: tuple[Any, ...], owner: str,
                turn_s: float) -> T | Continue[T]:
        """On a thread: ``fn(*args)``, and the slices it returns while no other key's job is queued or this key's
        turn lasts (``turn_s``): a hop through the event loop would only hand the thread back to this job. The
        first :class:`Continue` past that goes back to the queue."""
        began = time.perf_counter()
        result = fn(*args)
        while isinstance(result, Continue) and (not (self._queued_keys - {owner})
                                                 or time.perf_counter() - began < turn_s):
            result = result.fn(*result.args)
        return result

    def _has_free_thread(self) -> bool:
        return self.running < self.threads and not self._waiting and not self._resuming

    def _full(self, owner: str) -> bool:
        """No free thread and ``limit`` jobs of ``owner`` already waiting: its job arriving now is refused."""
        return self.limit is not None and not self._has_free_thread() and self.waiting_of(owner) >= self.limit

    def refusal(self, owner: str = ANONYMOUS) -> ServiceError | None:
        """The error a job of ``owner`` arriving now would get at once (``shutting_down`` or ``overloaded``),
        counted as refused; None when it would run or wait. For a check before the request's body is read
        (:mod:`service.http.queue_gate`); :meth:`run` checks again, as the queue may fill meanwhile."""
        if self.closed:
            self._count(SHUT_DOWN)
            return shutting_down_error()
        return self.reject(owner) if self._full(owner) else None

    def reject(self, owner: str = ANONYMOUS) -> ServiceError:
        """Count a job of ``owner`` refused for want of room and return its ``overloaded`` error (with
        Retry-After)."""
        self._count(REJECTED)
        wait = self.retry_after_s(owner)
        whose = "requests waiting" if owner == ANONYMOUS else "requests of this API key waiting"
        return ServiceError("overloaded", f"model {self.name!r} already has {self.limit} {whose} (RSMT_QUEUE_LIMIT) "
                                          f"and {self.running} running; retry in about {wait} s, or on another "
                                          "replica", headers={"Retry-After": str(wait)})

    def would_refuse(self, owner: str = ANONYMOUS) -> bool:
        """Whether :meth:`refusal` would refuse a job of ``owner`` now (counts nothing)."""
        return self.closed or self._full(owner)

    def _finished(self, future: asyncio.Future[Any], owner: str, started: float) -> None:
        """A slice is done: queue the job's next slice (if any) first in its key's turn, then pass the slot on."""
        if not future.cancelled() and future.exception() is None and isinstance(future.result(), Continue):
            self._continuations[future] = self._enqueue(self._resuming, owner)
        self._done(owner, time.perf_counter() - started)

    def _drop_continuation(self, owner: str, future: asyncio.Future[Any]) -> None:
        """The caller of a slice was cancelled: its job goes no further, and the next slice's turn is given up."""
        ticket = self._continuations.pop(future, None)
        if ticket is None:
            return
        if ticket.done() and not ticket.cancelled() and ticket.exception() is None:
            self._release()  # granted meanwhile: pass the slot on
        else:
            self._forget(owner, ticket)
            ticket.cancel()

    def _done(self, owner: str, seconds: float) -> None:
        """A job of ``owner`` that held a thread for ``seconds`` is done: charge its key, pass the slot on."""
        self._turns.charge(owner, seconds)
        self._running_of[owner] -= 1
        if self._running_of[owner] <= 0:
            del self._running_of[owner]
        self._turns.tidy([*self._waiting, *self._resuming, *self._running_of])
        self._release()

    def _enqueue(self, queues: dict[str, deque[asyncio.Future[None]]], owner: str) -> asyncio.Future[None]:
        """A new ticket of ``owner``, last in its queue of ``queues`` (``_waiting`` or ``_resuming``)."""
        ticket: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        queues.setdefault(owner, deque()).append(ticket)
        self._arrived[ticket] = self._arrivals
        self._arrivals += 1
        self._changed()
        return ticket

    async def _wait(self, owner: str, ticket: asyncio.Future[None], gone: Callable[[], Awaitable[None]] | None) -> None:
        """Wait until ``ticket`` is granted a slot (:meth:`run` has checked there is room)."""
        watcher = None if gone is None else asyncio.create_task(self._watch(owner, ticket, gone),
                                                                name="work-queue-watch")
        try:
            await ticket
        except BaseException:
            if ticket.done() and not ticket.cancelled() and ticket.exception() is None:
                self._release()  # granted, then cancelled before it could start: pass the slot on
            else:
                self._forget(owner, ticket)
            raise
        finally:
            if watcher is not None:
                watcher.cancel()

    async def _watch(self, owner: str, ticket: asyncio.Future[None], gone: Callable[[], Awaitable[None]]) -> None:
        try:
            await gone()
        except Exception:  # nothing to learn from a broken receive: the job stays queued
            log.debug("watching for a disconnect failed", exc_info=True)
            return
        if not ticket.done():
            self._forget(owner, ticket)
            self._count(ABANDONED)
            ticket.set_exception(ClientGone())

    def _forget(self, owner: str, ticket: asyncio.Future[None]) -> None:
        for queues in (self._waiting, self._resuming):
            queue = queues.get(owner)
            if queue is not None and ticket in queue:
                queue.remove(ticket)
                if not queue:
                    del queues[owner]
        self._arrived.pop(ticket, None)
        self._changed()

    def _release(self) -> None:
        """A running job is done: hand its slot to the first waiting job of the key whose turn it is, or free it."""
        while self._waiting or self._resuming:
            # Each key's next ticket: the next slice of a started job, else its oldest waiting job.
            heads = {k: q[0] for k, q in self._waiting.items()} | {k: q[0] for k, q in self._resuming.items()}
            owner = self._turns.first(sorted(heads, key=lambda k: self._arrived[heads[k]]))
            assert owner is not None
            queues = self._resuming if owner in self._resuming else self._waiting
            ticket = queues[owner].popleft()
            if not queues[owner]:
                del queues[owner]
            self._arrived.pop(ticket, None)
            if not ticket.done():
                ticket.set_result(None)  # the slot passes on; ``running`` is unchanged
                self._changed()
                return
        self.running -= 1
        self._changed()

    def close(self) -> int:
        """Refuse new jobs and answer every waiting one ``shutting_down`` (started ones go on to their end);
        returns how many were waiting."""
        self.closed = True
        dropped = 0
        tickets = [t for queue in self._waiting.values() for t in queue]
        self._waiting.clear()
        for ticket in tickets:
            self._arrived.pop(ticket, None)
            if not ticket.done():
                ticket.set_exception(shutting_down_error())
                dropped += 1
        if dropped:
            self._count(SHUT_DOWN, dropped)
        self._changed()
        return dropped

    def _count(self, outcome: str, n: int = 1) -> None:
        if self.metrics is not None:
            self.metrics.work_jobs.labels(self.name, outcome).inc(n)

    def _changed(self) -> None:
        """The tickets queued changed: the threads' view of which keys wait, and the gauge."""
        self._queued_keys = frozenset(self._waiting) | frozenset(self._resuming)
        if self.metrics is not None:
            self.metrics.work_waiting.labels(self.name).set(self.waiting)


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
