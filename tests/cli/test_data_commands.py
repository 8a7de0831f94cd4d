"""Tests of ``rsmt data inspect``, run in-process through ``rsmt_cli.main.main``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rsmt_cli.main import main
from tests.model.data.test_takes import make_100style_tree, make_bandai_tree, write_bvh


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["data", "inspect", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_inspect_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    make_bandai_tree(tmp_path, takes_per_group=3, frames=40)
    write_bvh(tmp_path / "data" / "readme.bvh")
    (tmp_path / "data" / "dataset-2_run_active_001.bvh").write_text("HIERARCHY\n{\n")
    code, out, _ = run(capsys, str(tmp_path))
    assert code == 0
    assert "Layout:      bandai-namco" in out
    assert "18 takes, 756 frames, 0.4 min; 2 styles x 3 contents" in out  # 6 groups x (41 + 42 + 43)
    assert "content \\ style" in out
    row = next(line for line in out.splitlines() if line.startswith("walk-turn-left"))
    assert row.split() == ["walk-turn-left", "3/126", "3/126", "6/252", "0.1"]
    assert "Per style:" in out and "Per content:" in out
    assert "train" in out and "val" in out and "test" in out
    assert "Problems: 2 file(s) skipped (unlabelled 1, unreadable 1)" in out
    assert "data/readme.bvh: [unlabelled]" in out


def test_inspect_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    make_bandai_tree(tmp_path, takes_per_group=4, frames=40)
    code, out, _ = run(capsys, str(tmp_path), "--json", "--holdout-style", "elderly", "--ratios", "0.5,0.25,0.25")
    assert code == 0
    report = json.loads(out)
    assert report["total"] == {"takes": 24, "frames": 24 * 40 + 6 * 10, "minutes": pytest.approx(0.57, abs=0.01)}
    assert report["styles"] == ["active", "elderly"]
    assert report["table"]["active"]["walk"] == {"takes": 4, "frames": 4 * 40 + 10}
    assert report["per_content"]["walk"]["takes"] == 8
    split = report["split"]
    assert split["holdout"]["takes"] == 12 and split["holdout_styles"] == ["elderly"]
    assert (split["train"]["takes"], split["val"]["takes"], split["test"]["takes"]) == (6, 3, 3)
    assert report["problems"] == []


def test_inspect_100style_and_manifest(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    make_100style_tree(tmp_path / "s")
    code, out, _ = run(capsys, str(tmp_path / "s"), "--json")
    report = json.loads(out)
    assert code == 0 and report["layout"] == "100style"
    assert report["table"]["Aeroplane"]["BR"] == {"takes": 1, "frames": 40}  # cut [10, 50) at 60 fps
    assert report["table"]["Aeroplane"]["FW"] == {"takes": 1, "frames": 60}
    assert {p["kind"] for p in report["problems"]} == {"skipped", "unlabelled"}

    manifest = tmp_path / "m.csv"
    manifest.write_text("file,style,content\ns/Zombie/Zombie_BR.bvh,calm,idle\n")
    code, out, _ = run(capsys, str(tmp_path / "s"), "--manifest", str(manifest), "--profile", "bandai-namco", "--json")
    report = json.loads(out)
    assert report["layout"] == "manifest" and report["total"]["takes"] == 1


def test_inspect_with_the_cache(tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    make_100style_tree(tmp_path / "s")
    write_bvh(tmp_path / "s" / "Zombie" / "Zombie_BR.bvh", names={"Head": "Skull"}, fps=60.0)
    code, out, _ = run(capsys, str(tmp_path / "s"), "--cache", "--json")
    report = json.loads(out)
    assert code == 0 and report["frames_from"] == "cache" and report["fps"] == [30.0]
    assert report["table"]["Aeroplane"]["BR"] == {"takes": 1, "frames": 20}
    assert "rig" in {p["kind"] for p in report["problems"]}
    code, out, _ = run(capsys, str(tmp_path / "s"), "--cache")
    assert "preprocessed at 30 fps" in out and "[rig]" in out


def test_inspect_rig_problem_from_headers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    make_bandai_tree(tmp_path, takes_per_group=1)
    code, out, _ = run(capsys, str(tmp_path), "--profile", "100style", "--json")
    report = json.loads(out)
    assert code == 1  # nothing fits the 100STYLE rig
    assert report["total"]["takes"] == 0 and {p["kind"] for p in report["problems"]} == {"rig"}


def test_inspect_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, str(tmp_path / "absent"))
    assert code == 2 and "no such data folder" in err
    code, out, _ = run(capsys, str(tmp_path))
    assert code == 1 and "0 takes" in out
    with pytest.raises(SystemExit):
        main(["data", "inspect", str(tmp_path), "--ratios", "x"])
    capsys.readouterr()


@pytest.mark.real_data
def test_inspect_real_data(shared_data: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, str(shared_data))
    assert code == 0
    assert "2601 takes" in out and "7 styles x 10 contents" in out
    header = next(line for line in out.splitlines() if line.startswith("content \\ style"))
    for style in ("active", "elderly", "exhausted", "feminine", "masculine", "normal", "youthful"):
        assert style in header
    rows = [line.split()[0] for line in out.splitlines()[out.splitlines().index(header) + 1:][:10]]
    assert rows == ["raise-up-both-hands", "raise-up-left-hand", "raise-up-right-hand", "run", "walk",
                    "walk-turn-left", "walk-turn-right", "wave-both-hands", "wave-left-hand", "wave-right-hand"]
    total = next(line for line in out.splitlines() if line.startswith("total "))
    assert total.split()[-2] == "2601/344,244"
    assert "Problems: none" in out
