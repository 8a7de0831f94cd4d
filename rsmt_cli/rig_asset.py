"""The model's rig as files game engines import: a T-pose for the skeleton, a BVH and a skinned glTF.

Torch-free (numpy only) so that ``rsmt rig export`` runs from a bare install. The model's joints keep their
own local frames (the Bandai-Namco rig's bones point along local +-X, so all-identity rotations are not a
standing pose); :func:`model.motion.standing_pose.t_pose` finds local rotations that stand the rig up in a
T-pose, facing +Z with its left on +X (the model's axes, which are also glTF's). Engines then play the
model's local rotations on the imported bones unchanged (after their axis conversion), since the bones
keep the model's frames.
"""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from model.motion.bvh import BvhDocument, BvhJoint
from model.motion.bvh_parser import vec3
from model.motion.standing_pose import FORWARD, UP, Pose, Rig, arms_lowered, t_pose, unit

ARMS_DOWN_DEG = 40.0      # the sample motion lowers the arms by this much
MOTION_FRAMES = 31


# ---------------------------------------------------------------------- rotations (3x3 matrices, x,y,z,w quaternions)

def matrix_to_quat(m: np.ndarray) -> tuple[float, float, float, float]:
    """x, y, z, w with w >= 0 (Shepperd's method: from the largest of w, x, y, z, exact near 180 degrees too)."""
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    cands = [tr, m[0, 0], m[1, 1], m[2, 2]]
    i = int(np.argmax(cands))
    if i == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4)
    elif i == 1:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif i == 2:
        s = 2.0 * math.sqrt(1.0 - m[0, 0] + m[1, 1] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 - m[0, 0] - m[1, 1] + m[2, 2])
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s)
    n = math.sqrt(sum(v * v for v in q)) * (1.0 if q[3] >= 0 else -1.0)
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def matrix_to_euler_zxy(m: np.ndarray) -> tuple[float, float, float]:
    """Degrees (z, x, y) with m = Rz(z) Rx(x) Ry(y): BVH channels ``Zrotation Xrotation Yrotation``."""
    x = math.asin(max(-1.0, min(1.0, m[2, 1])))
    z = math.atan2(-m[0, 1], m[1, 1])
    y = math.atan2(-m[2, 0], m[2, 2])
    return (math.degrees(z), math.degrees(x), math.degrees(y))


# ---------------------------------------------------------------------- the sample motion

def sample_motion(rig: Rig, rest: Pose, frames: int = MOTION_FRAMES) -> list[Pose]:
    """From the T-pose, both arms lower by ARMS_DOWN_DEG (about the forward axis) over ``frames`` frames."""
    return [arms_lowered(rig, rest, ARMS_DOWN_DEG * f / max(frames - 1, 1)) for f in range(frames)]


# ---------------------------------------------------------------------- BVH

def to_bvh(rig: Rig, poses: list[Pose], fps: float) -> str:
    """Position channels on the root only, ``Zrotation Xrotation Yrotation`` everywhere, 6 decimals."""
    joints = []
    for j, name in enumerate(rig.names):
        channels = (("Xposition", "Yposition", "Zposition") if j == 0 else ()) + ("Zrotation", "Xrotation", "Yrotation")
        end = rig.end_sites.get(j)
        if end is None and not rig.children(j):
            end = (0.0, 0.0, 0.0)
        joints.append(BvhJoint(name, rig.parents[j], vec3(rig.offsets[j]), channels, end))
    rows = []
    for pose in poses:
        row = list(pose.root)
        for m in pose.local:
            row.extend(matrix_to_euler_zxy(m))
        rows.append(row)
    return BvhDocument(joints, 1.0 / fps, np.array(rows)).format(precision=6)


# ---------------------------------------------------------------------- glTF

_FLOAT, _USHORT = 5126, 5123


