"""Built-in styles in a bundle (``styles/``): codes encoded by the bundle's own engine at packaging time, stored
without motion, read back exactly, independent of the weights file, and refused when they belong to other weights
or are of the older clip format."""

from __future__ import annotations

import json
import logging
import shutil
from dataclasses import fields

import pytest
import torch
from safetensors.torch import load_file, save_file

from model.data.synthetic import synthetic_walk
from model.inference.bundle import Bundle, BundleError
from model.inference.bundle_styles import (
    StyleClip,
    StyleFolderError,
    clip_on_rig,
    read_style_bvh,
    save_styles,
    styles_from_folder,
)
from model.inference.engine import Engine
from model.inference.style_packing import encode_styles, write_builtin_styles
from model.motion.bvh_clip import dump_clip
from model.motion.clip import Clip
from model.motion.skeleton import Skeleton
from model.nets.sampler import StyleContext
from tests.model.tiny_bundles import tiny_bundle

CLIPS = {"slow": (40, 60.0), "brisk": (50, 160.0)}


def style_clips() -> list[StyleClip]:
    return [StyleClip(n, synthetic_walk(f, speed_cm_s=v), f"{n}.bvh") for n, (f, v) in CLIPS.items()]


def same_context(a: StyleContext, b: StyleContext) -> bool:
    return all(torch.equal(getattr(a, f.name), getattr(b, f.name)) for f in fields(StyleContext))


def test_codes_round_trip_leave_the_weights_alone_and_store_no_motion(tmp_path) -> None:
    bundle = tiny_bundle(1)
    path = bundle.save(tmp_path / "b")
    weights = (path / "weights.safetensors").read_bytes()
    config = (path / "config.json").read_text()
    folder, written = write_builtin_styles(path, style_clips())
    assert (path / "weights.safetensors").read_bytes() == weights and (path / "config.json").read_text() == config
    loaded = Bundle.load(path)
    assert loaded.version == bundle.version and sorted(loaded.styles) == ["brisk", "slow"]
    # The stored code is what the bundle's engine computes from the clip (the service serves it as it is).
    engine = Engine(Bundle.load(path, styles=False), threads=1)
    for item in style_clips():
        got = loaded.styles[item.name]
        assert got.frames == item.frames and got.source == f"{item.name}.bvh" and got.version == bundle.version
        assert same_context(got.context, engine.encode_style(item.clip)[0].context)
    assert sorted(p.name for p in folder.iterdir()) == ["codes.safetensors", "styles.json"]
    stored = load_file(str(folder / "codes.safetensors"))
    assert {k.split("/")[1] for k in stored} == {f.name for f in fields(StyleContext)}  # no rotations, no positions
    index = json.loads((folder / "styles.json").read_text())
    assert index["format"] == "rsmt-styles/2" and index["version"] == bundle.version
    assert index["styles"][0] == {"name": "brisk", "frames": 50, "source": "brisk.bvh"}
    assert [s.name for s in written] == ["slow", "brisk"]
    # A copy saved from the loaded bundle (same weights) keeps them; an empty set removes the folder.
    Bundle.load(path).save(tmp_path / "copy")
    assert sorted(Bundle.load(tmp_path / "copy").styles) == ["brisk", "slow"]
    save_styles(path, [], bundle.skeleton, 30.0, bundle.version)
    assert not (path / "styles").exists() and Bundle.load(path).styles == {}


