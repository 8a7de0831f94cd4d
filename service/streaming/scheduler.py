"""Per-step batching across streams: one background task per model advances every live character of
every connection with one batched engine step per tick.

Characters are grouped by pace, each group in one :class:`~model.inference.engine.CharacterBatch`:

* ``realtime`` characters step together once per frame period (1 / model fps), on a fixed clock;
* ``asap`` characters step together back to back, as fast as the engine goes, while any waits, but
  never so as to make a realtime frame late beyond a small share of the time
  (:mod:`service.streaming.asap_gate`).

With per-key step shares on (:mod:`service.streaming.step_shares`, the default with API keys), each
key's characters step in batches of their own (:mod:`service.streaming.lanes`) and the key that has
used the least step time goes first, so one key's many characters cannot slow another key's few.

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
waits on a future. Commands from connections (:mod:`service.streaming.commands`) are queued on the
loop and applied at the start of the next tick, before its step.
"""

from __future__ import annotations

import asyncio
import logging
import time
from concurrent.futures import Executor
from dataclasses import dataclass, field

import numpy as np

from model.inference.engine import CharacterBatch, EncodedStyle, Engine
from model.inference.errors import EngineError
from model.motion.clip import Clip
from service.errors import ServiceError, from_engine
from service.metrics import Metrics
from service.streaming.asap_gate import AsapGate
from service.streaming.commands import Add, Command, Park, Remove, Request, Retarget, SetStyle, Unpark
from service.streaming.frames import encode_binary, encode_json
from service.streaming.lanes import Lanes
from service.streaming.step_shares import StepShares
from service.streaming.stream import PACES, Stream

log = logging.getLogger(__name__)


@dataclass
class _Tick:
    frames: list[tuple[Stream, int, str | bytes, bool]] = field(default_factory=list)
    replies: list[tuple[asyncio.Future[int], int | ServiceError]] = field(default_factory=list)
    failed: list[tuple[Stream, str]] = field(default_factory=list)
    steps: list[tuple[str, int, int, float, float]] = field(default_factory=list)  # pace, live rows, rows, s, CPU s
    charges: list[tuple[str, str, float]] = field(default_factory=list)  # owner, pace, step seconds


@dataclass
class _Plan:
    """What one tick steps: the keys whose realtime lanes step (first one always, the others only while
    they end before ``deadline``, a ``time.monotonic()``), and the key whose next asap lane steps."""

    realtime: list[str] = field(default_factory=list)
    deadline: float | None = None
    asap: str | None = None


