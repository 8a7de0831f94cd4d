"""Poses built from a skeleton alone: a T-pose and a standing pose, rest-pose aware, on any rig with the usual roles.

A rig's joints keep their own local frames (the Bandai-Namco rig's bones point along local +-X), so
all-identity rotations are not a standing pose, and rotations carried over from another rig by joint name
lay the person on its side. :func:`t_pose` instead aims every bone: spine up, arms out along +-X, legs down,
feet forward and pitched down, facing +Z with its left on +X (the model's axes), toes just above the floor
(y = 0). :func:`standing_pose` is that T-pose with the arms lowered beside the body, the pose a person
stands in before walking.

Numpy only (no torch), so that ``rsmt rig export`` runs from a bare install. Rotations are 3x3 matrices;
:class:`Rig` is a skeleton as ``skeleton.json`` stores it (``GET /v1/model`` ``skeleton``).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from model.motion.bvh_parser import vec3

if TYPE_CHECKING:
    from model.motion.skeleton import Skeleton

UP = np.array([0.0, 1.0, 0.0])
LEFT = np.array([1.0, 0.0, 0.0])
FORWARD = np.array([0.0, 0.0, 1.0])
FOOT_PITCH_DEG = 30.0     # ankle-to-toe bone, below horizontal
TOE_HEIGHT = 2.0          # toe joint above the ground, model units
ARMS_STANDING_DEG = 80.0  # a standing person's arms: lowered this far from the T-pose, 10 degrees off the body


@dataclass(frozen=True)
class Rig:
    """A skeleton as ``skeleton.json`` stores it: names, parents, offsets and the roles resolved to indices."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray            # [J, 3], model units, in the parent's frame
    end_sites: dict[int, tuple[float, float, float]]
    roles: dict[str, Any]
    units: str

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Rig:
        joints = data["joints"]
        ends = {int(e["joint"]): vec3(e["offset"]) for e in data.get("end_sites", [])}
        return cls(tuple(j["name"] for j in joints), tuple(int(j["parent"]) for j in joints),
                   np.array([j["offset"] for j in joints], dtype=np.float64), ends,
                   dict(data["roles"]), str(data.get("units", "cm")))

    @classmethod
    def load(cls, path: Path) -> Rig:
        return cls.from_json(json.loads(path.read_text()))

    @classmethod
    def from_skeleton(cls, skeleton: Skeleton) -> Rig:
        return cls(skeleton.names, skeleton.parents, np.array(skeleton.offsets, dtype=np.float64),
                   dict(skeleton.end_sites), asdict(skeleton.roles), skeleton.units)

    def children(self, j: int) -> list[int]:
        return [k for k, p in enumerate(self.parents) if p == j]

    def descendants(self, j: int) -> list[int]:
        out = [j]
        for k in range(j + 1, len(self.parents)):
            if self.parents[k] in out:
                out.append(k)
        return out


def unit(v: np.ndarray) -> np.ndarray:
    """``v`` scaled to length 1."""
    return v / np.linalg.norm(v)


def axis_angle(axis: np.ndarray, deg: float) -> np.ndarray:
    """Right-handed rotation matrix of ``deg`` degrees about ``axis``."""
    x, y, z = unit(np.asarray(axis, dtype=np.float64))
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) * c + s * k + (1 - c) * np.outer([x, y, z], [x, y, z])