def test_codes_of_other_weights_do_not_load_and_name_both_versions(tmp_path, caplog) -> None:
    a, b = tiny_bundle(1).save(tmp_path / "a"), tiny_bundle(2).save(tmp_path / "b")
    write_builtin_styles(a, style_clips())
    va, vb = Bundle.load(a).version, Bundle.load(b).version
    shutil.copytree(a / "styles", b / "styles")
    with pytest.raises(BundleError, match=f"encoded by model version {va}.*weights are version {vb}") as err:
        Bundle.load(b)
    assert "rsmt bundle add-styles" in str(err.value)
    # Saved with other weights (here: the same model stored as float16; a fine-tuned copy alike) they are left
    # out, saying so; writing them directly is refused.
    loaded = Bundle.load(a)
    with caplog.at_level(logging.WARNING, logger="model.inference.bundle"):
        loaded.save(tmp_path / "half", weights_dtype="float16")
    assert f"encoded by model version {va}" in caplog.text and "rsmt bundle add-styles" in caplog.text
    assert Bundle.load(tmp_path / "half").styles == {} and not (tmp_path / "half" / "styles").exists()
    with pytest.raises(StyleFolderError, match=f"encoded by model version {va}, not by this bundle's weights"):
        save_styles(tmp_path / "half", loaded.styles.values(), loaded.skeleton, 30.0, Bundle.load(tmp_path / "half").version)
    # The version stamped in the codes file is checked too, not only the index.
    index = json.loads((b / "styles" / "styles.json").read_text())
    (b / "styles" / "styles.json").write_text(json.dumps({**index, "version": vb}))
    with pytest.raises(BundleError, match=f"codes.safetensors: the codes were encoded by model version {va}"):
        Bundle.load(b)
    # Re-encoding with the bundle's own weights repairs it.
    write_builtin_styles(b, style_clips())
    assert sorted(Bundle.load(b).styles) == ["brisk", "slow"]


def test_a_folder_of_the_older_clip_format_says_how_to_re_encode(tmp_path) -> None:
    bundle = tiny_bundle(3)
    path = bundle.save(tmp_path / "b")
    walk = synthetic_walk(30)
    (path / "styles").mkdir()
    save_file({"walk/rotations": walk.rotations, "walk/root_positions": walk.root_positions},
              str(path / "styles" / "clips.safetensors"), metadata={"format": "rsmt-styles/1"})
    (path / "styles" / "styles.json").write_text(json.dumps(
        {"format": "rsmt-styles/1", "fps": 30.0, "joints": list(bundle.skeleton.names),
         "styles": [{"name": "walk", "frames": 30, "source": "walk.bvh"}]}))
    with pytest.raises(BundleError, match=r"rsmt-styles/1.*rsmt bundle add-styles"):
        Bundle.load(path)
    assert Bundle.load(path, styles=False).styles == {}  # the commands that rewrite the folder can still read the bundle
    write_builtin_styles(path, [StyleClip("walk", walk)])
    assert sorted(p.name for p in (path / "styles").iterdir()) == ["codes.safetensors", "styles.json"]
    assert Bundle.load(path).styles["walk"].frames == 30


def test_a_damaged_styles_folder_does_not_load(tmp_path) -> None:
    path = tiny_bundle(2).save(tmp_path / "b")
    write_builtin_styles(path, [StyleClip("walk", synthetic_walk(30))])
    index = path / "styles" / "styles.json"
    data = json.loads(index.read_text())
    index.write_text(json.dumps({**data, "fps": 60.0}))
    with pytest.raises(BundleError, match="60"):
        Bundle.load(path)
    index.write_text(json.dumps({**data, "styles": [{"name": "other", "frames": 30}]}))
    with pytest.raises(BundleError, match="'other' is missing"):
        Bundle.load(path)


@pytest.mark.parametrize("name", ["", "builtin:x", "a b", "../up", "-dash"])
def test_style_names_are_checked(name: str) -> None:
    engine = Engine(tiny_bundle(3), compiled=False)
    with pytest.raises(StyleFolderError, match="style name"):
        encode_styles(engine, [StyleClip(name, synthetic_walk(20))])


def test_a_clip_the_encoder_cannot_take_is_refused_naming_the_style(tmp_path) -> None:
    engine = Engine(tiny_bundle(3), compiled=False)
    with pytest.raises(StyleFolderError, match="'short'.*16 to 240 frames"):
        encode_styles(engine, [StyleClip("short", synthetic_walk(8))])


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
