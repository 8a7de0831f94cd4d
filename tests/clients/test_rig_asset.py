"""The shipped rig (clients/rig: BVH, glTF, T-pose JSON) is what ``rsmt rig export`` writes for the default model,
reads back through the model's own BVH loader, stands in a T-pose, and is a well-formed skinned glTF 2.0 whose
joints sit where the model's forward kinematics puts them. The Unity package has a ``.meta`` per asset."""

from __future__ import annotations

import base64
import json
import re
import struct
from pathlib import Path

import numpy as np
import pytest
import torch

from model.motion.bvh_clip import load_clip
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_to_matrix
from rsmt_cli.main import main as rsmt_main
from rsmt_cli.unity_meta import assets, ignored
from tests.clients.helpers import REPO, UNITY

RIG = REPO / "clients" / "rig"
STEM = "rsmt-default-rig"
GLTF_FLOAT = 5126  # a glTF accessor's componentType for float32 (the rig's other one: 5123, uint16)


def read_accessor(gltf: dict, index: int) -> np.ndarray:
    """An accessor's values of a document with one embedded buffer, as float64 [count, width]."""
    acc = gltf["accessors"][index]
    view = gltf["bufferViews"][acc["bufferView"]]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[acc["type"]]
    fmt = "f" if acc["componentType"] == GLTF_FLOAT else "H"
    data = base64.b64decode(gltf["buffers"][0]["uri"].split(",", 1)[1])
    raw = data[view["byteOffset"]:view["byteOffset"] + acc["count"] * width * struct.calcsize("<" + fmt)]
    return np.array(struct.unpack(f"<{acc['count'] * width}{fmt}", raw), dtype=np.float64).reshape(acc["count"], width)


SKELETON = json.loads((REPO / "model" / "default_bundle" / "skeleton.json").read_text())
NAMES = [j["name"] for j in SKELETON["joints"]]
PARENTS = [j["parent"] for j in SKELETON["joints"]]


@pytest.fixture(scope="module")
def tpose() -> dict:
    return json.loads((RIG / f"{STEM}.tpose.json").read_text())


@pytest.fixture(scope="module")
def gltf() -> dict:
    return json.loads((RIG / f"{STEM}.gltf").read_text())


def tpose_positions(tpose: dict) -> np.ndarray:
    rots = torch.tensor([j["t_pose_rotation"] for j in tpose["joints"]], dtype=torch.float64)
    offsets = torch.tensor([j["offset"] for j in tpose["joints"]], dtype=torch.float64)
    pos, _ = forward_kinematics(rots, torch.tensor(tpose["t_pose_root_position"], dtype=torch.float64), offsets, PARENTS)
    return pos.numpy()


def test_shipped_files_are_what_the_generator_writes(tmp_path):
    assert rsmt_main(["rig", "export", "--out", str(tmp_path)]) == 0
    for suffix in (".bvh", ".tpose.json"):  # text, rounded when written: byte for byte
        assert (tmp_path / f"{STEM}{suffix}").read_bytes() == (RIG / f"{STEM}{suffix}").read_bytes(), suffix
    # The glTF's binary buffer holds float32 matrices as computed: another CPU's rounding may change a last
    # bit (an inverse bind matrix entry of 0 came out 3.5e-25 on an AVX2 machine). The rest byte for byte.
    written, shipped = json.loads((tmp_path / f"{STEM}.gltf").read_text()), json.loads((RIG / f"{STEM}.gltf").read_text())
    assert [b["byteLength"] for b in written["buffers"]] == [b["byteLength"] for b in shipped["buffers"]]
    assert {**written, "buffers": None} == {**shipped, "buffers": None}
    for i in range(len(shipped["accessors"])):
        np.testing.assert_allclose(read_accessor(written, i), read_accessor(shipped, i), rtol=0, atol=1e-6,
                                   err_msg=f"accessor {i}")
    assert all(p.stat().st_size < 64_000 for p in RIG.iterdir())
    # The Unity package carries the T-pose as a TextAsset for RsmtPoseRecorder / RsmtHumanoidBridge.
    assert (UNITY / "Rig" / f"{STEM}.tpose.json").read_bytes() == (RIG / f"{STEM}.tpose.json").read_bytes()


