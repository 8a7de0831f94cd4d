"""The asap gate: asap steps fill the gaps between realtime frames and make them late only on their share."""

from __future__ import annotations

import asyncio
import time
from concurrent.futures import ThreadPoolExecutor

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from model.inference.bundle import Bundle
from model.inference.engine import CharacterBatch, Engine
from service.streaming.asap_gate import MARGIN_S, AsapGate
from service.streaming.scheduler import Scheduler
from service.streaming.stream import Stream
from tests.service.conftest import context_clip, target_clip, walk
from tests.service.streaming.test_scheduler import _Outbox


def test_a_step_that_ends_before_the_realtime_frame_may_start_and_one_that_does_not_waits():
    gate = AsapGate(share=0.0)
    assert gate.allows(0.0, None) and gate.allows(0.0, 0.01)  # nothing known of its length yet
    gate.record(0.010, fitted=True)
    assert gate.allows(0.0, 0.010 + MARGIN_S) and not gate.allows(0.0, 0.005)
    assert gate.allows(5.0, None)  # no realtime character: always
    with pytest.raises(ValueError):
        AsapGate(share=1.5)
    with pytest.raises(ValueError):
        gate.record(-1.0, fitted=True)


def _simulate(period: float, rt_step: float, asap_step: float, share: float, seconds: float = 20.0) -> tuple[float, int]:
    """A single-threaded loop as the scheduler runs it, on a clock of its own: realtime ticks every ``period``
    (each ``rt_step`` long, restarting the clock when behind), asap steps of ``asap_step`` when the gate lets
    them. Returns (the realtime frames' rate as a share of real time, the asap steps taken)."""
    gate, now, next_rt, frames, asap = AsapGate(share), 0.0, 0.0, 0, 0
    while now < seconds:
        rt_due = now >= next_rt - 5e-4
        due_next = next_rt + (period if rt_due else 0.0)
        fits = gate.fits(now, due_next)
        go = gate.allows(now, due_next)
        if not (rt_due or go):
            now = next_rt
            continue
        if rt_due:
            now += rt_step
            frames += 1
            next_rt += period
            if next_rt < now - period:
                next_rt = now
        if go:
            now += asap_step
            gate.record(asap_step, fits)
            asap += 1
    return frames * period / seconds, asap


@settings(max_examples=40, deadline=None)
@given(st.floats(0.001, 0.02), st.floats(0.001, 0.2), st.floats(0.0, 0.5))
def test_realtime_keeps_its_speed_but_for_the_share_and_asap_still_moves(rt_step: float, asap_step: float,
                                                                        share: float):
    period = 1 / 30
    speed, asap = _simulate(period, rt_step, asap_step, share)
    # Late asap steps take at most `share` of the time: realtime keeps the rest (less a frame of slack
    # for the first step, whose length is not known, and the clock's restarts).
    assert speed >= 1.0 - share - 0.05
    if asap_step + rt_step + MARGIN_S < period or share > 0:
        assert asap > 0


def test_without_the_gate_one_long_asap_batch_would_slow_realtime():
    # The old loop (asap back to back): a 50 ms asap step behind every 33 ms frame.
    speed, _ = _simulate(1 / 30, 0.002, 0.05, share=1.0)
    assert speed < 0.7


@pytest.fixture(scope="module")
def engine(bundle_dir) -> Engine:
    return Engine(Bundle.load(bundle_dir))


def test_a_slow_asap_batch_waits_while_a_realtime_character_lives(engine, monkeypatch):
    """With share 0, an asap batch whose step is longer than a frame period steps at most once (before its
    length is known) while a realtime character is live, and finishes after it."""
    style, _ = engine.encode_style(walk(60))
    real_step = CharacterBatch.step
    order: list[str] = []
    batches: dict[int, str] = {}

    def step(self: CharacterBatch):
        pace = batches.get(id(self), "?")
        if pace == "asap":
            time.sleep(0.06)  # longer than the 33 ms between realtime frames
        order.append(pace)
        return real_step(self)

    monkeypatch.setattr(CharacterBatch, "step", step)

    async def main() -> None:
        with ThreadPoolExecutor(1) as pool:
            sched = Scheduler(engine, pool, name="t", asap_share=0.0)
            for pace, batch in sched._batches.items():
                batches[id(batch)] = pace
            sched.start()
            rt_box, asap_box = _Outbox(capacity=1000), _Outbox(capacity=1000)
            rt = Stream(character=engine.prepare(context_clip(), target_clip(), 20, style, seed=1), outbox=rt_box,
                        slot=0, pace="realtime", fps=30.0, encoding="json")
            fast = Stream(character=engine.prepare(context_clip(), target_clip(), 10, style, seed=2), outbox=asap_box,
                          slot=1, pace="asap", fps=30.0, encoding="json")
            sched.add(rt)
            await asyncio.sleep(0.1)  # the realtime character is live first
            sched.add(fast)
            deadline = asyncio.get_running_loop().time() + 30
            while not (rt.ended and fast.ended):
                assert asyncio.get_running_loop().time() < deadline, "the characters never ended"
                await asyncio.sleep(0.02)
            await sched.stop()
            assert rt_box.frames == list(range(20)) and asap_box.frames == list(range(10))

    asyncio.run(main())
    last_rt = max(i for i, p in enumerate(order) if p == "realtime")
    assert order[:last_rt].count("asap") <= 1, order