class _Buffer:
    def __init__(self) -> None:
        self.data = bytearray()
        self.views: list[dict[str, Any]] = []
        self.accessors: list[dict[str, Any]] = []

    def add(self, values: np.ndarray, kind: str, component: int, target: int | None = None,
            bounds: bool = False) -> int:
        raw = values.astype("<f4" if component == _FLOAT else "<u2").tobytes()
        while len(self.data) % 4:
            self.data.append(0)
        view: dict[str, Any] = {"buffer": 0, "byteOffset": len(self.data), "byteLength": len(raw)}
        if target is not None:
            view["target"] = target
        self.data += raw
        self.views.append(view)
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[kind]
        acc: dict[str, Any] = {"bufferView": len(self.views) - 1, "componentType": component,
                               "count": int(values.size // width), "type": kind}
        if bounds:
            flat = values.reshape(-1, width).astype(np.float32).astype(np.float64)
            acc["min"] = [round(float(v), 6) for v in flat.min(0)]
            acc["max"] = [round(float(v), 6) for v in flat.max(0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def _stick_mesh(rig: Rig, pos: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An octahedral bone from each joint to each child with a non-zero offset, skinned to the joint."""
    verts: list[np.ndarray] = []
    joints: list[int] = []
    index: list[int] = []
    for k, j in enumerate(rig.parents):
        if j < 0 or np.linalg.norm(rig.offsets[k]) < 1e-3:
            continue
        a, b = pos[j] * scale, pos[k] * scale
        d = b - a
        length = float(np.linalg.norm(d))
        side = np.cross(d, FORWARD if abs(float(unit(d) @ FORWARD)) < 0.9 else UP)
        u = unit(side) * min(0.1 * length, 0.03)
        v = unit(np.cross(d, u)) * min(0.1 * length, 0.03)
        mid = a + 0.2 * d
        base = len(verts)
        verts += [a, mid + u, mid + v, mid - u, mid - v, b]
        joints += [j] * 6
        for i in range(4):
            r0, r1 = base + 1 + i, base + 1 + (i + 1) % 4
            index += [base, r1, r0, base + 5, r0, r1]
    return np.array(verts), np.array(joints), np.array(index)


def to_gltf(rig: Rig, rest: Pose, motion: list[Pose], fps: float) -> dict[str, Any]:
    """A glTF 2.0 document (buffer embedded): a node per joint in the T-pose, a skinned stick mesh, the sample motion.

    glTF's axes are the model's (right-handed, Y up, +Z forward, +X left); lengths are metres.
    """
    scale = {"cm": 0.01, "m": 1.0, "mm": 0.001}.get(rig.units, 0.01)
    world, pos = rest.world(rig)
    buf = _Buffer()
    nodes: list[dict[str, Any]] = []
    for j, name in enumerate(rig.names):
        t = rest.root if j == 0 else rig.offsets[j]
        node: dict[str, Any] = {"name": name, "translation": [round(float(v) * scale, 7) for v in t],
                                "rotation": [round(v, 7) for v in matrix_to_quat(rest.local[j])]}
        kids = rig.children(j)
        if kids:
            node["children"] = kids
        nodes.append(node)
    inverse_bind = []
    for j in range(len(rig.names)):
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = world[j], pos[j] * scale
        inverse_bind.append(np.linalg.inv(m).T.reshape(-1))   # column-major
    verts, vjoints, index = _stick_mesh(rig, pos, scale)
    attrs = {"POSITION": buf.add(verts, "VEC3", _FLOAT, 34962, bounds=True),
             "JOINTS_0": buf.add(np.stack([vjoints, 0 * vjoints, 0 * vjoints, 0 * vjoints], 1), "VEC4", _USHORT, 34962),
             "WEIGHTS_0": buf.add(np.tile([1.0, 0.0, 0.0, 0.0], (len(verts), 1)), "VEC4", _FLOAT, 34962)}
    indices = buf.add(index, "SCALAR", _USHORT, 34963)
    ibm = buf.add(np.array(inverse_bind), "MAT4", _FLOAT)
    nodes.append({"name": "RsmtStickMesh", "mesh": 0, "skin": 0})
    times = buf.add(np.arange(len(motion)) / fps, "SCALAR", _FLOAT, bounds=True)
    channels, samplers = [], []
    for j in range(len(rig.names)):
        quats = np.array([matrix_to_quat(p.local[j]) for p in motion])
        samplers.append({"input": times, "output": buf.add(quats, "VEC4", _FLOAT), "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": j, "path": "rotation"}})
    samplers.append({"input": times, "output": buf.add(np.array([p.root * scale for p in motion]), "VEC3", _FLOAT),
                     "interpolation": "LINEAR"})
    channels.append({"sampler": len(samplers) - 1, "target": {"node": 0, "path": "translation"}})
    return {
        "asset": {"version": "2.0", "generator": "rsmt rig export"},
        "scene": 0,
        "scenes": [{"name": "RsmtRig", "nodes": [0, len(nodes) - 1]}],
        "nodes": nodes,
        "meshes": [{"name": "RsmtStickMesh", "primitives": [{"attributes": attrs, "indices": indices, "mode": 4}]}],
        "skins": [{"name": "RsmtRig", "joints": list(range(len(rig.names))), "skeleton": 0, "inverseBindMatrices": ibm}],
        "animations": [{"name": "ArmsDown", "channels": channels, "samplers": samplers}],
        "accessors": buf.accessors,
        "bufferViews": buf.views,
        "buffers": [{"byteLength": len(buf.data),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(buf.data)).decode()}],
    }


def reference_json(rig: Rig, rest: Pose) -> dict[str, Any]:
    """The skeleton with its T-pose, for the engine helpers' rest-pose correction (``RsmtReferencePose``)."""
    world, _ = rest.world(rig)
    return {
        "format": 1, "units": rig.units, "up_axis": "y", "handedness": "right",
        "joints": [{"name": n, "parent": p, "offset": [float(v) for v in rig.offsets[j]],
                    "t_pose_rotation": [round(v, 9) for v in matrix_to_quat(rest.local[j])],
                    "t_pose_world_rotation": [round(v, 9) for v in matrix_to_quat(world[j])]}
                   for j, (n, p) in enumerate(zip(rig.names, rig.parents))],
        "t_pose_root_position": [round(float(v), 6) for v in rest.root],
    }


def export(skeleton: Path, out: Path, stem: str, fps: float) -> dict[str, Path]:
    """Write ``STEM.bvh``, ``STEM.gltf`` and ``STEM.tpose.json`` under ``out``; returns the paths."""
    rig = Rig.load(skeleton)
    rest = t_pose(rig)
    motion = sample_motion(rig, rest)
    out.mkdir(parents=True, exist_ok=True)
    files = {"bvh": out / f"{stem}.bvh", "gltf": out / f"{stem}.gltf", "tpose": out / f"{stem}.tpose.json"}
    files["bvh"].write_text(to_bvh(rig, motion, fps), encoding="utf-8")
    files["gltf"].write_text(json.dumps(to_gltf(rig, rest, motion, fps), indent=1) + "\n", encoding="utf-8")
    files["tpose"].write_text(json.dumps(reference_json(rig, rest), indent=1) + "\n", encoding="utf-8")
    return files
