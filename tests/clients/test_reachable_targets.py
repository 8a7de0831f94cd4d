"""A target the server calls reachable is reached, and the root never outruns the style's capture on the way (issue 63
item 5), through a real server of the default model (its bundle has gait limits) and the Python client.

Targets lie 35%, 65% and 90% of the way to what the style's capture maximum covers in 60 frames, straight ahead
or 40 or 60 degrees off the facing (and turned that way), in the slowest, a middling and a fast built-in style.
Each goes as a pose (the context's last pose moved there and turned) without and with ``exact_arrival``, and as a
place and facing (``target_at``, exact by default), over ``POST /v1/transition`` and over ``/v1/stream``. Measured:
the reach notice, the last frame's root to the target's on the ground, and the root's largest ground speed frame
to frame (from the context's last frame) against the notice's ``max_speed_cm_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
import torch
from rsmt_client import Client, Poses, StreamClient, TargetAt

from model.inference.bundle import DEFAULT_BUNDLE
from model.inference.placed_target import Placement, placed_target
from model.motion.clip import Clip
from model.motion.skeleton import Skeleton
from tests.clients.arrival import place_from
from tests.service.server import Server

pytestmark = pytest.mark.slow  # a server of the default model
FRAMES = 60
ARRIVAL_CM = 8.0
SPEED_SLACK = 1.005  # float32 frames (the reach sweep's slack)
STYLES = ("elderly", "exhausted", "normal")
SHARES = ((0.35, 0.0), (0.65, 40.0), (0.9, -60.0))  # of the reachable distance; degrees off the facing
KINDS = ("pose", "pose exact", "target_at")


@dataclass(frozen=True)
class Row:
    style: str
    kind: str
    surface: str
    distance_cm: float
    reachable_cm: float
    feasible: bool
    miss_cm: float
    top_cm_s: float
    cap_cm_s: float
    over_frames: tuple[int, ...]

    def __str__(self) -> str:
        return (f"{self.style} {self.kind} ({self.surface}) {self.distance_cm:.0f} cm: miss {self.miss_cm:.2f} cm, "
                f"top {self.top_cm_s:.0f} cm/s of {self.cap_cm_s:.0f}" +
                (f" (over at frames {list(self.over_frames)})" if self.over_frames else ""))


def _pose_at(skeleton: Skeleton, roots: np.ndarray, rotations: np.ndarray, place: TargetAt) -> dict[str, Any]:
    """The context's last pose moved over ``place`` (its height kept) and turned to its facing: a one-frame target,
    as the server makes a ``target_at`` (:func:`model.inference.placed_target.placed_target`), sent as a pose."""
    context = Clip(skeleton=skeleton, rotations=torch.tensor(rotations, dtype=torch.float64),
                   root_positions=torch.tensor(roots, dtype=torch.float64), fps=30.0)
    target = placed_target(context, Placement(place.x, place.z, place.yaw))
    return {"root_positions": target.root_positions.tolist(), "rotations": target.rotations.tolist(), "fps": target.fps}


def _row(style: str, kind: str, surface: str, place: TargetAt, start: np.ndarray, poses: Poses) -> Row:
    reach = poses.reach
    assert reach is not None, "the default model's answer carries no reach notice"
    roots = np.concatenate([start[None], poses.root_positions.astype(np.float64)])
    speeds = np.linalg.norm(np.diff(roots[:, [0, 2]], axis=0), axis=-1) * poses.fps
    over = tuple(int(i) for i in np.nonzero(speeds > reach.max_speed_cm_s * SPEED_SLACK)[0])
    miss = math.hypot(float(roots[-1, 0]) - place.x, float(roots[-1, 2]) - place.z)
    return Row(style, kind, surface, reach.distance_cm, reach.reachable_cm, reach.feasible, miss, float(speeds.max()),
               reach.max_speed_cm_s, over)


@pytest.fixture(scope="module")
def rows(default_model_eager_server: Server) -> list[Row]:
    url = default_model_eager_server.url
    skeleton = Skeleton.load(DEFAULT_BUNDLE / "skeleton.json")
    out = []
    with Client(url) as c, StreamClient(url) as s:
        demo = c.demo("walk-normal")
        context = {"root_positions": demo.root_positions[100:110].tolist(),
                   "rotations": demo.rotations[100:110].tolist(), "fps": demo.fps}
        roots, rotations = np.asarray(context["root_positions"]), np.asarray(context["rotations"])
        assert {f"builtin:{name}" for name in STYLES} <= {st["style_id"] for st in c.styles()}
        for style in STYLES:
            # What the style covers in 60 frames: the server's own notice of a near target.
            near = place_from(skeleton, roots, rotations, 100.0, 0.0, 0.0)
            first = c.transition(context, near, FRAMES, style_id=f"builtin:{style}", seed=1).reach
            assert first is not None
            for n, (share, angle) in enumerate(SHARES):
                distance = share * first.reachable_cm
                ahead, side = distance * math.cos(math.radians(angle)), distance * math.sin(math.radians(angle))
                place = place_from(skeleton, roots, rotations, ahead, side, angle)
                pose = _pose_at(skeleton, roots, rotations, place)
                for kind in KINDS:
                    target: Any = place if kind == "target_at" else pose
                    # A pose target is exact only when asked; a target_at is left to the server's default, exact.
                    exact = True if kind == "pose exact" else None if kind == "target_at" else False
                    got = c.transition(context, target, FRAMES, style_id=f"builtin:{style}", seed=n,
                                       exact_arrival=exact)
                    out.append(_row(style, kind, "transition", place, roots[-1], got))
                    cid = s.start(context, target, FRAMES, style_id=f"builtin:{style}", seed=n, pace="asap",
                                  exact_arrival=exact)
                    result = s.collect(cid, timeout=120)
                    assert result.end is not None and result.end["reason"] == "arrived" and not result.stopped_short
                    out.append(_row(style, kind, "stream", place, roots[-1], result.poses(s.joint_names)))
    for row in out:
        print(row)
    return out


def test_every_target_within_reach_is_said_to_be_and_reached_within_8_cm(rows: list[Row]) -> None:
    assert len(rows) == len(STYLES) * len(SHARES) * len(KINDS) * 2
    assert all(r.feasible for r in rows), [str(r) for r in rows if not r.feasible]
    # Near the reach line the network walks under the cap for half the transition; the speed cap step then keeps
    # its target within reach (model/inference/output/speed_cap.py, kept_in_reach), so it gets there.
    missed = [str(r) for r in rows if r.miss_cm > ARRIVAL_CM]
    assert not missed, missed


def test_the_network_s_own_arrival_never_outruns_the_capture(rows: list[Row]) -> None:
    over = [str(r) for r in rows if r.kind == "pose" and r.over_frames]
    assert not over, over


def test_an_exact_arrival_never_outruns_the_capture(rows: list[Row]) -> None:
    # The exact arrival's bend (model/inference/output/arrival.py) runs after the speed cap and keeps each root step
    # within it itself, leading the network early enough that a target within reach is still landed on exactly.
    exact = [r for r in rows if r.kind != "pose"]
    over = [str(r) for r in exact if r.over_frames]
    assert not over, over
    missed = [str(r) for r in exact if r.miss_cm > 1e-2]
    assert not missed, missed
