"""Tests of the preprocessed motion cache: contents, cutting and resampling, keys, reuse, atomic builds, bad files."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import pytest
import torch

import model.data.preprocessed as mc
from model.data.location import cache_root
from model.data.preprocessed import (
    DATA_FILE,
    INDEX_FILE,
    MotionCache,
    cache_key,
    load_motion_cache,
)
from model.data.takes import index_takes
from model.motion.bvh_clip import load_clip
from model.motion.clip import Clip
from model.motion.skeleton import Skeleton
from tests.model.data.test_takes import NUM_JOINTS, bvh_text, make_100style_tree, make_bandai_tree, write_bvh


def load(folder: Path, root: Path, **kwargs) -> MotionCache:
    return load_motion_cache(folder, root=root, workers=1, progress=False, **kwargs)


def test_build_contents(tmp_path: Path) -> None:
    data = tmp_path / "data"
    make_bandai_tree(data, takes_per_group=2)
    cache = load(data, tmp_path / "cache")
    assert len(cache) == 12 and cache.problems == []
    assert cache.folder.parent == tmp_path / "cache" and cache.folder.name == cache.key
    assert (cache.folder / DATA_FILE).is_file() and (cache.folder / INDEX_FILE).is_file()
    assert cache.styles == ["active", "elderly"]
    assert cache.contents == ["raise-up-both-hands", "walk", "walk-turn-left"]

    take = "data/dataset-2_walk_elderly_002"
    clip = cache.clip(take)
    assert isinstance(clip, Clip) and clip.fps == 30.0 and clip.name == take
    assert clip.num_frames == 42 == cache.num_frames(take)
    assert clip.rotations.shape == (42, NUM_JOINTS, 4) and clip.rotations.dtype == torch.float32
    reference = load_clip(data / "data" / "dataset-2_walk_elderly_002.bvh")
    torch.testing.assert_close(clip.rotations, reference.rotations)
    torch.testing.assert_close(clip.root_positions, reference.root_positions)
    assert clip.skeleton == reference.skeleton
    i = cache.index_of(take)
    assert cache.takes[i].style == "elderly" and cache.style_id(i) == 1
    assert cache.clip(cache.takes[i]).num_frames == cache.clip(i).num_frames
    assert cache.indices_of([take, take]) == [i, i] and cache.indices_of([]) == []
    with pytest.raises(ValueError, match=r"no take nosuch, other in the data \(clips are named by take id\)"):
        cache.indices_of(["other", take, "nosuch"], "clips")

    meta = json.loads((cache.folder / INDEX_FILE).read_text())
    assert meta["fps"] == 30.0 and len(meta["takes"]) == 12
    assert Skeleton.from_dict(meta["skeletons"][meta["takes"][0]["skeleton"]]).num_joints == NUM_JOINTS
    # The split covers every cached take.
    assert sorted(cache.split.train + cache.split.val + cache.split.test) == list(range(12))
    assert len(cache.make_split(holdout_styles=["active"]).holdout) == 6


def test_cut_then_resample(tmp_path: Path) -> None:
    make_100style_tree(tmp_path / "100STYLE")
    cache = load(tmp_path / "100STYLE", tmp_path / "cache")
    assert sorted(t.take_id for t in cache.takes) == ["Aeroplane/Aeroplane_BR", "Aeroplane/Aeroplane_FW", "Zombie/Zombie_BR"]
    # Aeroplane BR: source frames [10, 50) at 60 fps -> 20 frames at 30 fps, starting on source frame 10.
    roots = cache.root_positions("Aeroplane/Aeroplane_BR")
    assert roots.shape == (20, 3)
    torch.testing.assert_close(roots[:, 0], torch.arange(10.0, 50.0, 2.0))
    # The stop past the file's 70 frames is cut at the end of the file: FW [0, 60) -> 30 frames.
    assert cache.num_frames("Aeroplane/Aeroplane_FW") == 30
    assert {p.kind for p in cache.problems} == {"skipped", "unlabelled"}


def test_bad_files_are_reported_and_skipped(tmp_path: Path) -> None:
    data = tmp_path / "data"
    make_bandai_tree(data, takes_per_group=1)
    broken = data / "data" / "dataset-2_run_active_001.bvh"
    broken.write_text(bvh_text(10).replace("90 0", "90 oops", 1))
    write_bvh(data / "data" / "dataset-2_run_active_002.bvh", names={"Head": "Skull"})  # rig lacks Head
    write_bvh(data / "data" / "dataset-2_run_active_003.bvh", frames=1)
    (data / "data" / "dataset-2_run_active_004.bvh").write_bytes(b"\x00\xff garbage")
    write_bvh(data / "data" / "unlabelled.bvh")
    cache = load(data, tmp_path / "cache")
    assert len(cache) == 6
    kinds = {p.path: p.kind for p in cache.problems}
    assert kinds == {
        "data/dataset-2_run_active_001.bvh": "unreadable",
        "data/dataset-2_run_active_002.bvh": "rig",
        "data/dataset-2_run_active_003.bvh": "too-short",
        "data/dataset-2_run_active_004.bvh": "unreadable",
        "data/unlabelled.bvh": "unlabelled",
    }
    message = next(p.message for p in cache.problems if p.path.endswith("_001.bvh"))
    assert "dataset-2_run_active_001.bvh" in message  # BvhError names the file and line
    # The problems survive a reload from disk.
    assert MotionCache.open(cache.folder).problems == cache.problems


def test_key_follows_data_and_settings(tmp_path: Path) -> None:
    paths = make_bandai_tree(tmp_path, takes_per_group=1)
    index = index_takes(tmp_path)
    key = cache_key(index)
    assert cache_key(index_takes(tmp_path)) == key
    assert cache_key(index, fps=60) != key
    assert cache_key(index, profile="bandai-namco") != key
    assert cache_key(index, min_frames=10) != key
    write_bvh(paths[0], frames=99)  # new size and mtime
    assert cache_key(index_takes(tmp_path)) != key
    key2 = cache_key(index_takes(tmp_path))
    os.utime(paths[1], ns=(time.time_ns(), time.time_ns() + 10**9))  # same size, new mtime
    assert cache_key(index_takes(tmp_path)) != key2
    key3 = cache_key(index_takes(tmp_path))
    write_bvh(tmp_path / "data" / "dataset-2_run_normal_001.bvh")  # a new file
    assert cache_key(index_takes(tmp_path)) != key3


def test_a_copy_of_the_data_elsewhere_gets_its_own_cache(tmp_path: Path) -> None:
    # Same files, sizes and modification times in another folder: the cache must still point at the folder asked for.
    make_bandai_tree(tmp_path / "data", takes_per_group=1)
    shutil.copytree(tmp_path / "data", tmp_path / "copy")  # copy2: modification times kept
    first = load(tmp_path / "data", tmp_path / "cache")
    second = load(tmp_path / "copy", tmp_path / "cache")
    assert second.key != first.key
    assert first.data_root == (tmp_path / "data").resolve() and second.data_root == (tmp_path / "copy").resolve()
    assert all(t.path.is_relative_to(second.data_root) for t in second.takes)


def test_reuse_and_rebuild(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    make_bandai_tree(tmp_path / "data", takes_per_group=1)
    first = load(tmp_path / "data", tmp_path / "cache")
    built: list[int] = []
    real_build = mc.build_motion_cache

    def counted_build(*a, **k):
        built.append(1)
        return real_build(*a, **k)

    monkeypatch.setattr(mc, "build_motion_cache", counted_build)
    again = load(tmp_path / "data", tmp_path / "cache")
    assert built == [] and again.folder == first.folder
    load(tmp_path / "data", tmp_path / "cache", rebuild=True)
    assert built == [1]
    load(tmp_path / "data", tmp_path / "cache", fps=15)
    assert built == [1, 1]
    assert sorted(p.name for p in (tmp_path / "cache").iterdir()) == sorted(
        [first.key, cache_key(index_takes(tmp_path / "data"), fps=15)])


def test_killed_build_leaves_no_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    make_bandai_tree(tmp_path / "data", takes_per_group=1)

    def die(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(mc, "save_file", die)
    with pytest.raises(KeyboardInterrupt):
        load(tmp_path / "data", tmp_path / "cache")
    assert list((tmp_path / "cache").iterdir()) == []
    # A temporary folder left by a process that no longer exists is cleared by the next build.
    stale = tmp_path / "cache" / ".tmp-999999999-abc"
    stale.mkdir()
    monkeypatch.undo()
    cache = load(tmp_path / "data", tmp_path / "cache")
    assert [p.name for p in (tmp_path / "cache").iterdir()] == [cache.key]


def test_damaged_cache_is_rebuilt(tmp_path: Path) -> None:
    make_bandai_tree(tmp_path / "data", takes_per_group=1)
    cache = load(tmp_path / "data", tmp_path / "cache")
    (cache.folder / DATA_FILE).write_bytes(b"not safetensors")
    with pytest.raises(ValueError):
        MotionCache.open(cache.folder)
    assert len(load(tmp_path / "data", tmp_path / "cache")) == 6


def test_cache_root_setting(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "elsewhere"))
    assert cache_root() == tmp_path / "elsewhere"
    make_bandai_tree(tmp_path / "data", takes_per_group=1)
    cache = load_motion_cache(tmp_path / "data", workers=1, progress=False)
    assert cache.folder.parent == tmp_path / "elsewhere"
    monkeypatch.delenv("RSMT_CACHE")
    assert cache_root() == Path.home() / ".cache" / "rsmt" / "preprocessed"


@pytest.mark.slow  # starts a process pool
def test_process_pool_gives_the_same_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    make_bandai_tree(tmp_path / "data", takes_per_group=2)
    (tmp_path / "data" / "data" / "dataset-2_run_active_001.bvh").write_text("HIERARCHY\nROOT\n")
    serial = load(tmp_path / "data", tmp_path / "serial")
    monkeypatch.setattr(mc, "POOL_MIN_TAKES", 1)
    pooled = load_motion_cache(tmp_path / "data", root=tmp_path / "pooled", workers=2, progress=False)
    assert [t.take_id for t in pooled.takes] == [t.take_id for t in serial.takes]
    assert pooled.problems == serial.problems
    for i in range(len(serial)):
        torch.testing.assert_close(pooled.rotations(i), serial.rotations(i))


@pytest.mark.real_data
def test_real_data_cache(shared_data: Path, tmp_path: Path) -> None:
    """Builds the whole cache (about 10-30 s on two cores) into a temporary folder."""
    began = time.perf_counter()
    cache = load_motion_cache(shared_data, root=tmp_path, progress=False)
    elapsed = time.perf_counter() - began
    assert len(cache) == 2601 and cache.problems == []
    assert len(cache.styles) == 7 and len(cache.contents) == 10
    assert cache.total_frames == 344244  # 30 fps files: no resampling
    clip = cache.clip(0)
    assert clip.skeleton.num_joints == 21 and clip.rotations.shape[1:] == (21, 4)
    assert len({s["joints"][0]["offset"][2] for s in cache.meta["skeletons"]}) >= 1
    print(f"real-data cache build: {elapsed:.1f} s")
