"""Scores of one method's transitions on one variant of every case (definitions in :mod:`model.evaluation.metrics`).

All positions and rotations are taken into the canonical frame of each case's last context
frame before scoring. With ground truth (unchanged controls):

* ``l2p``: standardised global positions (training-split :class:`~model.evaluation.metrics.PositionStats`),
  mean over cases and generated frames of the per-frame L2 norm; unitless;
* ``l2q``: global quaternions, same averaging;
* ``npss`` and ``npss_x100``: NPSS on global quaternions of the generated frames (LaFAN1 code's
  real-part spectrum), pooled over all cases;
* ``mpjpe_cm``: mean joint position error;
* ``foot_skate`` / ``foot_skate_gt``: cm/frame (horizontal foot speed weighted by
  ``clamp(2 - 2^(h/H), 0, 1)``, ``H = 2.5`` cm above each foot joint's training ground level)
  over the last context frame followed by the generated frames, for the method and for the
  ground truth of the same cases.

Always: ``last_frame_cm`` (mean joint distance of the last generated frame to the target pose,
after any target shift), ``last_frame_l2p`` (the same in standardised units, the paper's
"L2 norm of global position of the last frame"), ``foot_skate``, and the largest root speed over
the transition (last context frame included, cm/s): ``max_root_speed_cm_s``, the mean over cases of
each case's largest, and ``max_root_speed_cm_s_worst``, the largest of all (a course correction by
jumping shows there); ``floor_depth_cm`` (and ``floor_depth_cm_gt`` with ground truth): per case the
deepest a foot joint goes below its ground level over the generated frames, mean over cases
(:mod:`model.evaluation.floor`).

Gait figures (:mod:`model.motion.gait`), on the same frames (last context frame first): ``toe_skate``
(and ``toe_skate_gt``): the toe joints alone against the toes' rest height 4.25 cm above y = 0;
``backward_share``: the mean over cases (with hips faster than 30 cm/s somewhere) of the share of such
frame steps that move against the facing; ``longest_airborne_frames`` (the worst case's longest run with
both toes 15 cm above rest) and ``longest_airborne_frames_mean``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from model.evaluation import metrics
from model.evaluation.cases import LAST_CONTEXT, CaseSet, Variant
from model.evaluation.floor import floor_depth
from model.evaluation.reference import ReferenceStats
from model.motion import gait

Tensor = torch.Tensor


@dataclass
class Transitions:
    """Generated frames of every case in the canonical frame, with the last context frame in front.

    Attributes:
        positions: ``[B, N + 1, J, 3]`` (frame 0 is the last context frame).
        rotations: ``[B, N + 1, J, 4]`` global quaternions.
    """

    positions: Tensor
    rotations: Tensor

    @property
    def generated_positions(self) -> Tensor:
        return self.positions[:, 1:]

    @property
    def generated_rotations(self) -> Tensor:
        return self.rotations[:, 1:]


def to_canonical(cases: CaseSet, local_rotations: Tensor, roots: Tensor) -> Transitions:
    """FK a method's output (world local rotations and roots) on each case's rig, prepend frame 9, canonicalise."""
    pos, rot = cases.forward(local_rotations, roots)
    pos = torch.cat([cases.positions[:, LAST_CONTEXT:LAST_CONTEXT + 1], pos], dim=1)
    rot = torch.cat([cases.global_rotations[:, LAST_CONTEXT:LAST_CONTEXT + 1], rot], dim=1)
    return Transitions(cases.frame.positions_to(pos), cases.frame.rotations_to(rot))


def ground_truth_transitions(cases: CaseSet, v: Variant) -> Transitions:
    sl = slice(LAST_CONTEXT, LAST_CONTEXT + v.gap + 1)
    return Transitions(cases.canonical_positions[:, sl], cases.canonical_rotations[:, sl])


def root_speed(positions: Tensor, cases: CaseSet) -> dict[str, float]:
    """``max_root_speed_cm_s`` (mean over cases of each one's largest) and ``max_root_speed_cm_s_worst`` of ``positions``."""
    speed = metrics.max_root_speed(positions, cases.fps, cases.skeleton.roles.root)
    return {"max_root_speed_cm_s": float(speed.mean()), "max_root_speed_cm_s_worst": float(speed.max())}


def gait_rows(positions: Tensor, cases: CaseSet) -> dict[str, float]:
    """Toe skate, backward share and airborne runs of ``positions [B, N+1, J, 3]`` (see the module docstring)."""
    toes = gait.toe_joints(cases.skeleton)
    share = gait.backward_share(positions, cases.skeleton, cases.fps)
    moving = ~torch.isnan(share)
    air = gait.longest_airborne(positions, toes)
    return {"toe_skate": float(gait.toe_skate(positions, toes)),
            "backward_share": float(share[moving].mean()) if moving.any() else float("nan"),
            "backward_share_cases": int(moving.sum()),
            "longest_airborne_frames": int(air.max()) if len(air) else 0,
            "longest_airborne_frames_mean": float(air.float().mean()) if len(air) else 0.0}


def score(cases: CaseSet, v: Variant, out: Transitions, ref: ReferenceStats) -> dict[str, float]:
    """Scores of ``out`` on variant ``v`` (see the module docstring)."""
    pred_pos = out.generated_positions
    target = cases.frame.positions_to(cases.target_positions(v).unsqueeze(1))  # [B, 1, J, 3]
    result = {
        "cases": len(cases),
        "frames": v.frames,
        "last_frame_cm": float(metrics.last_frame_error_cm(pred_pos, target)),
        "last_frame_l2p": float(metrics.l2p(pred_pos[:, -1:], target, ref.positions)),
        "foot_skate": float(metrics.foot_skate(out.positions, ref.feet, ref.ground)),
        "floor_depth_cm": float(floor_depth(out.generated_positions, ref.feet, ref.ground).mean()),
        **root_speed(out.positions, cases),
        **gait_rows(out.positions, cases),
    }
    if v.has_ground_truth:
        gt = ground_truth_transitions(cases, v)
        gt_pos, gt_rot = gt.generated_positions, gt.generated_rotations
        npss = float(metrics.npss(out.generated_rotations, gt_rot))
        result.update({
            "l2p": float(metrics.l2p(pred_pos, gt_pos, ref.positions)),
            "l2q": float(metrics.l2q(out.generated_rotations, gt_rot)),
            "npss": npss,
            "npss_x100": 100.0 * npss,
            "mpjpe_cm": float(metrics.mean_joint_error_cm(pred_pos, gt_pos)),
            "foot_skate_gt": float(metrics.foot_skate(gt.positions, ref.feet, ref.ground)),
            "toe_skate_gt": gait_rows(gt.positions, cases)["toe_skate"],
            "floor_depth_cm_gt": float(floor_depth(gt_pos, ref.feet, ref.ground).mean()),
        })
    return result
