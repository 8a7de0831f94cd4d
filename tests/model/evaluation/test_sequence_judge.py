"""The sequence judge (the second style judge): its inputs ignore turns, moves and posture; it trains, saves and
loads; the windows it is checked on; the CLI command writes safetensors + JSON."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from model.data.preprocessed import MotionCache
from model.evaluation.judge_windows import judge_report, real_windows
from model.evaluation.sequence_judge import WINDOW, JudgeTraining, SequenceJudge, step_features, train_sequence_judge
from model.motion.rotations import quat_rotate, yaw_quat
from rsmt_cli.main import main

pytestmark = pytest.mark.usefixtures("one_thread")


def test_inputs_ignore_a_turn_and_a_move_and_a_held_posture(cache: MotionCache) -> None:
    windows, _, _ = real_windows(cache, cache.split.train[:2])
    sk = cache.skeleton(0)
    x = step_features(windows, sk, cache.fps)
    q = yaw_quat(torch.tensor(1.1)).expand(*windows.shape[:-1], 4)
    moved = quat_rotate(q, windows) + torch.tensor([300.0, 0.0, -50.0])
    assert torch.allclose(step_features(moved, sk, cache.fps), x, atol=1e-2)
    still = windows[:, :1].expand_as(windows)
    assert float(step_features(still, sk, cache.fps).abs().max()) == 0.0


def test_interpolated_windows_keep_the_ends(cache: MotionCache) -> None:
    real, _, _ = real_windows(cache, cache.split.train[:2])
    interp, _, _ = real_windows(cache, cache.split.train[:2], interpolated=True)
    assert real.shape == interp.shape and real.shape[1] == WINDOW
    assert torch.allclose(real[:, [0, -1]], interp[:, [0, -1]], atol=1e-3)
    assert not torch.allclose(real[:, WINDOW // 2], interp[:, WINDOW // 2], atol=1e-1)


def test_trains_saves_and_loads(cache: MotionCache, tmp_path: Path) -> None:
    windows, styles, _ = real_windows(cache, cache.split.train)
    index = {s: k for k, s in enumerate(cache.styles)}
    judge = train_sequence_judge(windows, torch.tensor([index[s] for s in styles]), cache.styles, cache.skeleton(0),
                                 cache.fps, JudgeTraining(steps=60, batch=32, width=16))
    report = judge_report(judge, cache, cache.split.train)
    assert report["accuracy"] > 1.0 / len(cache.styles)  # it learnt something from its training windows
    loaded = SequenceJudge.load(judge.save(tmp_path / "j"))
    assert torch.allclose(loaded.log_probs(windows[:8]), judge.log_probs(windows[:8]), atol=1e-6)
    longer = torch.cat([windows[:2], windows[:2, 1:]], dim=1)  # sequences of 81 poses: scored window by window
    assert loaded.log_probs(longer).shape == (2, len(cache.styles))
    assert sorted(p.name for p in (tmp_path / "j").iterdir()) == ["sequence_judge.json", "weights.safetensors"]


def test_the_draw_gives_every_content_of_a_style_its_share() -> None:
    from model.evaluation.sequence_judge import _draw, _groups

    labels = torch.tensor([0] * 90 + [0] * 10 + [1] * 50)
    contents = ["walk"] * 90 + ["walk-back"] * 10 + ["run"] * 50
    rows = _draw(_groups(labels, contents), 4000, torch.Generator().manual_seed(0))
    drawn = [contents[int(r)] for r in rows]
    # style 0 half the time, split evenly between its two contents, whatever their window counts
    assert abs(drawn.count("walk-back") / 4000 - 0.25) < 0.03 and abs(drawn.count("run") / 4000 - 0.5) < 0.03
    by_style = _draw(_groups(labels, None), 4000, torch.Generator().manual_seed(0))
    assert abs(sum(contents[int(r)] == "walk-back" for r in by_style) / 4000 - 0.05) < 0.02


def test_interpolated_windows_are_pushed_towards_no_style(cache: MotionCache) -> None:
    windows, styles, contents = real_windows(cache, cache.split.train)
    interp, _, _ = real_windows(cache, cache.split.train, interpolated=True)
    index = {s: k for k, s in enumerate(cache.styles)}
    labels = torch.tensor([index[s] for s in styles])
    settings = JudgeTraining(steps=80, batch=32, width=16)
    plain = train_sequence_judge(windows, labels, cache.styles, cache.skeleton(0), cache.fps, settings)
    flat = train_sequence_judge(windows, labels, cache.styles, cache.skeleton(0), cache.fps,
                                JudgeTraining(steps=80, batch=32, width=16, interpolated_weight=2.0),
                                contents=contents, interpolated=interp)
    uniform = torch.full((len(cache.styles),), 1.0 / len(cache.styles), dtype=torch.float64)

    def spread(judge: SequenceJudge) -> float:  # KL from uniform of the answers on interpolated windows
        lp = judge.log_probs(interp)
        return float((lp.exp() * (lp - uniform.log())).sum(-1).mean())

    assert spread(flat) < spread(plain)
    assert flat.info["interpolated_windows"] == len(interp) and flat.info["balance"] == "style, then content"
    with pytest.raises(ValueError):
        train_sequence_judge(windows, labels, cache.styles, cache.skeleton(0), cache.fps, settings, contents=contents[:3])
    with pytest.raises(ValueError):
        JudgeTraining(interpolated_share=1.5)
    with pytest.raises(ValueError):
        JudgeTraining(reversed_share=-0.1)


def test_windows_played_backwards_are_read_better_when_trained_on(cache: MotionCache) -> None:
    windows, styles, _ = real_windows(cache, cache.split.train)
    index = {s: k for k, s in enumerate(cache.styles)}
    labels = torch.tensor([index[s] for s in styles])
    back = windows.flip(1)

    def nll(share: float) -> float:
        judge = train_sequence_judge(windows, labels, cache.styles, cache.skeleton(0), cache.fps,
                                     JudgeTraining(steps=80, batch=32, width=16, reversed_share=share))
        assert judge.info["reversed_share"] == share
        return float(-judge.log_probs(back).gather(1, labels[:, None]).mean())

    assert nll(0.5) < nll(0.0)


def test_cli_command_writes_the_judge(dataset: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("RSMT_CACHE", str(dataset[1]))
    out = tmp_path / "judge2"
    assert main(["train", "sequence-judge", "--data", str(dataset[0]), "--out", str(out), "--steps", "20", "--batch", "16",
                 "--quiet"]) == 0
    record = json.loads((out / "training.json").read_text())
    assert record["val"]["windows"] > 0 and 0.0 <= record["val"]["interpolated_accuracy"] <= 1.0
    assert "real" in capsys.readouterr().out
    loaded = SequenceJudge.load(out)
    assert set(record["val"]["per_style"]) <= set(loaded.styles) and len(loaded.styles) == 3
    assert loaded.info["command"].startswith("rsmt train sequence-judge")
