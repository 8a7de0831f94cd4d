"""The per-take floor and facing checks read a forward walk, a backward walk and the toes' height."""

from __future__ import annotations

import math

import torch

from model.data.synthetic import synthetic_skeleton
from model.data.take_checks import summarise, take_check
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_identity, yaw_quat

SK = synthetic_skeleton()


def _walk(step: tuple[float, float], yaw: float, frames: int = 40) -> torch.Tensor:
    rot = quat_identity((frames, len(SK.names)))
    rot[:, SK.roles.root] = yaw_quat(torch.full((frames,), yaw))
    t = torch.arange(frames, dtype=torch.float32)
    root = torch.stack([t * step[0], torch.full_like(t, 90.0), t * step[1]], -1)
    return forward_kinematics(rot, root, SK.offsets_tensor(), SK.parents)[0]


def test_forward_backward_and_sideways_walks() -> None:
    yaw = 0.7
    ahead = (3.0 * math.sin(yaw), 3.0 * math.cos(yaw))
    fwd, back = take_check(_walk(ahead, yaw), SK, 30.0), take_check(_walk((-ahead[0], -ahead[1]), yaw), SK, 30.0)
    assert abs(fwd["travel_vs_facing_deg"]) < 1e-3 and fwd["backward_share"] == 0.0
    assert abs(abs(back["travel_vs_facing_deg"]) - 180.0) < 1e-3 and back["backward_share"] == 1.0
    left = take_check(_walk((3.0 * math.cos(yaw), -3.0 * math.sin(yaw)), yaw), SK, 30.0)  # 90 degrees off the facing
    assert abs(abs(left["travel_vs_facing_deg"]) - 90.0) < 1e-3
    toes = float(_walk(ahead, yaw)[:, SK.roles.left_foot[-1], 1].min())
    assert abs(fwd["toe_rest_cm"] - toes) < 1e-4 and abs(fwd["hips_median_cm"] - 90.0) < 1e-4


def test_summary_takes_medians_per_source_and_content() -> None:
    rows = [{"source": "dataset-1", "content": "walk-back", "toe_rest_cm": x, "toe_lowest_cm": x, "hips_median_cm": 90.0,
             "travel_vs_facing_deg": 180.0, "backward_share": 1.0} for x in (4.0, 4.2, 9.0)]
    s = summarise(rows)["dataset-1/walk-back"]
    assert s["takes"] == 3 and abs(s["toe_rest_cm"] - 4.2) < 1e-6 and s["backward_share"] == 1.0