def test_tpose_is_the_model_skeleton_standing_in_a_t_pose(tpose):
    assert [j["name"] for j in tpose["joints"]] == NAMES and [j["parent"] for j in tpose["joints"]] == PARENTS
    np.testing.assert_allclose([j["offset"] for j in tpose["joints"]], [j["offset"] for j in SKELETON["joints"]])
    assert (tpose["units"], tpose["up_axis"], tpose["handedness"]) == ("cm", "y", "right")
    p = tpose_positions(tpose)
    i = NAMES.index
    assert p[i("Head"), 1] > p[i("Neck"), 1] > p[i("Chest"), 1] > p[i("Hips"), 1] > p[i("Foot_L"), 1]   # upright
    assert p[i("Hand_L"), 0] > 50 and p[i("Hand_R"), 0] < -50                   # left on +X, arms straight out
    np.testing.assert_allclose(p[[i("Hand_L"), i("Hand_R")], 1], p[i("UpperArm_L"), 1], atol=1e-2)
    assert p[i("Toes_L"), 2] > 5 and p[i("Toes_R"), 2] > 5                      # facing +Z
    assert p[:, 1].min() == pytest.approx(2.0, abs=1e-6)                        # toes 2 cm above the ground
    world = torch.tensor([j["t_pose_world_rotation"] for j in tpose["joints"]], dtype=torch.float64)
    _, fk_world = forward_kinematics(torch.tensor([j["t_pose_rotation"] for j in tpose["joints"]], dtype=torch.float64),
                                     torch.zeros(3, dtype=torch.float64), torch.zeros(21, 3, dtype=torch.float64), PARENTS)
    np.testing.assert_allclose(quat_to_matrix(world).numpy(), quat_to_matrix(fk_world).numpy(), atol=1e-7)


def test_bvh_reads_back_through_the_model_loader(tpose):
    clip = load_clip(RIG / f"{STEM}.bvh")
    assert clip.skeleton.names == tuple(NAMES) and clip.fps == 30.0 and clip.num_frames == 31
    np.testing.assert_allclose(clip.skeleton.offsets_tensor(torch.float64).numpy()[1:],
                               [j["offset"] for j in SKELETON["joints"]][1:], atol=1e-9)
    pos, _ = clip.global_transforms()
    np.testing.assert_allclose(pos[0].double().numpy(), tpose_positions(tpose), atol=1e-3)   # frame 0: the T-pose
    last = pos[-1].double().numpy()
    i = NAMES.index
    assert last[i("Hand_L"), 1] < last[i("UpperArm_L"), 1] - 10 and last[i("Hand_L"), 0] > 30   # arms lowered sideways
    assert last[i("Hand_R"), 1] < last[i("UpperArm_R"), 1] - 10 and last[i("Hand_R"), 0] < -30


def _node_matrix(node: dict) -> np.ndarray:
    m = np.eye(4)
    q = torch.tensor(node.get("rotation", [0, 0, 0, 1]), dtype=torch.float64)
    m[:3, :3] = quat_to_matrix(q).numpy()
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def _check_accessors(gltf: dict) -> None:
    buffer_len = gltf["buffers"][0]["byteLength"]
    uri = gltf["buffers"][0]["uri"]
    assert uri.startswith("data:application/octet-stream;base64,")
    sizes = {5126: 4, 5123: 2}
    widths = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}
    for view in gltf["bufferViews"]:
        assert view["buffer"] == 0 and view["byteOffset"] % 4 == 0 and view["byteOffset"] + view["byteLength"] <= buffer_len
    for acc in gltf["accessors"]:
        view = gltf["bufferViews"][acc["bufferView"]]
        assert acc["componentType"] in sizes and acc["type"] in widths
        assert acc["count"] * widths[acc["type"]] * sizes[acc["componentType"]] == view["byteLength"]
        if "min" in acc:
            data = read_accessor(gltf, gltf["accessors"].index(acc))
            np.testing.assert_allclose(data.min(0), acc["min"], atol=1e-6)
            np.testing.assert_allclose(data.max(0), acc["max"], atol=1e-6)


def _check_node_tree(gltf: dict) -> tuple[dict[int, int], list[int]]:
    """The nodes form a tree whose roots are the scene's nodes, with unit rotations; returns child -> parent
    and the roots."""
    nodes = gltf["nodes"]
    child_of: dict[int, int] = {}
    for n, node in enumerate(nodes):
        for c in node.get("children", []):
            assert c not in child_of and 0 <= c < len(nodes)   # a tree: one parent per node
            child_of[c] = n
        if "rotation" in node:
            assert abs(np.linalg.norm(node["rotation"]) - 1.0) < 1e-6
    roots = [n for n in range(len(nodes)) if n not in child_of]
    assert sorted(gltf["scenes"][gltf["scene"]]["nodes"]) == roots
    return child_of, roots


def _check_mesh(gltf: dict, mesh_node: dict) -> None:
    """The skinned mesh's attributes agree in length, index its vertices and weigh existing joints to 1."""
    prim = gltf["meshes"][mesh_node["mesh"]]["primitives"][0]
    verts = read_accessor(gltf, prim["attributes"]["POSITION"])
    joints = read_accessor(gltf, prim["attributes"]["JOINTS_0"])
    weights = read_accessor(gltf, prim["attributes"]["WEIGHTS_0"])
    index = read_accessor(gltf, prim["indices"])
    assert len(verts) == len(joints) == len(weights) and index.max() < len(verts) and len(index) % 3 == 0
    assert joints.max() < len(NAMES) and np.allclose(weights.sum(1), 1.0)