def between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Shortest-arc rotation taking direction u onto v (for opposite directions: about world forward, else left)."""
    u, v = unit(u), unit(v)
    axis = np.cross(u, v)
    if np.linalg.norm(axis) < 1e-9:
        if float(u @ v) > 0:
            return np.eye(3)
        axis = FORWARD if abs(float(u @ FORWARD)) < 0.9 else LEFT
        return axis_angle(axis - (axis @ u) * u, 180.0)
    return axis_angle(axis, math.degrees(math.atan2(np.linalg.norm(axis), float(u @ v))))


def frame_from(primary_local: np.ndarray, primary_world: np.ndarray, second_local: np.ndarray,
               second_world: np.ndarray) -> np.ndarray:
    """The rotation taking local primary onto world primary exactly and local second as close as possible to world second."""
    def basis(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        e0 = unit(a)
        e1 = unit(b - (b @ e0) * e0)
        return np.stack([e0, e1, np.cross(e0, e1)], axis=1)
    return basis(primary_world, second_world) @ basis(primary_local, second_local).T


@dataclass(frozen=True)
class Pose:
    """Local rotation matrices [J, 3, 3] and the root position (model units and axes)."""

    local: np.ndarray
    root: np.ndarray

    def world(self, rig: Rig) -> tuple[np.ndarray, np.ndarray]:
        """World rotations [J, 3, 3] and positions [J, 3] by forward kinematics."""
        rot = np.zeros_like(self.local)
        pos = np.zeros((len(rig.names), 3))
        for j, p in enumerate(rig.parents):
            if p < 0:
                rot[j], pos[j] = self.local[j], self.root
            else:
                rot[j] = rot[p] @ self.local[j]
                pos[j] = pos[p] + rot[p] @ rig.offsets[j]
        return rot, pos


def _spine(rig: Rig) -> list[int]:
    """The joints from the root up to the head."""
    chain = [rig.roles["head"]]
    while rig.parents[chain[-1]] >= 0:
        chain.append(rig.parents[chain[-1]])
    return list(reversed(chain))


def _bone_targets(rig: Rig) -> dict[int, np.ndarray]:
    """Per joint with a bone to aim, the world direction of the bone towards its primary child."""
    r, names = rig.roles, rig.names
    targets: dict[int, np.ndarray] = dict.fromkeys(_spine(rig), UP)
    for side, sign in (("left", 1.0), ("right", -1.0)):
        clavicle = rig.parents[r[f"{side}_shoulder"]]
        for j in rig.descendants(clavicle):
            targets[j] = sign * LEFT
        ankle, _toe = r[f"{side}_foot"][:2]
        for j in rig.descendants(r[f"{side}_hip"]):
            targets[j] = -UP
        for j in rig.descendants(ankle):
            targets[j] = unit(FORWARD - math.tan(math.radians(FOOT_PITCH_DEG)) * UP)
    missing = [names[j] for j in range(len(names)) if j not in targets]
    if missing:
        raise ValueError(f"no T-pose direction for joint(s) {', '.join(missing)}: not on the spine, an arm or a leg")
    return targets


def _primary_child(rig: Rig, j: int, spine_next: dict[int, int]) -> int | None:
    kids = [k for k in rig.children(j) if np.linalg.norm(rig.offsets[k]) > 1e-6]
    if j in spine_next:
        return spine_next[j]
    return kids[0] if len(kids) == 1 else None


def t_pose(rig: Rig) -> Pose:
    """Arms out along +-X, legs down, spine up, feet forward and 30 degrees down, facing +Z, toes 2 units above y=0.

    Each bone is aimed with the shortest rotation from where its parent leaves it (so twists follow the
    parent); a joint with a left and a right child (hips, chest) also turns them to +X and -X.
    """
    r = rig.roles
    targets = _bone_targets(rig)
    chain = _spine(rig)
    spine_next = {chain[i]: chain[i + 1] for i in range(len(chain) - 1)}
    left = set(rig.descendants(rig.parents[r["left_shoulder"]])) | set(rig.descendants(r["left_hip"]))
    right = set(rig.descendants(rig.parents[r["right_shoulder"]])) | set(rig.descendants(r["right_hip"]))
    world = np.zeros((len(rig.names), 3, 3))
    for j, p in enumerate(rig.parents):
        parent = np.eye(3) if p < 0 else world[p]
        child = _primary_child(rig, j, spine_next)
        if child is None:                       # a leaf (or a zero-length bone): keep the parent's frame
            world[j] = parent
            continue
        kids = rig.children(j)
        lk = [k for k in kids if k in left and k not in spine_next.values()]
        rk = [k for k in kids if k in right and k not in spine_next.values()]
        if lk and rk:
            lateral = rig.offsets[lk[0]] - rig.offsets[rk[0]]
            world[j] = frame_from(rig.offsets[child], targets[j], lateral, LEFT)
        else:
            aim = parent @ rig.offsets[child]
            world[j] = between(aim, targets[j]) @ parent
    local = np.stack([world[j] if p < 0 else world[p].T @ world[j] for j, p in enumerate(rig.parents)])
    _, pos = Pose(local, np.zeros(3)).world(rig)
    return Pose(local, np.array([0.0, TOE_HEIGHT - pos[:, 1].min(), 0.0]))


def arms_lowered(rig: Rig, rest: Pose, deg: float) -> Pose:
    """``rest`` (a T-pose) with both arms turned down by ``deg`` degrees about the forward axis, at the shoulders."""
    world, _ = rest.world(rig)
    local = rest.local.copy()
    for side, sign in (("left", -1.0), ("right", 1.0)):
        j = rig.roles[f"{side}_shoulder"]
        local[j] = world[rig.parents[j]].T @ axis_angle(FORWARD, sign * deg) @ world[j]
    return Pose(local, rest.root.copy())


def standing_pose(rig: Rig) -> Pose:
    """A person standing upright on the floor (toes 2 units up), arms down beside the body, facing +Z over the origin."""
    return arms_lowered(rig, t_pose(rig), ARMS_STANDING_DEG)
