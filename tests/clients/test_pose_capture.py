"""Pose-from-rig helpers of both engine clients (Unity ``RsmtPoseCapture.cs`` with mcs/mono, Unreal
``RsmtPoseCapture.cpp`` with g++), against the Python side on the default model's rig.

A pose is built in Python in the model's axes (the shipped T-pose plus known rotations) and written the way each
engine would hold it, derived independently of the clients' quaternion formulas: rotation matrices conjugated by
the axis map (Unity: mirror X; Unreal: swap Y and Z) and offsets mapped by it. The engine helpers must give back
the Python pose in the API's format, and their own forward kinematics must put every joint where the model's
forward kinematics (model.motion.kinematics) does, mapped to the engine's axes. A copy of each helper with the
handedness conversion removed is built too and must fail the same comparison.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from model.motion.kinematics import forward_kinematics
from model.motion.rotations import axis_angle_to_quat, matrix_to_quat, quat_mul, quat_rotate, quat_to_matrix, yaw_quat
from tests.clients.helpers import CORE, CXX_FLAGS, REPO, UNITY, UNREAL, core_objects, gxx, mono_tools, run

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]  # slow: compiles with mcs and g++

REFERENCE = REPO / "clients" / "rig" / "rsmt-default-rig.tpose.json"
MIRROR_X = np.diag([-1.0, 1.0, 1.0])                                          # model -> Unity (then metres)
SWAP_YZ = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])      # model -> Unreal (cm)
UNITY_SCALE, UNREAL_SCALE = 0.01, 1.0
# Known rotations on top of the T-pose: (joint, axis in the joint's parent frame, degrees); every axis has x, y, z parts.
TURNS = [("Hips", (0.2, 1.0, 0.1), 35.0), ("Spine", (0.5, -0.3, 0.8), 20.0), ("UpperArm_L", (0.3, -0.5, 0.8), 50.0),
         ("LowerArm_L", (0.0, 0.4, 1.0), 60.0), ("UpperLeg_R", (0.7, 0.2, -0.4), 30.0), ("Head", (-0.3, 0.9, 0.2), 25.0)]
ROOT = (12.0, 88.0, -30.0)


# ---------------------------------------------------------------------- the pose on the Python side

def _reference() -> dict:
    return json.loads(REFERENCE.read_text())


def _t(x) -> torch.Tensor:
    return torch.tensor(np.asarray(x, dtype=np.float64))


def model_pose() -> tuple[np.ndarray, np.ndarray]:
    """Root position [3] and local rotations [J, 4] (model axes): T-pose with TURNS applied."""
    ref = _reference()
    names = [j["name"] for j in ref["joints"]]
    rots = _t([j["t_pose_rotation"] for j in ref["joints"]])
    for name, axis, deg in TURNS:
        j = names.index(name)
        a = _t(axis) / _t(axis).norm()
        rots[j] = quat_mul(axis_angle_to_quat(a, _t(math.radians(deg))), rots[j])
    return np.array(ROOT), rots.numpy()


def model_fk(root: np.ndarray, rots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ref = _reference()
    pos, world = forward_kinematics(_t(rots), _t(root), _t([j["offset"] for j in ref["joints"]]),
                                    [j["parent"] for j in ref["joints"]])
    return pos.numpy(), world.numpy()


def to_engine(q: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Quaternions [..., 4] of rotations R conjugated by the axis map: M R M^-1 (as matrices, then back)."""
    mats = quat_to_matrix(_t(q)).numpy()
    return matrix_to_quat(_t(m @ mats @ m.T)).numpy()


