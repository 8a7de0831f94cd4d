"""Motion matching over a database: every row finds itself, a straight walk's trajectory points ahead of it, a style
restricts the rows searched, and a query with no row to go to says so."""

from __future__ import annotations

import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.retrieval.database import MotionDatabase
from model.retrieval.matching import TRAJECTORY, MatchIndex


@pytest.fixture(scope="module")
def index() -> MatchIndex:
    segments = [(w.rotations, w.root_positions, style, "walk") for w, style in (
        (synthetic_walk(frames=120, speed_cm_s=100.0), "slow"),
        (synthetic_walk(frames=120, speed_cm_s=160.0, turn_deg_s=30.0), "fast"),
        (synthetic_walk(frames=120, speed_cm_s=100.0, turn_deg_s=-30.0, start_yaw_deg=90.0), "slow"))]
    return MatchIndex(MotionDatabase.from_segments(synthetic_walk(frames=2).skeleton, 30.0, segments))


def test_rows_without_a_frame_before_or_the_trajectory_after_are_not_searched(index: MatchIndex) -> None:
    assert int(index.valid.sum()) == 3 * (120 - 1 - TRAJECTORY[-1])
    assert not bool(index.valid[0]) and not bool(index.valid[119 - TRAJECTORY[-1] + 1])


def test_every_valid_row_finds_itself(index: MatchIndex) -> None:
    rows = torch.nonzero(index.valid).flatten()
    found = index.search(index.row_groups(rows))
    assert torch.equal(found.rows, rows) and float(found.cost.abs().max()) < 1e-3  # float32 rounding of |f|^2 - 2q.f + |q|^2


def test_a_straight_walk_s_trajectory_points_ahead_along_its_facing(index: MatchIndex) -> None:
    groups = index.row_groups(torch.tensor([40]))  # the slow straight walk, facing +Z
    x, z = groups["trajectory"].view(len(TRAJECTORY), 2).unbind(-1)
    assert float(x.abs().max()) < 2.0
    assert z.tolist() == pytest.approx([100.0 * k / 30.0 for k in TRAJECTORY], abs=3.0)
    assert groups["facing"].view(len(TRAJECTORY), 2)[:, 1].tolist() == pytest.approx([100.0] * 3, abs=0.5)


def test_a_style_mask_keeps_the_search_within_its_rows(index: MatchIndex) -> None:
    fast_row = torch.tensor([int(index.db.starts[1]) + 50])
    slow = index.db.rows_of_style("slow")
    found = index.search(index.row_groups(fast_row), allowed=slow)
    assert bool(slow[found.rows].all()) and float(found.cost[0]) > 0.0
    nothing = index.search(index.row_groups(fast_row), allowed=index.db.rows_of_style("elderly"))
    assert nothing.rows.tolist() == [-1] and nothing.cost.tolist() == [float("inf")]
