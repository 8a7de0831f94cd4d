"""Tests of the take index: labels from Bandai-Namco names, a 100STYLE tree and a manifest, and the problems reported.

The synthetic-data helpers here (``write_bvh``, ``make_bandai_tree``, ...) are shared by the other
dataset tests.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from model.data.takes import (
    Take,
    find_bvh_files,
    index_takes,
    parse_bandai_namco_name,
    read_bvh_header,
)

# A 10-joint rig with Bandai-Namco names: enough for the built-in profile to resolve.
_RIG = [  # name, parent, offset
    ("Hips", None, (0.0, 90.0, 0.0)),
    ("Spine", "Hips", (0.0, 10.0, 0.0)),
    ("Head", "Spine", (0.0, 40.0, 0.0)),
    ("UpperArm_L", "Spine", (15.0, 30.0, 0.0)),
    ("UpperArm_R", "Spine", (-15.0, 30.0, 0.0)),
    ("UpperLeg_L", "Hips", (9.0, -5.0, 0.0)),
    ("Foot_L", "UpperLeg_L", (0.0, -80.0, 0.0)),
    ("Toes_L", "Foot_L", (0.0, -5.0, 12.0)),
    ("UpperLeg_R", "Hips", (-9.0, -5.0, 0.0)),
    ("Foot_R", "UpperLeg_R", (0.0, -80.0, 0.0)),
    ("Toes_R", "Foot_R", (0.0, -5.0, 12.0)),
]
NUM_JOINTS = len(_RIG)


def bvh_text(frames: int = 40, fps: float = 30.0, names: dict[str, str] | None = None, phase: float = 0.0) -> str:
    """A small BVH take: the root's x position is the frame number (so cuts can be checked)."""
    names = names or {}
    children: dict[str | None, list[int]] = {}
    for i, (_, parent, _) in enumerate(_RIG):
        children.setdefault(parent, []).append(i)
    lines = ["HIERARCHY"]

    def emit(i: int, depth: int) -> None:
        name, parent, off = _RIG[i]
        pad = "  " * depth
        lines.append(f"{pad}{'ROOT' if parent is None else 'JOINT'} {names.get(name, name)}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}  OFFSET {off[0]} {off[1]} {off[2]}")
        lines.append(f"{pad}  CHANNELS " + ("6 Xposition Yposition Zposition " if parent is None else "3 ")
                     + "Zrotation Xrotation Yrotation")
        kids = children.get(name, [])
        for k in kids:
            emit(k, depth + 1)
        if not kids:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET 0 1 0", f"{pad}  }}"])
        lines.append(f"{pad}}}")

    emit(0, 0)
    lines += ["MOTION", f"Frames: {frames}", f"Frame Time: {1.0 / fps:.7f}"]
    for f in range(frames):
        angle = 10.0 * math.sin(0.2 * f + phase)
        values = [float(f), 90.0, 0.0] + [round(angle, 3), 0.0, 0.0] * NUM_JOINTS
        lines.append(" ".join(f"{v:g}" for v in values))
    return "\n".join(lines) + "\n"


def write_bvh(path: Path, frames: int = 40, fps: float = 30.0, **kwargs) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(bvh_text(frames, fps, **kwargs))
    return path


BANDAI_STYLES = ("active", "elderly")
BANDAI_CONTENTS = ("walk", "walk-turn-left", "raise-up-both-hands")


def make_bandai_tree(root: Path, takes_per_group: int = 3, frames: int = 40) -> list[Path]:
    """``root/data/dataset-2_{content}_{style}_{NNN}.bvh`` for 2 styles x 3 contents."""
    paths = []
    for style in BANDAI_STYLES:
        for content in BANDAI_CONTENTS:
            for n in range(1, takes_per_group + 1):
                paths.append(write_bvh(root / "data" / f"dataset-2_{content}_{style}_{n:03d}.bvh",
                                       frames=frames + n, phase=n))
    return paths


def make_100style_tree(root: Path) -> None:
    """Two styles at 60 fps with a Frame_Cuts.csv: one N/A cut, one empty cut, one folder the CSV lacks."""
    (root / "Frame_Cuts.csv").parent.mkdir(parents=True, exist_ok=True)
    cts = ["BR", "BW", "FR", "FW", "ID", "SR", "SW", "TR1", "TR2", "TR3"]
    header = ["STYLE_NAME"] + [f"{ct}_{e}" for ct in cts for e in ("START", "STOP")]
    rows = {
        "Aeroplane": {"BR": ("10", "50"), "FW": ("0", "60"), "ID": ("N/A", "N/A")},
        "Zombie": {"BR": ("4", "44"), "SW": ("", "")},
    }
    lines = [",".join(header)]
    for style, cuts in rows.items():
        cells = [style]
        for ct in cts:
            cells += list(cuts.get(ct, ("N/A", "N/A")))
        lines.append(",".join(cells))
    (root / "Frame_Cuts.csv").write_text("\n".join(lines) + "\n")
    for style, cuts in rows.items():
        for ct in cuts:
            write_bvh(root / style / f"{style}_{ct}.bvh", frames=70, fps=60.0)
    write_bvh(root / "Robot" / "Robot_BR.bvh", frames=70, fps=60.0)  # style not in the CSV
    write_bvh(root / "Aeroplane" / "Aeroplane_notes.bvh", frames=70, fps=60.0)  # not <Style>_<CT>