def same_rotations(a: np.ndarray, b: np.ndarray, atol: float = 1e-6) -> bool:
    """Equal up to the sign of each quaternion (q and -q are one rotation)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    dots = np.abs(np.sum(a * b, axis=-1)) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return bool(np.all(1.0 - dots < atol))


def write_case(path: Path, engine: str) -> dict:
    """The inputs both harnesses read: the pose as the engine holds it, a retarget rig, a history."""
    m, scale = (MIRROR_X, UNITY_SCALE) if engine == "unity" else (SWAP_YZ, UNREAL_SCALE)
    ref = _reference()
    root, rots = model_pose()
    parents = [j["parent"] for j in ref["joints"]]
    offsets = np.array([j["offset"] for j in ref["joints"]])
    # A game rig with other bone frames: reference world rotations G_j (arbitrary), in the same T-pose.
    g = torch.Generator().manual_seed(3)
    game_ref = torch.nn.functional.normalize(torch.randn(len(parents), 4, generator=g, dtype=torch.float64), dim=-1).numpy()
    _, world_pose = model_fk(root, rots)
    _, world_t = model_fk(np.array(ref["t_pose_root_position"]), np.array([j["t_pose_rotation"] for j in ref["joints"]]))
    delta = quat_mul(_t(world_pose), _t(world_t) * _t([-1.0, -1.0, -1.0, 1.0])).numpy()   # W_pose W_T^-1 (model axes)
    game_world = quat_mul(_t(to_engine(delta, m)), _t(game_ref)).numpy()                 # the rig's own frames on top
    t = np.cumsum([0.0] + [1 / 60 + 0.004 * math.sin(3.0 * i) for i in range(40)])       # ~60 Hz with jitter
    history = [{"t": float(ti), "root": [100.0 * float(ti), 0.0, 0.0],
                "rotations": [yaw_quat(_t(math.radians(90.0 * ti))).tolist()] * 2} for ti in t]
    case = {
        "parents": parents, "metres_per_unit": UNITY_SCALE, "cm_per_unit": UNREAL_SCALE,
        f"{engine}_local": to_engine(rots, m).tolist(), f"{engine}_root": (m @ root * scale).tolist(),
        f"{engine}_offsets": (offsets @ m.T * scale).tolist(),
        "reference_path": str(REFERENCE), "game_reference_world": game_ref.tolist(), "game_world": game_world.tolist(),
        "game_root": (m @ root * scale).tolist(), "history": history, "history_fps": 30.0, "history_frames": 10,
    }
    path.write_text(json.dumps(case))
    return {"t": t}


# ---------------------------------------------------------------------- builds (the real helpers and a broken copy)

def _unity_sources(tmp: Path, broken: bool) -> list[str]:
    sources = sorted((UNITY / "Runtime" / "Core").glob("*.cs"))
    if not broken:
        return [str(p) for p in sources]
    out = []
    for p in sources:
        text = p.read_text()
        if p.name == "RsmtCoordinates.cs":
            old = ("public static RsmtQuat UnityToModelRotation(RsmtQuat q)\n        {\n"
                   "            return new RsmtQuat(q.X, -q.Y, -q.Z, q.W);")
            assert old in text
            text = text.replace(old, old.replace("(q.X, -q.Y, -q.Z, q.W)", "(q.X, q.Y, q.Z, q.W)"))
        (tmp / p.name).write_text(text)
        out.append(str(tmp / p.name))
    return out


def build_unity(tmp: Path, broken: bool = False) -> Path:
    mcs, _ = mono_tools()
    exe = tmp / "RsmtPoseHarness.exe"
    run([mcs, "-nologo", "-warnaserror", "-r:System.Net.Http.dll", f"-out:{exe}", *_unity_sources(tmp, broken),
         str(UNITY / "Harness~" / "RsmtPoseHarness.cs")], timeout=300)
    return exe


def build_unreal(tmp: Path, broken: bool = False) -> Path:
    """The pose test program; ``broken``: with RsmtConvert's rotation conversion wrong (compiled here, the other
    sources' objects shared with the other Unreal builds)."""
    names = ["RsmtJson.cpp", "RsmtMath.cpp", "RsmtConvert.cpp", "RsmtProtocol.cpp", "RsmtPoseCapture.cpp"]
    sources = [str(obj) for obj in core_objects(tmp, [n for n in names if not (broken and n == "RsmtConvert.cpp")])]
    if broken:
        text = (CORE / "Private" / "RsmtConvert.cpp").read_text()
        old = "Quat UnrealToModelRotation(const Quat& q) {\n    return Quat{-q.x, -q.z, -q.y, q.w};"
        assert old in text
        (tmp / "RsmtConvert.cpp").write_text(text.replace(old, old.replace("{-q.x, -q.z, -q.y, q.w}", "{q.x, q.z, q.y, q.w}")))
        sources.append(str(tmp / "RsmtConvert.cpp"))
    exe = tmp / "rsmt_pose_test"
    run([gxx(), *CXX_FLAGS, *sources, str(UNREAL / "Tests" / "rsmt_pose_test.cpp"), "-o", str(exe)], timeout=600)
    return exe


def run_case(engine: str, exe: Path, case: Path) -> dict:
    if engine == "unity":
        _, mono = mono_tools()
        cmd = [mono, str(exe), str(case)]
    else:
        cmd = [str(exe), str(case)]
    return json.loads(run(cmd, timeout=120).stdout)


def motion_pose(motion: dict) -> tuple[np.ndarray, np.ndarray]:
    return np.array(motion["root_positions"][0]), np.array(motion["rotations"][0])


# ---------------------------------------------------------------------- tests

@pytest.fixture(scope="module", params=["unity", "unreal"])
def engine(request, tmp_path_factory) -> dict:
    name = request.param
    tmp = tmp_path_factory.mktemp(f"pose-{name}")
    exe = build_unity(tmp) if name == "unity" else build_unreal(tmp)
    case = tmp / "case.json"
    extra = write_case(case, name)
    return {"name": name, "exe": exe, "case": case, "out": run_case(name, exe, case), "tmp": tmp, **extra}


def test_exact_capture_gives_the_python_pose(engine):
    """Bones with the model's frames: local rotations and the root convert back to the pose Python built."""
    root, rots = model_pose()
    got_root, got_rots = motion_pose(engine["out"]["exact"])
    np.testing.assert_allclose(got_root, root, atol=1e-9)
    assert same_rotations(got_rots, rots, 1e-12)
    # The API's format: root_positions [frames][3], rotations [frames][joints][4], unit quaternions.
    assert np.allclose(np.linalg.norm(got_rots, axis=-1), 1.0, atol=1e-12) and got_rots.shape == (21, 4)