def test_gltf_is_a_well_formed_skinned_rig(gltf, tpose):
    assert gltf["asset"]["version"] == "2.0"
    _check_accessors(gltf)
    nodes = gltf["nodes"]
    child_of, roots = _check_node_tree(gltf)
    skin = gltf["skins"][0]
    assert [nodes[j]["name"] for j in skin["joints"]] == NAMES
    assert [child_of.get(j, -1) for j in skin["joints"]] == PARENTS and nodes[skin["skeleton"]]["name"] == "Hips"
    mesh_node = next(n for n in nodes if "mesh" in n)
    assert mesh_node["skin"] == 0 and nodes.index(mesh_node) in roots
    # Joint world matrices from the node tree (metres): positions are the T-pose's, inverse binds undo them.
    world: list[np.ndarray] = []
    for j, parent in enumerate(PARENTS):
        local = _node_matrix(nodes[skin["joints"][j]])
        world.append(local if parent < 0 else world[parent] @ local)
    np.testing.assert_allclose([w[:3, 3] for w in world], tpose_positions(tpose) * 0.01, atol=1e-6)
    ibm = read_accessor(gltf, skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)   # column-major
    for j in range(len(NAMES)):
        np.testing.assert_allclose(ibm[j] @ world[j], np.eye(4), atol=1e-5)
    _check_mesh(gltf, mesh_node)


def test_gltf_animation_matches_the_bvh(gltf):
    anim = gltf["animations"][0]
    clip = load_clip(RIG / f"{STEM}.bvh")
    pos, _ = clip.global_transforms()
    rots = np.zeros((clip.num_frames, len(NAMES), 4))
    root = np.zeros((clip.num_frames, 3))
    for ch in anim["channels"]:
        s = anim["samplers"][ch["sampler"]]
        times = read_accessor(gltf, s["input"])[:, 0]
        np.testing.assert_allclose(times, np.arange(clip.num_frames) / 30.0, atol=1e-6)
        values = read_accessor(gltf, s["output"])
        if ch["target"]["path"] == "rotation":
            rots[:, ch["target"]["node"]] = values
        else:
            assert ch["target"]["node"] == 0 and ch["target"]["path"] == "translation"
            root = values / 0.01
    offsets = torch.tensor([j["offset"] for j in SKELETON["joints"]], dtype=torch.float64)
    gpos, _ = forward_kinematics(torch.tensor(rots), torch.tensor(root), offsets, PARENTS)
    np.testing.assert_allclose(gpos.numpy(), pos.double().numpy(), atol=1e-3)


def test_unity_package_has_a_meta_per_asset_with_unique_guids():
    found = assets(UNITY)
    assert any(p.suffix == ".cs" for p in found) and Path("Runtime") in found
    guids = []
    for rel in found:
        meta = UNITY / (rel.as_posix() + ".meta")
        assert meta.is_file(), f"{rel} has no .meta"
        text = meta.read_text()
        m = re.search(r"^guid: ([0-9a-f]{32})$", text, re.M)
        assert m and text.startswith("fileFormatVersion: 2\n"), meta
        assert ("folderAsset: yes" in text) == (UNITY / rel).is_dir()
        guids.append(m.group(1))
    assert len(set(guids)) == len(guids)
    # No .meta in folders Unity ignores, none without its asset; and the generator has nothing to change.
    metas = [p.relative_to(UNITY) for p in UNITY.rglob("*.meta")]
    assert not [p for p in metas if ignored(p)]
    assert sorted(metas) == sorted(Path(r.as_posix() + ".meta") for r in found)
    assert rsmt_main(["rig", "unity-meta", "--package", str(UNITY), "--check"]) == 0


def test_unity_meta_generator_is_deterministic_and_finds_gaps(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "Runtime").mkdir(parents=True)
    (pkg / "Harness~").mkdir()
    (pkg / "package.json").write_text('{"name": "com.example.test"}')
    (pkg / "Runtime" / "A.cs").write_text("class A {}")
    (pkg / "Harness~" / "B.cs").write_text("class B {}")
    assert rsmt_main(["rig", "unity-meta", "--package", str(pkg), "--check"]) == 1
    assert rsmt_main(["rig", "unity-meta", "--package", str(pkg)]) == 0
    first = {p.name: p.read_text() for p in pkg.rglob("*.meta")}
    assert set(first) == {"package.json.meta", "Runtime.meta", "A.cs.meta"}      # nothing under Harness~
    assert "MonoImporter" in first["A.cs.meta"] and "PackageManifestImporter" in first["package.json.meta"]
    (pkg / "Runtime" / "A.cs.meta").unlink()
    (pkg / "Runtime" / "Gone.cs.meta").write_text("fileFormatVersion: 2\n")
    assert rsmt_main(["rig", "unity-meta", "--package", str(pkg), "--check"]) == 1
    assert rsmt_main(["rig", "unity-meta", "--package", str(pkg)]) == 0
    assert {p.name: p.read_text() for p in pkg.rglob("*.meta")} == first          # same GUIDs, orphan removed
