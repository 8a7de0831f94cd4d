"""The style classifier: input selection, training on synthetic takes, save/load round trip."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from model.data.preprocessed import MotionCache
from model.nets.style_classifier import (
    INPUTS,
    ClassifierError,
    StyleClassifier,
    StyleClassifierConfig,
    input_channels,
    select_inputs,
)
from model.train.classifier_stage import TrainSettings, baseline_windows, build_windows, check_classifier, train_classifier

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.mark.parametrize("inputs", INPUTS)
def test_input_selection_shapes(inputs: str) -> None:
    cfg = StyleClassifierConfig(styles=["a", "b"], joints=3, inputs=inputs)
    x = torch.randn(2, 7, 3 * 12)
    y = select_inputs(x, inputs)
    assert y.shape == (2, 7, input_channels(cfg))


def test_motion_inputs_ignore_the_mean_pose_and_acceleration_ignores_constant_velocity() -> None:
    x = torch.randn(2, 9, 4, 12)
    shifted = x.clone()
    shifted[..., 0:3] += torch.randn(2, 1, 4, 3)  # another mean position
    shifted[..., 6:12] += torch.randn(2, 1, 4, 6)  # another mean rotation
    a, b = select_inputs(x.flatten(-2), "motion"), select_inputs(shifted.flatten(-2), "motion")
    torch.testing.assert_close(a, b)
    steady = torch.zeros(2, 9, 4, 12)
    steady[..., 3:6] = torch.randn(2, 1, 4, 3)  # constant velocity, as in an interpolation
    assert select_inputs(steady.flatten(-2), "acceleration").abs().max() == 0
    assert select_inputs(steady.flatten(-2), "dynamics").abs().max() < 1e-6


def test_config_checks() -> None:
    with pytest.raises(ValueError):
        StyleClassifierConfig(styles=["a", "b"], inputs="nonsense")
    with pytest.raises(ValueError):
        StyleClassifierConfig(styles=["only"])
    model = StyleClassifier(StyleClassifierConfig(styles=["a", "b"], joints=3))
    with pytest.raises(ValueError):
        model(torch.randn(1, 5, 30))


def test_train_save_load_round_trip(cache: MotionCache, tmp_path: Path) -> None:
    cache = cache
    split = cache.split
    train = build_windows(cache, split.train, window=40, step=20, mirror=True)
    val = build_windows(cache, split.val, window=40, step=20)
    assert len(train) > 0 and bool(train.mirrored.any()) and not bool(val.mirrored.any())
    assert train.gather(torch.tensor([0, 1])).shape == (2, 40, 21 * 12)
    cfg = StyleClassifierConfig(styles=cache.styles, joints=21, channels=16, feature_dim=8, layers=2)
    lines: list[str] = []
    result = train_classifier(train, val, cfg, TrainSettings(epochs=2, iterations=3, batch=16, normalisation_windows=64),
                              progress=False, report=lines.append)
    assert len(result.history) == 2 and 1 <= result.best_epoch <= 2
    assert len(lines) == 2 and "val acc" in lines[0]
    model = result.model
    assert model.std.min() > 0

    folder = model.save(tmp_path / "clf", {"note": "smoke"})
    data = json.loads((folder / "config.json").read_text())
    assert data["styles"] == cache.styles and data["record"] == {"note": "smoke"}
    assert len(data["normalisation"]["mean"]) == input_channels(cfg)
    loaded = StyleClassifier.load(folder)
    assert loaded.record == {"note": "smoke"}
    x = val.gather(torch.arange(min(4, len(val))))
    logits_a, feats_a = model.predict(x)
    logits_b, feats_b = loaded.predict(x)
    torch.testing.assert_close(logits_a, logits_b, rtol=0, atol=0)
    torch.testing.assert_close(feats_a, feats_b, rtol=0, atol=0)
    assert feats_a.shape == (x.shape[0], 8)

    check = check_classifier(loaded, cache, split.test, step=20)
    assert set(check["per_style"]) <= set(cache.styles) and 0.0 <= check["accuracy"] <= 1.0
    assert 0.0 <= check["interpolation"]["accuracy"] <= 1.0
    assert sum(map(sum, check["confusion"]["counts"])) == check["windows"]


def test_baseline_windows_end_on_the_real_pose(cache: MotionCache) -> None:
    cache = cache
    take = cache.split.test[0]
    real = build_windows(cache, [take], window=40, step=20)
    interp, styles, _ = baseline_windows(cache, [take], window=40, step=20)
    assert interp.shape == (len(real), 40, 21 * 12) and styles.tolist() == real.style.tolist()
    # The last frame's pose (positions, rotations) is the real one: interpolation ends on the target.
    last_real = real.gather(torch.arange(len(real)))[:, -1].reshape(len(real), 21, 12)
    last_interp = interp[:, -1].reshape(len(real), 21, 12)
    torch.testing.assert_close(last_interp[..., 0:3], last_real[..., 0:3], atol=1e-3, rtol=0)
    torch.testing.assert_close(last_interp[..., 6:12], last_real[..., 6:12], atol=1e-4, rtol=0)


def test_load_errors(tmp_path: Path) -> None:
    with pytest.raises(ClassifierError, match="missing"):
        StyleClassifier.load(tmp_path)
    model = StyleClassifier(StyleClassifierConfig(styles=["a", "b"], joints=2, channels=8, feature_dim=4))
    folder = model.save(tmp_path / "c")
    data = json.loads((folder / "config.json").read_text())
    data["config"]["channels"] = 16
    (folder / "config.json").write_text(json.dumps(data))
    with pytest.raises(ClassifierError, match="inconsistent"):
        StyleClassifier.load(folder)


def test_train_classifier_command(cache: MotionCache, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    from rsmt_cli.main import main

    monkeypatch.setenv("RSMT_CACHE", str(cache.folder.parent))
    out = tmp_path / "clf"
    code = main(["train", "classifier", "--data", str(cache.data_root), "--out", str(out), "--epochs", "1",
                 "--iterations", "2", "--holdout-style", "slow", "--quiet"])
    assert code == 0
    stdout = capsys.readouterr().out
    assert "epoch 1/1" in stdout and "val acc" in stdout
    assert "per style:" in stdout and "per content:" in stdout and "interpolation transitions" in stdout
    model = StyleClassifier.load(out)
    assert model.styles == ["bouncy", "brisk"] and model.config.inputs == "acceleration"
    assert model.record["holdout_styles"] == ["slow"] and "rsmt train classifier" in model.record["command"]
    assert set(model.record["test"]["per_style"]) <= {"bouncy", "brisk"}
    # The existing stages are still there.
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    helptext = capsys.readouterr().out
    assert all(stage in helptext for stage in ("phase", "manifold", "sampler", "all", "classifier")), helptext
