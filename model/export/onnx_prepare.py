"""The ``prepare`` graph: what :meth:`model.inference.engine.Engine.prepare` computes from one character's poses, so
that an engine holding the graphs starts a transition from the poses it has (no service, no Python).

In: the context's last ``context`` frames (local x, y, z, w rotations ``[K, J, 4]`` and root positions ``[K, 3]``, on
the model's rig at its fps) and the target frame (``[1, J, 4]``, ``[1, 3]``). Out, each with a batch of one: the
context and target states in the transition's canonical frame (``begin``'s inputs), that frame (``yaw``, ``origin``:
``output``'s) and the output steps' first memory (its caps open: inf). The target's velocity is unknown (one frame),
as a game sends it.
"""

from __future__ import annotations

import torch

from model.inference.engine import Engine
from model.motion.features import CanonicalFrame
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_normalize, quat_to_sixd
from model.nets.pose_state import state_from_positions

Tensor = torch.Tensor

PREPARE_INPUTS = ("context_rotations", "context_roots", "target_rotations", "target_roots")
PREPARE_STATES = ("context_rel", "context_vel", "context_rot", "context_root_xz", "target_rel", "target_vel",
                  "target_rot", "target_root_xz", "yaw", "origin")


class Prepare(torch.nn.Module):
    offsets: Tensor

    def __init__(self, engine: Engine) -> None:
        super().__init__()
        self.engine = engine
        self.register_buffer("offsets", engine.skeleton.offsets_tensor())

    def _global(self, rotations: Tensor, roots: Tensor) -> tuple[Tensor, Tensor]:
        return forward_kinematics(quat_normalize(rotations), roots, self.offsets, self.engine.skeleton.parents)

    def forward(self, crot: Tensor, croot: Tensor, trot: Tensor, troot: Tensor) -> tuple[Tensor, ...]:
        e, sk = self.engine, self.engine.skeleton
        k = e.config.context
        cpos, cglob = self._global(crot, croot)
        frame = CanonicalFrame.at_frame(cpos.unsqueeze(0), sk, k - 1)
        ctx = state_from_positions(frame.positions_to(cpos.unsqueeze(0)),
                                   quat_to_sixd(frame.rotations_to(cglob.unsqueeze(0))), sk.roles.root)
        tpos, tglob = self._global(trot, troot)
        tpos, trot6 = frame.positions_to(tpos.unsqueeze(0)), quat_to_sixd(frame.rotations_to(tglob.unsqueeze(0)))
        tgt = state_from_positions(torch.cat([tpos, tpos], 1), torch.cat([trot6, trot6], 1),
                                   sk.roles.root).index((slice(None), 1))  # no frame before it: a zero velocity
        memory = {**e.pipeline.frame.start(quat_normalize(crot), croot), **e.pipeline.frame.open_columns()}
        states = (ctx.rel, ctx.vel, ctx.rot, ctx.root_xz, tgt.rel, tgt.vel, tgt.rot, tgt.root_xz, frame.yaw, frame.origin)
        return (*states, *(memory[key] for key in e.output_fn.fn.keys))


def prepare_example(engine: Engine) -> tuple[Tensor, ...]:
    from model.data.synthetic import synthetic_walk

    walk = engine.conform(synthetic_walk(frames=80, turn_deg_s=15.0))
    k = engine.config.context
    return walk.rotations[:k], walk.root_positions[:k], walk.rotations[60:61], walk.root_positions[60:61]