# ---------------------------------------------------------------------------------- Bandai-Namco
@pytest.mark.parametrize("name, expected", [
    ("dataset-2_walk_active_001.bvh", ("walk", "active")),
    ("dataset-2_walk-turn-left_elderly_017.bvh", ("walk-turn-left", "elderly")),
    ("dataset-2_raise-up-both-hands_youthful_120.bvh", ("raise-up-both-hands", "youthful")),
    ("dataset-1_walk-back_not-confident_003.bvh", ("walk-back", "not-confident")),
    ("Dataset-1_Bow_Happy_001.BVH", ("bow", "happy")),
    ("walk_active_001.bvh", None),
    ("dataset-2_walk_active.bvh", None),
    ("dataset-2_walk_extra_active_001.bvh", None),
])
def test_bandai_namco_names(name: str, expected: tuple[str, str] | None) -> None:
    assert parse_bandai_namco_name(name) == expected


def test_index_bandai_namco_labels_recursive_and_problems(tmp_path: Path) -> None:
    make_bandai_tree(tmp_path)
    write_bvh(tmp_path / "data" / "extra" / "dataset-1_bow_happy_002.bvh")  # found recursively
    write_bvh(tmp_path / "data" / "notes_take.bvh")  # unlabelled
    (tmp_path / "data" / "dataset-2_walk_active_001.json").write_text("{}")  # not a BVH: ignored
    index = index_takes(tmp_path)
    assert index.layout == "bandai-namco"
    assert len(index.takes) == 2 * 3 * 3 + 1
    assert index.styles == ["active", "elderly", "happy"]
    assert index.contents == ["bow", "raise-up-both-hands", "walk", "walk-turn-left"]
    take = next(t for t in index.takes if t.take_id == "data/dataset-2_walk-turn-left_elderly_002")
    assert (take.style, take.content, take.start, take.stop) == ("elderly", "walk-turn-left", None, None)
    assert take.path == (tmp_path / "data" / "dataset-2_walk-turn-left_elderly_002.bvh").resolve()
    assert take.key == "elderly/walk-turn-left/data/dataset-2_walk-turn-left_elderly_002"
    assert [p.path for p in index.problems] == ["data/notes_take.bvh"]
    assert index.problems[0].kind == "unlabelled"
    assert [t.take_id for t in index.takes] == sorted(t.take_id for t in index.takes)


def test_find_bvh_files_skips_hidden_folders(tmp_path: Path) -> None:
    write_bvh(tmp_path / "a" / "x.bvh")
    write_bvh(tmp_path / ".trash" / "y.bvh")
    assert find_bvh_files(tmp_path) == [tmp_path / "a" / "x.bvh"]


def test_index_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        index_takes(tmp_path / "absent")


# ---------------------------------------------------------------------------------- 100STYLE
def test_index_100style(tmp_path: Path) -> None:
    make_100style_tree(tmp_path / "100STYLE")
    index = index_takes(tmp_path / "100STYLE")
    assert index.layout == "100style"
    got = {(t.style, t.content, t.start, t.stop, t.take_id) for t in index.takes}
    assert got == {
        ("Aeroplane", "BR", 10, 50, "Aeroplane/Aeroplane_BR"),
        ("Aeroplane", "FW", 0, 60, "Aeroplane/Aeroplane_FW"),
        ("Zombie", "BR", 4, 44, "Zombie/Zombie_BR"),
    }
    kinds = {p.path: p.kind for p in index.problems}
    assert kinds == {
        "Aeroplane/Aeroplane_ID.bvh": "skipped",  # N/A cut
        "Zombie/Zombie_SW.bvh": "skipped",  # empty cut
        "Robot/Robot_BR.bvh": "unlabelled",  # style missing from Frame_Cuts.csv
        "Aeroplane/Aeroplane_notes.bvh": "unlabelled",
    }


def test_frame_cuts_found_below_the_folder(tmp_path: Path) -> None:
    make_100style_tree(tmp_path / "unpacked" / "100STYLE")
    assert index_takes(tmp_path).layout == "100style"


def test_frame_cuts_without_style_column(tmp_path: Path) -> None:
    (tmp_path / "Frame_Cuts.csv").write_text("NAME,BR_START,BR_STOP\nA,1,2\n")
    with pytest.raises(ValueError, match="STYLE_NAME"):
        index_takes(tmp_path)


