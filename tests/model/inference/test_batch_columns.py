"""The batch owns a live character's inputs: the steps declare the columns they read, the batch stacks them from its
members' caps and requests, a retarget or a style switch hands it a new frozen request, and a waiting character joins
only when the batch admits it (never as a side effect of reading a row)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.inference.character import Limits
from model.inference.character_batch import CharacterBatch
from model.inference.engine import Engine
from model.inference.output.floor_contact import LIFT_CAP
from model.inference.output.foot_plant import PLANT_CAP
from model.inference.output.smoothing import SPEED_CAP
from model.inference.output.steering import RETARGETED
from model.motion.gait_limits import GaitLimits, StyleGait
from tests.model.inference.test_speed_cap import FAST, FPS, SLOW, _bundle

# Two styles' capture limits: speed (cm/s), then their feet's lift and planted rise (cm).
LIMITS = GaitLimits({"slow": StyleGait(SLOW, SLOW * 0.9, {"walk": (80.0, 95.0)}, 3, 9.0, 2.0),
                     "fast": StyleGait(FAST, FAST * 0.9, {"walk": (80.0, 95.0)}, 3, 14.0, 4.0)}, "test", FPS)


def _engine() -> Engine:
    bundle = _bundle(LIMITS)
    bundle.output = dataclasses.replace(bundle.output, foot_plant=True)
    return Engine(bundle, compiled=False)


def test_the_steps_declare_the_columns_they_read_and_each_is_a_cap_or_the_retarget_flag() -> None:
    engine = _engine()
    assert engine.pipeline.frame.columns == (SPEED_CAP, LIFT_CAP, PLANT_CAP)  # smoothing, floor contact, foot plant
    assert engine.pipeline.loop_columns == (RETARGETED, SPEED_CAP)  # steering, the speed cap
    assert not set(engine.pipeline.frame.columns) & set(engine.pipeline.frame.memory_keys)  # inputs, not memory
    caps = {f.name for f in dataclasses.fields(Limits)}
    assert set(engine.pipeline.loop_columns + engine.pipeline.frame.columns) == caps | {RETARGETED}


def test_a_style_switch_and_a_retarget_hand_the_batch_a_new_request_and_its_columns() -> None:
    walk = synthetic_walk(frames=120)
    engine = _engine()
    slow, _ = engine.encode_style(walk.window(0, 60))
    slow.gait = "slow"
    fast = dataclasses.replace(slow, gait="fast")
    ch = engine.prepare(walk.window(0, 10), walk.window(40, 42), 30, slow, seed=1)
    assert ch.limits == Limits(SLOW / FPS, 9.0, 2.0)
    batch = CharacterBatch(engine)
    batch.add(ch)
    columns = batch.stacked()[4]
    assert [columns[k].tolist() for k in (SPEED_CAP, LIFT_CAP, PLANT_CAP)] == [[pytest.approx(SLOW / FPS)], [9.0], [2.0]]
    asked = ch.request
    engine.set_style(ch, fast, batch)
    assert ch.request is not asked and asked.style is slow and ch.request.style is fast  # a new request, the old kept
    with pytest.raises(dataclasses.FrozenInstanceError):
        ch.request.frames = 5  # type: ignore[misc]
    columns = batch.stacked()[4]  # restacked from the new style's caps
    assert [columns[k].tolist() for k in (SPEED_CAP, LIFT_CAP, PLANT_CAP)] == [[pytest.approx(FAST / FPS)], [14.0], [4.0]]
    batch.step()
    engine.retarget(ch, batch, frames=12)
    assert ch.request.frames == 13 and ch.remaining == 12 and not ch.request.retargeted
    engine.retarget(ch, batch, target=walk.window(60, 62))
    assert ch.request.retargeted and ch.request.frames == 13 and ch.request.style is fast


def test_a_waiting_character_joins_when_the_batch_admits_it_not_when_a_row_is_read() -> None:
    walk = synthetic_walk(frames=120)
    engine = _engine()
    style, _ = engine.encode_style(walk.window(0, 60))
    ch = engine.prepare(walk.window(0, 10), walk.window(40, 42), 20, style, seed=1)
    batch = CharacterBatch(engine)
    batch.add(ch)
    with pytest.raises(ValueError, match="admit"):
        batch.row_of(ch)
    assert batch.members == [] and ch.parked is not None and ch.parked.prepared is not None  # waiting, not warmed up
    batch.admit()
    assert batch.members == [ch] and ch.parked is None  # the batch holds its live part now
    assert batch.row_of(ch).tta.tolist() == [20]
    torch.testing.assert_close(batch.stacked()[4][PLANT_CAP], torch.tensor([4.0]))  # a clip's style: the largest


def test_the_batch_takes_a_live_part_whole_gives_it_back_whole_and_a_retarget_hands_over_a_new_aim() -> None:
    walk = synthetic_walk(frames=120)
    engine = _engine()
    style, _ = engine.encode_style(walk.window(0, 60))
    template = engine.prepare(walk.window(0, 10), walk.window(20, 22), 16, style, seed=1, exact_arrival=True)
    shared = template.parked
    assert shared is not None and shared.prepared is not None and template.aim.bent_to is not None  # in reach
    ch = template.replica("a")  # shares the template's Parked
    batch = CharacterBatch(engine)
    batch.add(ch)
    for _ in range(10):  # into exact arrival's window: its memory is written from here on
        batch.step()
    assert ch.parked is None and template.parked is shared and shared.arrival.progress is None  # the shared part as was
    batch.detach(ch)
    back = ch.parked
    assert back is not None and back.prepared is None and back.row is not None and back.arrival.progress is not None
    torch.testing.assert_close(back.frame.origin, shared.frame.origin, rtol=0, atol=0)  # fixed when it started
    tta, aim = back.row.tta.clone(), ch.aim
    reach = engine.retarget(ch, target=walk.window(30, 32), frames=8)  # out of a batch: on the part it holds
    assert ch.aim is not aim and ch.aim.reach is reach and ch.aim.arrival is not aim.arrival
    assert ch.parked is not back and torch.equal(back.row.tta, tta)  # a new row in a new part; the old one as was
    assert ch.parked is not None and ch.parked.row is not None and ch.parked.row.tta.tolist() == [8]
    batch.add(ch)
    batch.admit()
    assert ch.parked is None and batch.row_of(ch).tta.tolist() == [8]
