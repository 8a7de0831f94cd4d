"""Exact arrival: bend the last frames of a transition so its final frame *is* the target pose,
keeping planted feet where they are while the correction is spread out.

The network only learns to approach the target. Over the last ``window`` frames the body (local
rotations by slerp, the root by lerp) is blended toward the target with a smoothstep weight that
reaches 1 on the arrival frame. Blending moves the hips, which would drag planted feet along, so
each foot's share of the correction advances only while that foot is in the air: a planted foot
is held by two-bone IK on its leg where it was planted, and a swinging foot catches up. On the
arrival frame every foot takes its target place, so the frame equals the target exactly; a foot
planted through the whole window moves there on that frame.

A character with a speed cap (its style's capture maximum, :mod:`model.inference.output.speed_cap`, in cm a frame)
is never bent faster than that: each frame's root is put at the point nearest the blend's that is both within the
cap of the previous emitted root and within the cap times the frames left of the target (:func:`capped_root`), so
the target stays reachable to the end and the arrival frame is the target whenever the root could get there under
the cap. Where the network walks too slowly for that, the root leads it (before the window too, the whole body
carried with it); where even the cap cannot get there, the root goes straight at the target at the cap and arrives
short.

Works frame by frame with explicit per-character state, so streaming and whole transitions share it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from model.motion.kinematics import forward_kinematics, global_to_local_rotations, two_bone_ik
from model.motion.rotations import quat_slerp
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor

DEFAULT_WINDOW = 10
PLANT_SPEED_CM = 1.0  # cm/frame at 30 fps: slower feet count as planted


@dataclass
class ArrivalState:
    """Per-character memory of the two ankles (world positions ``[2, 3]``)."""

    previous: Tensor | None = None  # generated ankle positions of the previous frame
    placed: Tensor | None = None  # where each ankle was put on the previous frame
    progress: Tensor | None = None  # [2] share of each foot's correction applied so far
    root: Tensor | None = None  # [3] the root emitted on the previous frame (the context's last at the start)


def arrival_weight(remaining: Tensor, window: int | Tensor) -> Tensor:
    """Blend weight for frames with ``remaining`` frames after them: 0 before the window, 1 on arrival
    (``window``: frames, positive; one for all, or one a row)."""
    u = ((window - remaining.float()) / window).clamp(0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def capped_root(desired: Tensor, previous: Tensor, target: Tensor, cap: float, remaining: int) -> Tensor:
    """The ground point (``[2]``) nearest ``desired`` that is within ``cap`` of ``previous`` and within ``cap *
    remaining`` of ``target`` (all ``[2]``, cm); where no point is both, the point ``cap`` from ``previous`` straight
    towards ``target`` (the nearest it can get)."""
    reach = cap * remaining
    gap = target - previous
    dist = float(gap.norm())
    if dist > cap + reach:
        return previous + gap * (cap / dist)
    if float((desired - previous).norm()) <= cap and float((desired - target).norm()) <= reach:
        return desired
    candidates = []
    for centre, radius, other, other_radius in ((previous, cap, target, reach), (target, reach, previous, cap)):
        away = desired - centre
        n = float(away.norm())
        point = centre + away * (radius / n) if n > radius else desired
        if float((point - other).norm()) <= other_radius + 1e-4:
            candidates.append(point)
    if not candidates and dist > 1e-9:  # the nearest point of the lens is one of its two corners
        along = (dist * dist + cap * cap - reach * reach) / (2.0 * dist)
        half = max(0.0, cap * cap - along * along) ** 0.5
        unit = gap / dist
        normal = torch.stack([-unit[1], unit[0]])
        mid = previous + unit * along
        candidates = [mid + normal * half, mid - normal * half]
    if not candidates:
        return previous.clone()
    return min(candidates, key=lambda q: float((q - desired).norm()))


class ArrivalCorrector:
    """Batched exact-arrival correction for one skeleton."""

    def __init__(self, skeleton: Skeleton, window: int = DEFAULT_WINDOW, plant_speed_cm: float = PLANT_SPEED_CM) -> None:
        if window < 1:
            raise ValueError("the arrival window must be at least one frame")
        self.skeleton = skeleton
        self.window = window
        self.plant_speed = plant_speed_cm
        sk = skeleton
        self.legs = sk.legs
        self.offsets = sk.offsets_tensor()

    def _capped(self, root: Tensor, target_roots: Tensor, remaining: Tensor, caps: Tensor | None,
                states: list[ArrivalState]) -> Tensor:
        """``root [N, 3]`` (the blend's) with each capped row's ground point moved by :func:`capped_root`; rows
        it leaves alone keep their bits."""
        if caps is None:
            return root
        out = root
        for i, st in enumerate(states):
            cap = float(caps[i])
            if st.root is None or not cap < float("inf"):
                continue
            previous = st.root.to(root.dtype)[::2]
            ground = capped_root(root[i, ::2], previous, target_roots[i, ::2], cap, int(remaining[i]))
            if not torch.equal(ground, root[i, ::2]):
                out = out.clone() if out is root else out
                out[i, 0], out[i, 2] = ground[0], ground[1]
        return out

    def apply(self, rotations: Tensor, roots: Tensor, target_rotations: Tensor, target_roots: Tensor,
              remaining: Tensor, states: list[ArrivalState], caps: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Correct one frame of ``N`` characters.

        Args:
            rotations, roots: ``[N, J, 4]`` local rotations and ``[N, 3]`` roots as generated.
            target_rotations, target_roots: the targets, same shapes.
            remaining: ``[N]`` frames left after this one (0 on the arrival frame).
            states: one :class:`ArrivalState` per character, updated in place.
            caps: ``[N]`` each row's speed cap (cm a frame on the ground; ``inf``: none); None: no caps.
        """
        sk = self.skeleton
        w = arrival_weight(remaining, self.window)
        gen_pos, _ = forward_kinematics(rotations, roots, self.offsets, sk.parents)
        ankles = torch.stack([gen_pos[:, leg[2]] for leg in self.legs], dim=1)  # [N, 2, 3]
        active = (w > 0).view(-1, 1)  # before the window the generated pose passes through untouched
        rot = torch.where(active.unsqueeze(-1), quat_slerp(rotations, target_rotations, w.view(-1, 1)), rotations)
        blended = torch.where(active, torch.lerp(roots, target_roots, w.view(-1, 1)), roots)
        root = self._capped(blended, target_roots, remaining, caps, states)
        lead = root - blended  # the cap's move of the root: the generated feet are carried with it
        carried = ankles + lead.unsqueeze(1)
        pos, grot = forward_kinematics(rot, root, self.offsets, sk.parents)
        goals = torch.zeros(len(states), len(self.legs), 3)
        body = torch.stack([pos[:, leg[2]] for leg in self.legs], dim=1)  # ankles of the blended body
        for i, st in enumerate(states):
            planted = torch.zeros(len(self.legs), dtype=torch.bool)
            if st.previous is not None:
                planted = (ankles[i] - st.previous).norm(dim=-1) < self.plant_speed
            if st.progress is None or st.placed is None:
                st.progress = torch.zeros(len(self.legs))
                st.placed = carried[i].clone()
            r = int(remaining[i])
            if r == 0:
                st.progress = torch.ones_like(st.progress)
            elif w[i] > 0:
                # A foot in the air catches up with the body so it is done by the end; a planted one waits.
                step = (w[i] - st.progress).clamp_min(0.0)
                st.progress = torch.where(planted, st.progress, st.progress + step)
            goal = torch.lerp(carried[i], body[i], st.progress.unsqueeze(-1))
            # A planted foot stays exactly where it was put on the previous frame.
            goal = torch.where((planted & (w[i] > 0) & (r > 0)).unsqueeze(-1), st.placed, goal)
            st.previous, st.placed = ankles[i].clone(), goal.clone()
            goals[i] = goal
        for i, st in enumerate(states):
            st.root = root[i].clone()
        adjusting = w > 0
        if not adjusting.any():
            return rot, root
        for f, (hip, knee, ankle) in enumerate(self.legs):
            rows = adjusting & ((goals[:, f] - pos[:, ankle]).norm(dim=-1) > 1e-4)
            if not rows.any():
                continue
            goal = goals[rows, f]
            new_hip, new_knee = two_bone_ik(pos[rows, hip], pos[rows, knee], pos[rows, ankle],
                                            grot[rows, hip], grot[rows, knee], goal)
            g = grot[rows].clone()
            g[:, hip], g[:, knee] = new_hip, new_knee
            # Children keep their world rotations (the foot stays flat); only the two bones change.
            fixed = global_to_local_rotations(g, sk.parents)
            sub = rot[rows].clone()
            for j in (hip, knee, ankle):
                sub[:, j] = fixed[:, j]
            rot[rows] = sub
            pos[rows], grot[rows] = forward_kinematics(rot[rows], root[rows], self.offsets, sk.parents)
        return rot, root


@dataclass(frozen=True)
class ArrivalPose:
    """Where one character arrives exactly: its target pose in world space (local rotations ``[J, 4]``, root
    ``[3]``). The corrector's memory of the character (:class:`ArrivalState`) lives beside it, in its batch."""

    rotations: Tensor
    root: Tensor


class ExactArrival:
    """Exact arrival as an output step: it runs after the frame steps' graph, on the rows whose request asked
    for it (per character, so it stays out of the traced graph)."""

    def __init__(self, corrector: ArrivalCorrector) -> None:
        self.corrector = corrector

    def start(self, rotations: Tensor, root: Tensor) -> ArrivalPose:
        """A character's target for arriving exactly at the pose ``rotations [J, 4]``, ``root [3]`` (world)."""
        return ArrivalPose(rotations, root)

    def __call__(self, rotations: Tensor, roots: Tensor, remaining: Tensor, targets: list[ArrivalPose | None],
                 states: list[ArrivalState], caps: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """A batch's frame (``[N, J, 4]``, ``[N, 3]``; ``remaining [N]``) with the rows whose target is not None
        bent toward it (None also where a target is out of reach: :attr:`model.inference.character.Aim.bent_to`),
        the others as they are; ``states``: each row's corrector memory, the bent rows' updated in place, and
        every row's emitted root remembered (a row may be bent from a later retarget on); ``caps [N]``: each row's
        speed cap (cm a frame; None or ``inf``: none), which no bent root step exceeds."""
        exact = [i for i, t in enumerate(targets) if t is not None]
        if not exact:
            for st, root in zip(states, roots.clone().unbind(0), strict=True):
                st.root = root
            return rotations, roots
        idx = torch.tensor(exact)
        chosen = [t for t in targets if t is not None]
        t_rot = torch.stack([t.rotations for t in chosen])
        t_root = torch.stack([t.root for t in chosen])
        fixed_rot, fixed_root = self.corrector.apply(rotations[idx], roots[idx], t_rot, t_root, remaining[idx],
                                                     [states[i] for i in exact], None if caps is None else caps[idx])
        rotations, roots = rotations.clone(), roots.clone()
        rotations[idx], roots[idx] = fixed_rot, fixed_root
        for st, root in zip(states, roots.clone().unbind(0), strict=True):
            st.root = root
        return rotations, roots


def exact_arrival(rotations: Tensor, roots: Tensor, target_rotation: Tensor, target_root: Tensor, skeleton: Skeleton,
                  window: int = DEFAULT_WINDOW, cap: float = float("inf"),
                  start: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Correct a whole transition ``[T, J, 4]``, ``[T, 3]`` so its last frame equals the target; with a ``cap`` (cm
    a frame on the ground) no root step is longer, from ``start [3]`` (the root before the first frame; None: the
    first frame's own) on."""
    corrector = ArrivalCorrector(skeleton, window)
    state = ArrivalState(root=start)
    caps = torch.tensor([cap])
    t = rotations.shape[0]
    out_r, out_p = [], []
    for i in range(t):
        r, p = corrector.apply(rotations[i : i + 1], roots[i : i + 1], target_rotation.unsqueeze(0), target_root.unsqueeze(0),
                               torch.tensor([t - 1 - i]), [state], caps)
        out_r.append(r[0])
        out_p.append(p[0])
    return torch.stack(out_r), torch.stack(out_p)