def test_frame_cuts_bad_number_is_a_problem(tmp_path: Path) -> None:
    (tmp_path / "Frame_Cuts.csv").write_text("STYLE_NAME,BR_START,BR_STOP\nA,ten,20\nB,30,20\n")
    write_bvh(tmp_path / "A" / "A_BR.bvh")
    write_bvh(tmp_path / "B" / "B_BR.bvh")
    index = index_takes(tmp_path)
    assert index.takes == []
    assert sorted(p.kind for p in index.problems) == ["bad-cut", "bad-cut"]


# ---------------------------------------------------------------------------------- manifest
def test_index_manifest(tmp_path: Path) -> None:
    data = tmp_path / "data"
    write_bvh(data / "a" / "one.bvh")
    write_bvh(data / "two.bvh")
    write_bvh(data / "unlisted.bvh")
    manifest = tmp_path / "labels.csv"
    manifest.write_text(
        "file,style,content,start,stop\n"
        "data/a/one.bvh,proud,walk,,\n"
        "data/two.bvh,proud,run,0,20\n"
        "data/two.bvh,sad,run,20,40\n"
        "data/missing.bvh,sad,walk,,\n"
        "data/a/one.bvh,,walk,,\n"
        "data/two.bvh,sad,run,30,10\n"
    )
    # A Frame_Cuts.csv and Bandai-Namco names are ignored when a manifest is given.
    (data / "Frame_Cuts.csv").write_text("STYLE_NAME\n")
    index = index_takes(data, manifest=manifest)
    assert index.layout == "manifest"
    got = sorted((t.take_id, t.style, t.content, t.start, t.stop) for t in index.takes)
    assert got == [
        ("data/a/one", "proud", "walk", None, None),
        ("data/two@0-20", "proud", "run", 0, 20),
        ("data/two@20-40", "sad", "run", 20, 40),
    ]
    problems = {(p.path, p.kind) for p in index.problems}
    assert problems == {
        ("missing.bvh", "missing"),
        ("a/one.bvh", "unlabelled"),  # no style on line 6
        ("two.bvh", "bad-cut"),
        ("unlisted.bvh", "unlabelled"),
    }
    assert any("labels.csv:5" in p.message for p in index.problems)


def test_manifest_without_columns(tmp_path: Path) -> None:
    manifest = tmp_path / "m.csv"
    manifest.write_text("path,style\nx.bvh,a\n")
    with pytest.raises(ValueError, match="file.*content"):
        index_takes(tmp_path, manifest=manifest)
    with pytest.raises(FileNotFoundError):
        index_takes(tmp_path, manifest=tmp_path / "absent.csv")


# ---------------------------------------------------------------------------------- header probe
def test_read_bvh_header(tmp_path: Path) -> None:
    header = read_bvh_header(write_bvh(tmp_path / "t.bvh", frames=17, fps=30.0))
    assert header.frames == 17
    assert header.fps == 30.0  # 0.0333333 s snapped
    assert header.joints[0] == "Hips" and len(header.joints) == NUM_JOINTS


def test_read_bvh_header_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.bvh"
    bad.write_text("HELLO\n")
    with pytest.raises(ValueError, match="bad.bvh:1"):
        read_bvh_header(bad)
    truncated = tmp_path / "cut.bvh"
    truncated.write_text(bvh_text(5).split("MOTION")[0])
    with pytest.raises(ValueError, match="cut.bvh"):
        read_bvh_header(truncated)
    # The full reader's rules (issue 64): a rate that overflows (1 / 1e-310) gave an OverflowError on .fps, and
    # non-ASCII digits ("\u0669\u0663", 93 to float()) were read as numbers.
    text = bvh_text(5)
    for name, line, wanted in (("tiny", "Frame Time: 1e-310", "Frame Time 1e-310 s gives inf fps; accepted: 1 to 1000"),
                               ("arabic-time", "Frame Time: 0.\u0660\u0663", "expected a number after 'Time:'"),
                               ("arabic-count", "Frames: \u0665", "expected a number after 'Frames:'")):
        key = line.split(":")[0] + ":"
        lines = [line if row.startswith(key) else row for row in text.split("\n")]
        path = tmp_path / f"{name}.bvh"
        path.write_text("\n".join(lines), encoding="utf-8")
        with pytest.raises(ValueError, match=f"{name}.bvh:[0-9]+: {re.escape(wanted)}"):
            read_bvh_header(path)


def test_take_is_hashable_and_frozen(tmp_path: Path) -> None:
    take = Take(path=tmp_path, style="s", content="c", take_id="x")
    assert hash(take) == hash(Take(path=tmp_path, style="s", content="c", take_id="x"))
    for name in ("style", "content", "take_id"):
        with pytest.raises(AttributeError):
            setattr(take, name, "t")


# ---------------------------------------------------------------------------------- real data
@pytest.mark.real_data
def test_real_data_index(shared_data: Path) -> None:
    index = index_takes(shared_data)
    assert index.layout == "bandai-namco"
    assert len(index.takes) == 2601
    assert len(index.styles) == 7 and len(index.contents) == 10
    assert index.problems == []
    assert "walk-turn-left" in index.contents and "raise-up-both-hands" in index.contents
