"""Built-in styles in a bundle (``styles/``): written and read back exactly, independent of the weights, checked."""

from __future__ import annotations

import json

import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.inference.bundle import Bundle, BundleError
from model.inference.bundle_styles import (
    BuiltinStyle,
    StyleFolderError,
    clip_on_rig,
    read_style_bvh,
    save_styles,
    styles_from_folder,
)
from model.motion.bvh_clip import dump_clip
from model.motion.clip import Clip
from model.motion.skeleton import Skeleton
from tests.model.tiny_bundles import tiny_bundle


def test_styles_round_trip_and_leave_the_weights_alone(tmp_path) -> None:
    bundle = tiny_bundle(1)
    path = bundle.save(tmp_path / "b")
    weights = (path / "weights.safetensors").read_bytes()
    config = (path / "config.json").read_text()
    clips = {"slow": synthetic_walk(40, speed_cm_s=60.0), "brisk": synthetic_walk(50, speed_cm_s=160.0)}
    save_styles(path, [BuiltinStyle(n, c, f"{n}.bvh") for n, c in clips.items()], bundle.skeleton, 30.0)
    assert (path / "weights.safetensors").read_bytes() == weights and (path / "config.json").read_text() == config
    loaded = Bundle.load(path)
    assert loaded.version == bundle.version and sorted(loaded.styles) == ["brisk", "slow"]
    for name, clip in clips.items():
        got = loaded.styles[name].clip
        assert torch.equal(got.rotations, clip.rotations) and torch.equal(got.root_positions, clip.root_positions)
        assert got.skeleton.names == bundle.skeleton.names and got.fps == 30.0
    index = json.loads((path / "styles" / "styles.json").read_text())
    assert index["styles"][0] == {"name": "brisk", "frames": 50, "source": "brisk.bvh"}
    # A copy saved from the loaded bundle keeps them; an empty set removes the folder.
    Bundle.load(path).save(tmp_path / "copy")
    assert sorted(Bundle.load(tmp_path / "copy").styles) == ["brisk", "slow"]
    save_styles(path, [], bundle.skeleton, 30.0)
    assert not (path / "styles").exists() and Bundle.load(path).styles == {}


def test_a_damaged_styles_folder_does_not_load(tmp_path) -> None:
    bundle = tiny_bundle(2)
    path = bundle.save(tmp_path / "b")
    save_styles(path, [BuiltinStyle("walk", synthetic_walk(30))], bundle.skeleton, 30.0)
    index = path / "styles" / "styles.json"
    data = json.loads(index.read_text())
    index.write_text(json.dumps({**data, "fps": 60.0}))
    with pytest.raises(BundleError, match="60"):
        Bundle.load(path)
    index.write_text(json.dumps({**data, "styles": [{"name": "other", "frames": 30}]}))
    with pytest.raises(BundleError, match="'other' is missing"):
        Bundle.load(path)


@pytest.mark.parametrize("name", ["", "builtin:x", "a b", "../up", "-dash"])
def test_style_names_are_checked(tmp_path, name: str) -> None:
    bundle = tiny_bundle(3)
    with pytest.raises(StyleFolderError, match="style name"):
        save_styles(tmp_path, [BuiltinStyle(name, synthetic_walk(20))], bundle.skeleton, 30.0)


def test_a_folder_of_clips_one_file_or_one_folder_per_style(tmp_path) -> None:
    sk = tiny_bundle(4).skeleton
    (tmp_path / "styles").mkdir()
    (tmp_path / "styles" / "proud.bvh").write_text(dump_clip(synthetic_walk(61, fps=60.0)))
    (tmp_path / "styles" / "tired").mkdir()
    (tmp_path / "styles" / "tired" / "b.bvh").write_text(dump_clip(synthetic_walk(20)))
    (tmp_path / "styles" / "tired" / "a.bvh").write_text(dump_clip(synthetic_walk(25)))
    found = {s.name: s for s in styles_from_folder(tmp_path / "styles", sk, 30.0)}
    assert sorted(found) == ["proud", "tired"]
    assert found["proud"].frames == 31 and found["tired"].frames == 25 and found["tired"].source == "tired/a.bvh"
    cut = read_style_bvh(tmp_path / "styles" / "proud.bvh", sk, 30.0, start=5, frames=10)
    assert cut.num_frames == 10 and torch.allclose(cut.rotations, found["proud"].clip.rotations[5:15], atol=1e-5)
    with pytest.raises(StyleFolderError, match="outside its 31 frames"):
        read_style_bvh(tmp_path / "styles" / "proud.bvh", sk, 30.0, start=25, frames=10)
    with pytest.raises(StyleFolderError, match="no BVH files"):
        (tmp_path / "empty").mkdir()
        styles_from_folder(tmp_path / "empty", sk, 30.0)


def test_a_clip_of_another_rest_pose_is_refused_not_bent(tmp_path) -> None:
    sk = tiny_bundle(5).skeleton
    walk = synthetic_walk(20)
    # The same names with the legs pointing sideways at rest: the viewer's old demos bent exactly so.
    offsets = [list(o) for o in sk.offsets]
    for j in (sk.index("LowerLeg_L"), sk.index("Foot_L")):
        offsets[j] = [-offsets[j][1], 0.0, 0.0]
    other = Skeleton.build(sk.names, sk.parents, offsets, profile="bandai-namco")
    with pytest.raises(StyleFolderError, match="rest pose differs"):
        clip_on_rig(Clip(other, walk.rotations, walk.root_positions, 30.0), sk, 30.0, "sideways.bvh")
    same = clip_on_rig(walk, sk, 30.0, "walk")
    assert torch.allclose(same.global_positions(), walk.global_positions(), atol=1e-3)