def test_engine_forward_kinematics_matches_the_model(engine):
    """The engine-side pose is the same body: its FK equals the model's FK mapped to engine axes (left stays left)."""
    root, rots = model_pose()
    pos, _ = model_fk(root, rots)
    name = engine["name"]
    m, scale = (MIRROR_X, UNITY_SCALE) if name == "unity" else (SWAP_YZ, UNREAL_SCALE)
    got = np.array(engine["out"][f"{name}_fk"])
    np.testing.assert_allclose(got, pos @ m.T * scale, atol=1e-5 * scale)
    hand_l = [j["name"] for j in _reference()["joints"]].index("Hand_L")
    assert pos[hand_l, 0] - pos[0, 0] > 30.0                     # model: the character's left is +X
    if name == "unity":
        assert got[hand_l, 0] - got[0, 0] < -0.3                # Unity: +X is the character's right
    else:
        assert got[hand_l, 0] - got[0, 0] > 30.0 and got[:, 2].max() > 1.3 * 100 * UNREAL_SCALE  # Z is up


def test_retarget_capture_through_reference_poses(engine):
    """A rig with other bone frames, captured with RetargetOffsets from its reference (T-)pose: the same model pose."""
    root, rots = model_pose()
    got_root, got_rots = motion_pose(engine["out"]["retarget"])
    np.testing.assert_allclose(got_root, root, atol=1e-9)
    assert same_rotations(got_rots, rots, 1e-10)
    pos, _ = model_fk(root, rots)
    np.testing.assert_allclose(model_fk(got_root, got_rots)[0], pos, atol=1e-6)
    assert engine["out"]["reference_names"] == [j["name"] for j in _reference()["joints"]]


def test_turn_left_is_a_turn_left_in_the_model(engine):
    """The engine's turn toward the character's left becomes +90 degrees about the model's Y (Python's yaw_quat)."""
    got_root, got_rots = motion_pose(engine["out"]["turn_left"])
    want = yaw_quat(torch.tensor(math.radians(90.0), dtype=torch.float64)).numpy()
    assert same_rotations(got_rots[0], want, 1e-12)
    forward = quat_rotate(_t(got_rots[0]), _t([0.0, 0.0, 1.0])).numpy()
    np.testing.assert_allclose(forward, [1.0, 0.0, 0.0], atol=1e-12)   # model forward +Z turns to +X, the left
    np.testing.assert_allclose(got_root, [-10.0, 20.0, 30.0] if engine["name"] == "unity" else [10.0, 20.0, 30.0],
                               atol=1e-9)


def test_history_resamples_to_the_model_fps(engine):
    out = engine["out"]
    t0 = engine["t"][0]
    history = out["history"]
    samples = int(math.floor((engine["t"][-1] - t0) * 30.0 + 1e-9)) + 1
    assert out["history_count"] == min(samples, 16) and history["fps"] == 30.0
    roots = np.array(history["root_positions"])
    times = t0 + np.arange(samples - 10, samples) / 30.0
    np.testing.assert_allclose(roots[:, 0], 100.0 * times, atol=1e-9)   # linear in time: exact at the 30 fps ticks
    yaw = np.array([2 * math.atan2(q[0][1], q[0][3]) for q in history["rotations"]])
    np.testing.assert_allclose(yaw, np.radians(90.0 * times), atol=2e-4)


def test_broken_handedness_is_caught(engine):
    """Without the handedness conversion the same case no longer gives the Python pose."""
    tmp = engine["tmp"] / "broken"
    tmp.mkdir(exist_ok=True)
    exe = build_unity(tmp, broken=True) if engine["name"] == "unity" else build_unreal(tmp, broken=True)
    out = run_case(engine["name"], exe, engine["case"])
    _, rots = model_pose()
    assert not same_rotations(motion_pose(out["exact"])[1], rots, 1e-3)
    assert not same_rotations(motion_pose(out["retarget"])[1], rots, 1e-3)
    assert not same_rotations(motion_pose(out["turn_left"])[1][0],
                              yaw_quat(torch.tensor(math.radians(90.0), dtype=torch.float64)).numpy(), 1e-3)


def test_the_server_reads_the_helpers_payloads(engine):
    """The helpers' Motion payloads pass the service's own schema and pose reader on the default model's skeleton."""
    from model.motion.skeleton import Skeleton
    from service.motion import MotionLimits, _pose_clip
    from service.schemas import PoseMotion

    skeleton = Skeleton.load(REPO / "model" / "default_bundle" / "skeleton.json")
    root, rots = model_pose()
    motion = PoseMotion.model_validate(engine["out"]["exact"])
    clip = _pose_clip(motion, skeleton, 30.0, MotionLimits(), "context")
    np.testing.assert_allclose(clip.root_positions[0].numpy(), root, atol=1e-4)
    assert same_rotations(clip.rotations[0].double().numpy(), rots, 1e-6)
    history = PoseMotion.model_validate(engine["out"]["history"])
    assert history.fps == 30.0 and len(history.rotations) == 10