class Scheduler:
    """The stepping loop of one model. Create, :meth:`start` on the event loop, :meth:`stop` at shutdown."""

    def __init__(self, engine: Engine, executor: Executor, metrics: Metrics | None = None, name: str = "model",
                 asap_share: float = 0.1, shares: StepShares | None = None) -> None:
        self.engine = engine
        self._gate = AsapGate(asap_share)  # owned by the event loop
        self._shares = shares or StepShares(enabled=False)  # owned by the event loop
        self.name = name
        self.fps = float(engine.config.fps)
        self.metrics = metrics
        self._executor = executor
        # Owned by the step thread.
        self._lanes = Lanes(engine, self._shares.rows)
        self._parked: set[int] = set()  # id() of characters detached for flow control
        self._streams_of: dict[int, Stream] = {}
        # Owned by the event loop.
        self.streams: dict[str, set[Stream]] = {p: set() for p in PACES}
        self._commands: list[Command] = []
        self._wake = asyncio.Event()
        self._task: asyncio.Task | None = None
        self._closed = False
        self.ticks = 0

    @property
    def _batches(self) -> dict[str, CharacterBatch]:
        """The first lane of each pace: the only one with per-key shares off."""
        return {p: self._lanes.first(p) for p in PACES}

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
        self._push(Add(stream=stream))
        self._gauge()

    def drop(self, stream: Stream) -> None:
        """Stop a character (cancel or disconnect); frames already generated for it are discarded."""
        if stream.ended:
            return
        stream.ended = True
        stream.cancelled = True
        self.streams[stream.pace].discard(stream)
        self._push(Remove(stream=stream))
        self._gauge()

    def park(self, stream: Stream, now: float) -> None:
        if stream.parked or stream.ended:
            return
        stream.parked_at = now
        self._push(Park(stream=stream))

    def unpark(self, stream: Stream) -> None:
        if not stream.parked:
            return
        stream.parked_at = None
        if not stream.ended:
            self._push(Unpark(stream=stream))

    async def retarget(self, stream: Stream, target: Clip | None, frames: int | None) -> int:
        """Apply a new target and/or length from the next frame; returns that frame's ``seq``."""
        reply: asyncio.Future[int] = asyncio.get_running_loop().create_future()
        self._push(Retarget(stream=stream, reply=reply, target=target, frames=frames))
        return await reply

    async def set_style(self, stream: Stream, style: EncodedStyle) -> int:
        """Switch a character's style from the next frame; returns that frame's ``seq``."""
        reply: asyncio.Future[int] = asyncio.get_running_loop().create_future()
        self._push(SetStyle(stream=stream, reply=reply, style=style))
        return await reply

    def _push(self, command: Command) -> None:
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
            commands: list[Command] = []
            try:
                now = loop.time()
                next_rt, rt_due, asap_fits, plan = self._plan(now, next_rt, period)
                asap_go = plan.asap is not None
                if not (rt_due or asap_go or self._commands):
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
                if plan.deadline is not None:  # the loop's clock to the step thread's
                    plan.deadline += time.monotonic() - loop.time()
                result = await loop.run_in_executor(self._executor, self._tick, commands, plan)
                self._charge(result, asap_fits)
                if rt_due and next_rt is not None:
                    next_rt += period
                    if next_rt < loop.time() - period:  # fell behind: restart the clock, never burst
                        next_rt = loop.time()
                self._deliver(result, loop.time())
                self.ticks += 1
                self._observe(result, loop.time() - started)
                if asap_go:
                    await asyncio.sleep(0)  # let connections send between back-to-back ticks
            except Exception:  # the loop must survive anything a tick throws
                log.exception("scheduler %s: tick failed", self.name)
                for command in commands:  # nobody may wait forever for a reply
                    if isinstance(command, Request) and not command.reply.done():
                        command.reply.set_exception(
                            ServiceError("internal", f"{command.kind} failed; the server log has the details"))
                await asyncio.sleep(period)

    def _plan(self, now: float, next_rt: float | None, period: float) -> tuple[float | None, bool, bool, _Plan]:
        """What a tick at ``now`` steps: ``(next realtime time, realtime due, an asap step fits, the plan)``."""
        owner = self._shares.owner
        waiting = {p: {owner(s.owner) for s in self.streams[p] if not s.parked} for p in PACES}
        self._shares.keep(owner(s.owner) for p in PACES for s in self.streams[p])
        if not waiting["realtime"]:
            next_rt = None
        elif next_rt is None:
            next_rt = now
        rt_due = next_rt is not None and now >= next_rt - 5e-4
        # When the next realtime frame is due: an asap step of this tick must end before it.
        due_next = None if next_rt is None else next_rt + (period if rt_due else 0.0)
        plan = _Plan()
        if rt_due:
            plan.realtime, plan.deadline = self._shares.order(waiting["realtime"]), due_next
        first = self._shares.first(waiting["asap"])
        estimate = None if first is None else self._shares.estimate(first)
        fits = self._gate.fits(now, due_next, estimate)
        if first is not None and self._gate.allows(now, due_next, estimate):
            plan.asap = first
        return next_rt, rt_due, fits, plan

    def _charge(self, result: _Tick, asap_fits: bool) -> None:
        """Count each step against its key's share, and asap steps against the asap gate's budget."""
        for owner, pace, seconds in result.charges:
            self._shares.charge(owner, seconds, asap=pace == "asap")
            if pace == "asap":
                self._gate.record(seconds, asap_fits)

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
        for reply, value in result.replies:
            if reply.done():
                continue
            if isinstance(value, ServiceError):
                reply.set_exception(value)
            else:
                reply.set_result(value)
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
    def _tick(self, commands: list[Command], plan: _Plan) -> _Tick:
        result = _Tick()
        changed: set[int] = set()  # id() of lanes whose membership changed: they restack anyway
        for command in commands:
            self._apply(command, result, changed)
        for ch in self._lanes.sweep():  # lanes left with ended characters only, which no plan may step again
            self._streams_of.pop(id(ch), None)
        for i, owner in enumerate(plan.realtime):
            for lane in self._lanes.in_turn("realtime", owner):
                # The least served key's lanes always step; the others' only while they end in time (a key
                # left out uses nothing, so it soon is the least served one).
                if i and plan.deadline is not None and time.monotonic() + self._lanes.seconds(lane) > plan.deadline:
                    continue
                self._prune_and_step("realtime", owner, lane, changed, result)
        if plan.asap is not None:
            for lane in self._lanes.in_turn("asap", plan.asap)[:1]:
                self._prune_and_step("asap", plan.asap, lane, changed, result)
        return result

    def _prune_and_step(self, pace: str, owner: str, lane: CharacterBatch, changed: set[int], result: _Tick) -> None:
        self._prune(lane, id(lane) in changed)
        if len(lane):
            self._step(pace, owner, lane, result)

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
            dropped = batch.drop_finished()
            for ch in dropped:
                self._streams_of.pop(id(ch), None)
            self._lanes.forget(dropped)

    def _apply(self, command: Command, result: _Tick, changed: set[int]) -> None:
        """Apply one command; a request's reply (or the error that refused it) goes into ``result``."""
        try:
            if isinstance(command, Request):
                result.replies.append((command.reply, self._answer(command)))
            else:
                self._change_membership(command, changed)
        except EngineError as exc:
            if isinstance(command, Request):
                result.replies.append((command.reply, from_engine(exc)))
        except Exception as exc:  # a failed command must not take the batch down with it
            log.exception("scheduler %s: %s of character %s failed", self.name, command.kind, command.stream.id)
            if isinstance(command, Request):
                result.replies.append((command.reply, ServiceError("internal", f"{command.kind} failed: {exc}")))

    def _change_membership(self, command: Command, changed: set[int]) -> None:
        """Add, remove, park or unpark a character; its lane goes into ``changed`` when it will restack."""
        stream = command.stream
        ch = stream.character
        owner = self._shares.owner(stream.owner)
        key = id(ch)
        if isinstance(command, Add):
            self._streams_of[key] = stream
            if not ch.cancelled:
                changed.add(id(self._lanes.add(ch, stream.pace, owner)))
        elif isinstance(command, Remove):
            ch.cancelled = True
            if key in self._parked:
                self._parked.discard(key)
                self._streams_of.pop(key, None)
            elif self._lanes.withdraw(ch):  # cancelled before its first step: nothing of it is kept
                self._streams_of.pop(key, None)
        elif isinstance(command, Park):
            if not ch.done and key not in self._parked:
                lane = self._lanes.detach(ch)
                self._parked.add(key)
                if lane is not None:
                    changed.add(id(lane))
        elif isinstance(command, Unpark) and key in self._parked:
            self._parked.discard(key)
            if not ch.done:
                changed.add(id(self._lanes.add(ch, stream.pace, owner)))

    def _answer(self, request: Request) -> int | ServiceError:
        """Apply a retarget or a style change; the ``seq`` of the first frame it affects."""
        ch = request.stream.character
        if ch.done:
            return ServiceError("unknown_character", f"character {ch.id!r} has already ended")
        batch = None if id(ch) in self._parked else self._lanes.lane_of(ch)
        if isinstance(request, Retarget):
            self.engine.retarget(ch, batch, target=request.target, frames=request.frames)
        elif isinstance(request, SetStyle):
            self.engine.set_style(ch, request.style, batch)
        return ch.seq

    def _step(self, pace: str, owner: str, batch: CharacterBatch, result: _Tick) -> None:
        started, cpu_started = time.perf_counter(), time.thread_time()
        try:
            out = batch.step()
        except Exception:
            log.exception("scheduler %s: the %s batch failed to step; ending its characters", self.name, pace)
            for ch in self._lanes.replace(batch):
                stream = self._streams_of.get(id(ch))
                if stream is not None:
                    result.failed.append((stream, "the model failed to generate a frame; start again"))
            return
        seconds, cpu = time.perf_counter() - started, time.thread_time() - cpu_started
        self._lanes.record(batch, seconds)
        result.charges.append((owner, pace, seconds))
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
        for i, (s, ch) in enumerate(zip(streams, chars, strict=True)):
            payload = payloads[i]
            if payload is None:
                payload = encode_json(s.id, s.slot, int(seqs[i]), float(t[i]), int(remaining[i]), roots[i], rotations[i])
            result.frames.append((s, int(seqs[i]), payload, ch.done))

