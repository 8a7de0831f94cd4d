"""Per-step batching across streams: one background task per model advances every live character of
every connection with one batched engine step per tick.

Characters are grouped by pace, each group in one :class:`~model.inference.engine.CharacterBatch`:

* ``realtime`` characters step together once per frame period (1 / model fps), on a fixed clock;
* ``asap`` characters step together back to back, as fast as the engine goes, while any waits.

So a tick is one ``step()`` of one batch; only when both groups are due at the same moment does a
tick make two calls. Keeping the groups in separate batches (rather than one batch stepped at the
asap rate with realtime members paused in between) matters because every membership change
restacks the batch's tensors, the per-character style attention keys included: a third of a step
at 64 characters, two fifths at 256 (measured: docs/service.md).

Flow control: a character whose connection has ``send_queue_frames`` of its frames unsent is
*parked*: taken out of its batch with its state kept (``CharacterBatch.detach``), and put back
once half of them are sent. The generator therefore never runs further ahead than the queue.

Threads: every engine call of a tick (commands, the step, frame encoding) runs in the model's
single step thread, so the batches are only ever touched by that thread and the event loop only
waits on a future. Commands from connections are queued on the loop and applied at the start of
the next tick, before its step.
"""

from __future__ import annotations

import asyncio
import logging
import time
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from model.inference.engine import Character, CharacterBatch, EncodedStyle, Engine, EngineError
from model.motion.clip import Clip
from service.errors import ServiceError
from service.frames import encode_binary, encode_json
from service.metrics import Metrics

log = logging.getLogger(__name__)
PACES = ("realtime", "asap")


class Outbox(Protocol):
    """What a connection offers the scheduler (implemented by :class:`service.connection.Connection`)."""

    encoding: str

    def deliver_frame(self, stream: Stream, seq: int, payload: str | bytes, now: float) -> None: ...

    def deliver_end(self, stream: Stream, reason: str) -> None: ...

    def deliver_failure(self, stream: Stream, message: str) -> None: ...


@dataclass(eq=False)
class Stream:
    """One streamed character: the engine's :class:`Character` plus its connection, slot and pacing.

    Fields below ``pace`` belong to the event loop; the step thread reads only the first ones.
    """

    character: Character
    outbox: Outbox
    slot: int
    pace: str
    fps: float
    encoding: str
    queued: int = 0  # frames generated and not yet sent
    sent: int = 0
    parked_at: float | None = None  # loop time it was parked for a full queue
    start_time: float | None = None  # loop time frame 0 was due
    ended: bool = False  # no more frames are taken (arrived, cancelled or dropped)
    cancelled: bool = False
    scheduler: Scheduler | None = None  # set by Scheduler.add
    model: str = ""
    last_due: float = 0.0

    @property
    def id(self) -> str:
        return self.character.id

    @property
    def parked(self) -> bool:
        return self.parked_at is not None

    def due(self, seq: int, now: float) -> float:
        """Loop time at which frame ``seq`` should leave: now for asap; on the fps clock for realtime.

        A realtime frame generated more than one frame period late moves the clock instead of
        bursting: the client gets it at once and the following ones one period apart.
        """
        if self.pace == "asap":
            return now
        period = 1.0 / self.fps
        if self.start_time is None:
            self.start_time = now - seq * period
        due = self.start_time + seq * period
        late = now - due
        if late > period:
            self.start_time += late - period
            due = now - period
        return due


@dataclass
class _Tick:
    frames: list[tuple[Stream, int, str | bytes, bool]] = field(default_factory=list)
    replies: list[tuple[asyncio.Future, Any]] = field(default_factory=list)
    failed: list[tuple[Stream, str]] = field(default_factory=list)
    steps: list[tuple[str, int, int, float, float]] = field(default_factory=list)  # pace, live rows, rows, s, CPU s


