"""The motion database: quantised poses that decode to the capture's within a hair, files that round-trip and refuse
another rig, and the build from a data set's train split that keeps to its byte budget and leaves standing takes out."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.data.database_build import TRIM, build_database
from model.data.preprocessed import load_motion_cache
from model.data.synthetic import synthetic_skeleton, synthetic_walk, write_synthetic_dataset
from model.motion.rotations import quat_normalize
from model.retrieval.database import DATABASE_META, DatabaseError, MotionDatabase, bytes_per_frame


def _db() -> MotionDatabase:
    walks = [synthetic_walk(frames=90, turn_deg_s=t) for t in (0.0, 20.0, -20.0)]
    segments = [(w.rotations, w.root_positions + torch.tensor([300.0, 0.0, -50.0]), style, "walk")
                for w, style in zip(walks, ("slow", "fast", "slow"))]
    return MotionDatabase.from_segments(walks[0].skeleton, 30.0, segments, "three synthetic walks")


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(lambda q: sum(x * x for x in q) > 1e-3))
def test_a_quaternion_decodes_to_the_same_rotation_within_three_tenths_of_a_degree(q: list[float]) -> None:
    sk = synthetic_skeleton()
    rot = quat_normalize(torch.tensor(q, dtype=torch.float64)).expand(2, sk.num_joints, 4).float()
    db = MotionDatabase.from_segments(sk, 30.0, [(rot, torch.zeros(2, 3), "s", "walk")])
    back = db.local_rotations()
    angle = 2 * torch.acos((back * rot).sum(-1).abs().clamp(max=1.0))
    assert float(angle.max()) < math.radians(0.3)


def test_roots_are_kept_to_the_millimetre_relative_to_their_segment() -> None:
    db = _db()
    walk = synthetic_walk(frames=90, turn_deg_s=20.0)
    start, n = int(db.starts[1]), int(db.lengths[1])
    got = db.root_positions()[start:start + n]
    want = walk.root_positions - walk.root_positions[:1] * torch.tensor([1.0, 0.0, 1.0])
    assert float((got - want).abs().max()) <= 0.05 + 1e-4
    assert db.frames == 270 and db.nbytes == 270 * bytes_per_frame(db.skeleton.num_joints) + 4 * 4 * 3


def test_styles_pick_their_rows() -> None:
    db = _db()
    assert db.styles == ["fast", "slow"] and int(db.rows_of_style("slow").sum()) == 180
    assert not bool(db.rows_of_style("elderly").any())


def test_files_round_trip_and_refuse_another_rig(tmp_path: Path) -> None:
    db = _db()
    assert MotionDatabase.load(tmp_path, db.skeleton) is None  # a bundle without one
    db.save(tmp_path)
    back = MotionDatabase.load(tmp_path, db.skeleton)
    assert back is not None and torch.equal(back.rotations, db.rotations) and torch.equal(back.roots_mm, db.roots_mm)
    assert back.styles == db.styles and back.source == db.source and back.fps == 30.0
    other = dataclasses.replace(db.skeleton, names=(*db.skeleton.names[:3], "SomethingElse", *db.skeleton.names[4:]))
    with pytest.raises(DatabaseError, match="another rig"):
        MotionDatabase.load(tmp_path, other)
    (tmp_path / DATABASE_META).unlink()
    with pytest.raises(DatabaseError, match="without"):
        MotionDatabase.load(tmp_path, db.skeleton)


def test_a_segment_too_long_to_hold_is_refused() -> None:
    walk = synthetic_walk(frames=30)
    far = walk.root_positions.clone()
    far[-1, 0] += 5000.0
    with pytest.raises(DatabaseError, match="32 m"):
        MotionDatabase.from_segments(walk.skeleton, 30.0, [(walk.rotations, far, "s", "walk")])


def test_the_build_takes_locomotion_of_the_train_split_within_its_budget(tmp_path: Path) -> None:
    write_synthetic_dataset(tmp_path / "data", takes_per_pair=3, frames=150)
    cache = load_motion_cache(tmp_path / "data", workers=1, progress=False, root=tmp_path / "cache")
    db = build_database(cache)
    train = [i for i in cache.split.train if cache.takes[i].content != "stand"]
    assert set(db.styles) == {cache.takes[i].style for i in train}
    assert all(int(n) == cache.num_frames(0) - 2 * TRIM for n in db.lengths)  # every take trimmed at both ends
    small = build_database(cache, budget_bytes=3 * 120 * bytes_per_frame(db.skeleton.num_joints))
    assert small.frames == 3 * 120 and small.contents == ["walk"] and len(small.styles) == 3  # each style's walk first
    with pytest.raises(ValueError, match="locomotion"):
        build_database(cache, takes=[])


def test_rsmt_bundle_database_writes_it_and_the_bundle_loads_it(tmp_path: Path) -> None:
    from model.inference.bundle import Bundle
    from rsmt_cli.main import main

    write_synthetic_dataset(tmp_path / "data", takes_per_pair=2, frames=120)
    folder = Bundle.create(synthetic_skeleton(), seed=0).save(tmp_path / "bundle")
    assert main(["bundle", "database", str(folder), "--from-data", str(tmp_path / "data")]) == 0
    loaded = Bundle.load(folder)
    assert loaded.database is not None and loaded.database.frames > 0
    assert main(["bundle", "database", str(folder), "--from-data", str(tmp_path / "data"), "--budget-mb", "11"]) == 2
    loaded.save(tmp_path / "copy")  # a bundle saved again keeps its database
    copy = Bundle.load(tmp_path / "copy").database
    assert copy is not None and torch.equal(copy.rotations, loaded.database.rotations)
