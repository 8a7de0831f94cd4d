"""Two data sets in one index: a second folder moves no take of the first, label merges move none, and a set with
a take or two per style and content still reaches val and test, every style in turn."""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path

import pytest

from model.data.location import DEFAULT_DATASET_1, DEFAULT_UNPACKED
from model.data.splits import SPLITS, split_takes
from model.data.takes import Take, index_takes, read_bvh_header, relabel

D1_STYLES = ("active", "angry", "childish", "feminine", "happy", "masculinity", "musical", "normal", "old", "tired")
D1_CONTENTS = ("walk", "walk-back", "walk-left", "walk-right", "run", "dash", "bow")


def _touch(folder: Path, names: list[str]) -> None:
    (folder / "data").mkdir(parents=True)
    for name in names:
        (folder / "data" / name).write_text("")


def _folders(tmp_path: Path) -> tuple[Path, Path]:
    d2, d1 = tmp_path / "d2", tmp_path / "d1"
    _touch(d2, [f"dataset-2_{c}_{s}_{n:03d}.bvh" for s in ("active", "elderly", "normal") for c in ("walk", "run")
                for n in range(1, 21)])
    _touch(d1, [f"dataset-1_{c}_{s}_001.bvh" for s in D1_STYLES for c in D1_CONTENTS])
    return d2, d1


def _assignment(takes: list[Take], frames: list[int] | None = None) -> dict[str, str]:
    split = split_takes(takes, frames=frames)
    return {takes[i].take_id: name for name in (*SPLITS, "holdout") for i in split[name]}


def test_second_folder_moves_no_take_of_the_first(tmp_path: Path) -> None:
    d2, d1 = _folders(tmp_path)
    alone = _assignment(index_takes(d2).takes)
    both_index = index_takes(f"{d2}{os.pathsep}{d1}")
    both = _assignment(both_index.takes)
    assert len(both_index.takes) == 120 + len(D1_STYLES) * len(D1_CONTENTS)
    assert {k: both[k] for k in alone} == alone
    assert {k: v for k, v in both.items() if k not in alone} == _assignment(index_takes(d1).takes)
    assert both_index.roots == (d2.resolve(), d1.resolve())
    assert {t.source for t in both_index.takes} == {"dataset-1", "dataset-2"}


def test_pooled_set_reaches_val_and_test_with_every_style_in_turn(tmp_path: Path) -> None:
    _, d1 = _folders(tmp_path)
    takes = index_takes(d1).takes
    got = _assignment(takes)
    by_content = {c: Counter(got[t.take_id] for t in takes if t.content == c) for c in D1_CONTENTS}
    assert all(n["val"] >= 1 and n["test"] >= 1 for n in by_content.values())
    held = [t.style for t in takes if got[t.take_id] != "train"]
    # 7 contents x 2 held-out takes over 10 styles: no style held out more than twice.
    assert max(Counter(held).values()) <= 2 and len(set(held)) == len(D1_STYLES)


def test_short_pooled_takes_stay_in_train(tmp_path: Path) -> None:
    _, d1 = _folders(tmp_path)
    takes = index_takes(d1).takes
    short = {t.take_id for t in takes if t.style in ("angry", "happy", "old")}
    got = _assignment(takes, frames=[30 if t.take_id in short else 200 for t in takes])
    assert all(got[k] == "train" for k in short)


def test_merged_labels_move_no_take(tmp_path: Path) -> None:
    d2, d1 = _folders(tmp_path)
    both = f"{d2}{os.pathsep}{d1}"
    own, merged = index_takes(both, style_labels="own"), index_takes(both, style_labels="merged")
    assert _assignment(own.takes) == _assignment(merged.takes)
    assert "old" in own.styles and "old" not in merged.styles and "elderly" in merged.styles
    old = next(t for t in merged.takes if t.source_style == "old")
    assert old.style == "elderly" and old.data_style == "old" and old.source == "dataset-1"
    # Dataset 2's own styles never change, and a dataset-2 take named like a dataset-1 style keeps its label.
    d2_take = Take(path=Path("dataset-2_walk_old_001.bvh"), style="old", content="walk", take_id="x")
    assert relabel(d2_take, "merged") is d2_take
    with pytest.raises(ValueError):
        index_takes(both, style_labels="fused")


@pytest.mark.skipif(not ((DEFAULT_UNPACKED / ".complete").is_file() and (DEFAULT_DATASET_1 / ".complete").is_file()),
                    reason="the unpacked datasets 1 and 2 are absent (../shared/data/unpack.sh unpacks them)")
def test_real_dataset_2_split_is_unchanged_beside_dataset_1() -> None:
    alone = index_takes(DEFAULT_UNPACKED)
    both = index_takes(f"{DEFAULT_UNPACKED}{os.pathsep}{DEFAULT_DATASET_1}")
    frames = [read_bvh_header(t.path).frames for t in both.takes]
    before = _assignment(alone.takes)
    after = _assignment(both.takes, frames)
    assert {k: after[k] for k in before} == before
    d1 = [t for t in both.takes if t.source == "dataset-1"]
    assert len(d1) == 130
    held = Counter((t.content, after[t.take_id]) for t in d1)
    assert held[("walk-back", "test")] == 1 and held[("walk-back", "val")] == 1