class Scheduler:
    """The stepping loop of one model. Create, :meth:`start` on the event loop, :meth:`stop` at shutdown."""

    def __init__(self, engine: Engine, executor: Executor, metrics: Metrics | None = None, name: str = "model") -> None:
        self.engine = engine
        self.name = name
        self.fps = float(engine.config.fps)
        self.metrics = metrics
        self._executor = executor
        # Owned by the step thread.
        self._batches = {p: CharacterBatch(engine) for p in PACES}
        self._parked: set[int] = set()  # id() of characters detached for flow control
        self._streams_of: dict[int, Stream] = {}
        # Owned by the event loop.
        self.streams: dict[str, set[Stream]] = {p: set() for p in PACES}
        self._commands: list[tuple] = []
        self._wake = asyncio.Event()
        self._task: asyncio.Task | None = None
        self._closed = False
        self.ticks = 0

    # ------------------------------------------------------------------ loop-side API
    @property
    def live(self) -> int:
        return sum(len(s) for s in self.streams.values())

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._run(), name=f"scheduler:{self.name}")

    async def stop(self) -> None:
        self._closed = True
        self._wake.set()
        if self._task is not None:
            await self._task

    def add(self, stream: Stream) -> None:
        """Start stepping a prepared character from the next tick on."""
        if stream.pace not in PACES:
            raise ValueError(f"unknown pace {stream.pace!r}")
        stream.scheduler = self
        stream.model = self.name
        self.streams[stream.pace].add(stream)
        self._push(("add", stream))
        self._gauge()

    def drop(self, stream: Stream) -> None:
        """Stop a character (cancel or disconnect); frames already generated for it are discarded."""
        if stream.ended:
            return
        stream.ended = True
        stream.cancelled = True
        self.streams[stream.pace].discard(stream)
        self._push(("remove", stream))
        self._gauge()

    def park(self, stream: Stream, now: float) -> None:
        if stream.parked or stream.ended:
            return
        stream.parked_at = now
        self._push(("park", stream))

    def unpark(self, stream: Stream) -> None:
        if not stream.parked:
            return
        stream.parked_at = None
        if not stream.ended:
            self._push(("unpark", stream))

    async def retarget(self, stream: Stream, target: Clip | None, frames: int | None) -> int:
        """Apply a new target and/or length from the next frame; returns that frame's ``seq``."""
        fut = asyncio.get_running_loop().create_future()
        self._push(("retarget", stream, target, frames, fut))
        return await fut

    async def set_style(self, stream: Stream, style: EncodedStyle) -> int:
        """Switch a character's style from the next frame; returns that frame's ``seq``."""
        fut = asyncio.get_running_loop().create_future()
        self._push(("style", stream, style, fut))
        return await fut

    def _push(self, command: tuple) -> None:
        self._commands.append(command)
        self._wake.set()

    def _gauge(self) -> None:
        if self.metrics is not None:
            self.metrics.live_characters.labels(self.name).set(self.live)

    # ------------------------------------------------------------------ the loop
    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        period = 1.0 / self.fps
        next_rt: float | None = None
        while not self._closed:
            commands: list[tuple] = []
            try:
                now = loop.time()
                rt_live = any(not s.parked for s in self.streams["realtime"])
                asap_live = any(not s.parked for s in self.streams["asap"])
                if not rt_live:
                    next_rt = None
                elif next_rt is None:
                    next_rt = now
                rt_due = rt_live and next_rt is not None and now >= next_rt - 5e-4
                if not (rt_due or asap_live or self._commands):
                    self._wake.clear()
                    timeout = None if next_rt is None else max(0.0, next_rt - now)
                    try:
                        async with asyncio.timeout(timeout):
                            await self._wake.wait()
                    except TimeoutError:
                        pass
                    continue
                commands, self._commands = self._commands, []
                started = loop.time()
                result = await loop.run_in_executor(self._executor, self._tick, commands, rt_due, asap_live)
                if rt_due and next_rt is not None:
                    next_rt += period
                    if next_rt < loop.time() - period:  # fell behind: restart the clock, never burst
                        next_rt = loop.time()
                self._deliver(result, loop.time())
                self.ticks += 1
                self._observe(result, loop.time() - started)
                if asap_live:
                    await asyncio.sleep(0)  # let connections send between back-to-back ticks
            except Exception:  # the loop must survive anything a tick throws
                log.exception("scheduler %s: tick failed", self.name)
                for command in commands:  # nobody may wait forever for a reply
                    fut = command[-1]
                    if isinstance(fut, asyncio.Future) and not fut.done():
                        fut.set_exception(ServiceError("internal", f"{command[0]} failed; the server log has the details"))
                await asyncio.sleep(period)

    def _observe(self, result: _Tick, tick_s: float) -> None:
        if self.metrics is None:
            return
        step_total = 0.0
        for pace, live, rows, seconds, cpu in result.steps:
            self.metrics.batch_size.labels(self.name, pace).observe(rows)
            self.metrics.step_seconds.labels(self.name, pace).observe(seconds)
            self.metrics.step_cpu_seconds.labels(self.name).inc(cpu)
            self.metrics.frames_generated.labels(self.name, pace).inc(live)
            step_total += seconds
        if result.steps:
            self.metrics.tick_overhead_seconds.labels(self.name).observe(max(0.0, tick_s - step_total))

    def _deliver(self, result: _Tick, now: float) -> None:
        for fut, value in result.replies:
            if fut.done():
                continue
            if isinstance(value, BaseException):
                fut.set_exception(value)
            else:
                fut.set_result(value)
        for stream, message in result.failed:
            if not stream.ended:
                self.drop(stream)
                stream.outbox.deliver_failure(stream, message)
        for stream, seq, payload, done in result.frames:
            if stream.ended:
                continue
            stream.outbox.deliver_frame(stream, seq, payload, now)
            if done:
                stream.ended = True
                self.streams[stream.pace].discard(stream)
                stream.outbox.deliver_end(stream, "arrived")
        if result.frames or result.failed:
            self._gauge()

    # ------------------------------------------------------------------ the step thread
    def _tick(self, commands: list[tuple], step_realtime: bool, step_asap: bool) -> _Tick:
        result = _Tick()
        changed: set[str] = set()  # paces whose membership changed: their batch restacks anyway
        for command in commands:
            self._apply(command, result, changed)
        for pace, due in (("realtime", step_realtime), ("asap", step_asap)):
            batch = self._batches[pace]
            if due and len(batch):
                self._prune(batch, pace in changed)
                if len(batch):
                    self._step(pace, batch, result)
        return result

    def _prune(self, batch: CharacterBatch, restacking: bool) -> None:
        """Drop ended characters, but only when it pays.

        Every membership change restacks the batch (the style keys and values of every member are
        copied), a third of a step's time at 64 characters. Ended characters are therefore
        left in the batch (stepped, their output ignored) until a restack happens anyway (a
        character joined or was parked this tick) or they make up a quarter of the batch.
        Unpruned rows cost a share of the step, never a restack.
        """
        done = [m for m in batch.members if m.done]
        # Exact-arrival characters are never left in: their correction is computed on every step.
        if done and (restacking or 4 * len(done) >= len(batch.members) or any(m.arrival is not None for m in done)):
            for ch in batch.drop_finished():
                self._streams_of.pop(id(ch), None)

    def _apply(self, command: tuple, result: _Tick, changed: set[str]) -> None:
        kind, stream = command[0], command[1]
        ch = stream.character
        batch = self._batches[stream.pace]
        try:
            if kind == "add":
                self._streams_of[id(ch)] = stream
                if not ch.cancelled:
                    batch.add(ch)
                    changed.add(stream.pace)
            elif kind == "remove":
                ch.cancelled = True
                if id(ch) in self._parked:
                    self._parked.discard(id(ch))
                    self._streams_of.pop(id(ch), None)
            elif kind == "park":
                if not ch.done and id(ch) not in self._parked:
                    batch.detach(ch)
                    self._parked.add(id(ch))
                    changed.add(stream.pace)
            elif kind == "unpark":
                if id(ch) in self._parked:
                    self._parked.discard(id(ch))
                    if not ch.done:
                        batch.add(ch)
                        changed.add(stream.pace)
            elif kind == "retarget":
                target, frames, fut = command[2], command[3], command[4]
                if ch.done:
                    result.replies.append((fut, ServiceError("unknown_character", f"character {ch.id!r} has already ended")))
                    return
                self.engine.retarget(ch, None if id(ch) in self._parked else batch, target=target, frames=frames)
                result.replies.append((fut, ch.seq))
            elif kind == "style":
                style, fut = command[2], command[3]
                if ch.done:
                    result.replies.append((fut, ServiceError("unknown_character", f"character {ch.id!r} has already ended")))
                    return
                if id(ch) in self._parked:
                    ch.style = style
                else:
                    batch.set_style(ch, style)
                result.replies.append((fut, ch.seq))
        except EngineError as exc:
            if len(command) > 2 and isinstance(command[-1], asyncio.Future):
                result.replies.append((command[-1], ServiceError(exc.code, str(exc))))
        except Exception as exc:  # a failed command must not take the batch down with it
            log.exception("scheduler %s: %s of character %s failed", self.name, kind, ch.id)
            if len(command) > 2 and isinstance(command[-1], asyncio.Future):
                result.replies.append((command[-1], ServiceError("internal", f"{kind} failed: {exc}")))

    def _step(self, pace: str, batch: CharacterBatch, result: _Tick) -> None:
        started, cpu_started = time.perf_counter(), time.thread_time()
        try:
            out = batch.step()
        except Exception:
            log.exception("scheduler %s: the %s batch failed to step; ending its characters", self.name, pace)
            for ch in list(batch.members):
                stream = self._streams_of.get(id(ch))
                if stream is not None:
                    result.failed.append((stream, "the model failed to generate a frame; start again"))
            self._batches[pace] = CharacterBatch(self.engine)
            return
        seconds, cpu = time.perf_counter() - started, time.thread_time() - cpu_started
        # Rows of characters that had ended before this step (kept until a prune) are ignored.
        live = [i for i, ch in enumerate(out.characters) if not ch.cancelled and out.seq[i] < ch.frames_total]
        result.steps.append((pace, len(live), len(out.characters), seconds, cpu))
        if not live:
            return
        chars = [out.characters[i] for i in live]
        streams = [self._streams_of[id(ch)] for ch in chars]
        idx = np.asarray(live)
        rotations = out.rotations.numpy()[idx]
        roots = out.root_positions.numpy()[idx]
        seqs = np.asarray(out.seq, dtype=np.int64)[idx]
        remaining = np.asarray([ch.frames_total - ch.seq for ch in chars], dtype=np.int64)
        t = (seqs + 1) / self.fps
        n = len(chars)
        binary = [i for i, s in enumerate(streams) if s.encoding == "binary"]
        payloads: list[str | bytes | None] = [None] * n
        if binary:
            rows = np.asarray(binary)
            slots = np.asarray([streams[i].slot for i in binary])
            encoded = encode_binary(slots, seqs[rows], t[rows], roots[rows], rotations[rows], remaining[rows])
            for i, data in zip(binary, encoded, strict=True):
                payloads[i] = data
        for i, s in enumerate(streams):
            if payloads[i] is None:
                payloads[i] = encode_json(s.id, s.slot, int(seqs[i]), float(t[i]), int(remaining[i]), roots[i], rotations[i])
        for i, (s, ch) in enumerate(zip(streams, chars, strict=True)):
            result.frames.append((s, int(seqs[i]), payloads[i], ch.done))  # type: ignore[arg-type]

