"""The whole training recipe runs on synthetic data, writes a loadable bundle, and resumes."""

from __future__ import annotations

import json

import pytest
import torch
from safetensors.torch import load_file

from model.data.synthetic import SYNTHETIC_STYLES, synthetic_walk, write_synthetic_dataset
from model.inference.bundle import Bundle
from model.inference.engine import Engine
from model.nets.style_classifier import StyleClassifier
from model.train.loop import resolve_device
from model.train.presets import preset_dict
from rsmt_cli.main import main

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.mark.slow  # trains every stage (synthetic data)
def test_train_all_smoke_and_resume(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    data = tmp_path / "data"
    write_synthetic_dataset(data)
    args = ["train", "all", "--preset", "smoke", "--data", str(data), "--out", str(tmp_path / "bundle"),
            "--run", str(tmp_path / "run"), "--quiet"]
    assert main(args) == 0
    bundle = Bundle.load(tmp_path / "bundle")
    assert bundle.phase_model is not None and bundle.meta.name == "rsmt-smoke"
    timings = json.loads((tmp_path / "run" / "timings.json").read_text())
    assert {"data_s", "phase_s", "labels_s", "manifold_s", "sampler_s"} <= set(timings)
    for stage in ("phase", "manifold", "sampler"):
        assert (tmp_path / "run" / stage / "checkpoint.safetensors").is_file()
    engine = Engine(bundle)
    walk = synthetic_walk(frames=60)
    style, _ = engine.encode_style(walk.window(10, 50))
    rot, _ = engine.generate([engine.prepare(walk.window(0, 10), walk.window(30, 32), 8, style, deterministic=True)])[0]
    assert rot.shape[0] == 8
    # A second run finds every stage finished in its checkpoints and writes the same weights again,
    # so the version (a hash of the weights, part of every style id) is the same.
    assert main(args) == 0
    again = Bundle.load(tmp_path / "bundle")
    assert again.version == bundle.version


def _smoke_args(tmp_path, data, name: str, *extra: str) -> list[str]:
    return ["train", "all", "--preset", "smoke", "--data", str(data), "--out", str(tmp_path / f"bundle-{name}"),
            "--run", str(tmp_path / f"run-{name}"), "--quiet", *extra]


def _checkpoint(tmp_path, name: str, stage: str) -> dict[str, torch.Tensor]:
    return load_file(str(tmp_path / f"run-{name}" / stage / "checkpoint.safetensors"))


@pytest.mark.slow  # trains every stage twice
def test_explicit_cpu_device_matches_default(tmp_path, monkeypatch, capsys):
    """``--device cpu`` trains exactly as a run without ``--device`` does on a machine without a GPU, in
    any process: same weights, optimiser moments and RNG state, bit for bit."""
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)  # "auto" means the CPU here, GPU or not
    data = tmp_path / "data"
    write_synthetic_dataset(data)
    # Each stage seeds its initial weights itself: a different global RNG state (torch 2.13 seeds it
    # randomly in every process) must not change anything.
    torch.manual_seed(1)
    assert main(_smoke_args(tmp_path, data, "default")) == 0
    out = capsys.readouterr()
    assert "training on cpu" in out.err
    torch.manual_seed(2)
    assert main(_smoke_args(tmp_path, data, "cpu", "--device", "cpu")) == 0
    assert Bundle.load(tmp_path / "bundle-cpu").version == Bundle.load(tmp_path / "bundle-default").version
    for stage in ("phase", "manifold", "sampler"):
        a, b = _checkpoint(tmp_path, "default", stage), _checkpoint(tmp_path, "cpu", stage)
        assert a.keys() == b.keys()
        assert all(torch.equal(a[k], b[k]) for k in a), stage


def test_cuda_device_without_gpu_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ValueError, match="cuda.*torch.cuda.is_available"):
        resolve_device("cuda")
    assert resolve_device("auto") == torch.device("cpu")
    # From the command line: one error line and exit status 2 before any data is read, no traceback.
    args = ["train", "all", "--preset", "smoke", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "b"),
            "--run", str(tmp_path / "run"), "--quiet", "--device", "cuda"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "rsmt: error: device 'cuda' was asked for" in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()
    args = ["finetune-style", "--model", str(tmp_path / "missing"), "--clips", str(tmp_path / "a.bvh"), "--name", "x",
            "--out", str(tmp_path / "tuned"), "--device", "cuda"]
    assert main(args) == 2
    assert "device 'cuda' was asked for" in capsys.readouterr().err


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_train_smoke_on_cuda_writes_a_cpu_bundle(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    data = tmp_path / "data"
    write_synthetic_dataset(data)
    assert main(_smoke_args(tmp_path, data, "gpu", "--device", "cuda")) == 0
    assert "training on cuda" in capsys.readouterr().err
    bundle = Bundle.load(tmp_path / "bundle-gpu")
    assert all(t.device.type == "cpu" for t in bundle.tensors().values())
    assert all(t.device.type == "cpu" for t in _checkpoint(tmp_path, "gpu", "sampler").values())
    walk = synthetic_walk(frames=60)
    engine = Engine(bundle)
    style, _ = engine.encode_style(walk.window(10, 50))
    rot, _ = engine.generate([engine.prepare(walk.window(0, 10), walk.window(30, 32), 8, style, deterministic=True)])[0]
    assert rot.shape[0] == 8 and torch.isfinite(rot).all()
    # The CUDA run's checkpoints load on the CPU: a CPU run in the same folder finds every stage done.
    assert main(_smoke_args(tmp_path, data, "gpu", "--device", "cpu")) == 0
    assert Bundle.load(tmp_path / "bundle-gpu").version == bundle.version


@pytest.mark.slow  # trains critics and a sampler
def test_style_loss_trains_critics_and_uses_cross_style_pairs(tmp_path, monkeypatch):
    """With ``w_style`` the run trains its own style critics, one per input selection (once: a rerun
    reuses them), the sampler's steps score same-style and cross-style transitions with them from
    ``extra_losses_from`` on, with
    the velocity, acceleration and foot-height losses, and changed-control windows (scaled durations,
    moved targets) from then on too; the bundle still loads."""
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    data = tmp_path / "data"
    write_synthetic_dataset(data)
    cfg = preset_dict("smoke")
    cfg["sampler_stage"].update(w_style=0.5, cross_batch=4, critic_epochs=1, critic_iterations=5,
                                critic_inputs=["dynamics", "acceleration"],
                                style_loss_min_frames=3, w_vel=1.0, w_acc=1.0, w_foot_height=1.0, extra_losses_from=3,
                                control_batch=4, w_cross_style=2.0)
    path = tmp_path / "style.json"
    path.write_text(json.dumps(cfg))
    args = ["train", "all", "--config", str(path), "--data", str(data), "--out", str(tmp_path / "bundle"),
            "--run", str(tmp_path / "run"), "--quiet"]
    assert main(args) == 0
    critic = StyleClassifier.load(tmp_path / "run" / "critic")
    assert critic.config.inputs == "dynamics" and sorted(critic.styles) == sorted(SYNTHETIC_STYLES)
    second = StyleClassifier.load(tmp_path / "run" / "critic-acceleration")
    assert second.config.inputs == "acceleration" and second.styles == critic.styles
    history = json.loads((tmp_path / "run" / "sampler" / "checkpoint.json").read_text())["history"]
    assert {"train_style_acc", "val_style_acc", "train_acc", "val_foot_height"} <= set(history[-1])
    assert "train_style_acc" not in history[0]  # the first epoch ends before extra_losses_from
    assert {"train_control_last", "train_control_acc"} <= set(history[-1])
    assert history[-1]["train_control_last"] > 0 and "train_control_last" not in history[0]
    assert Bundle.load(tmp_path / "bundle").sampler is not None
    saved = json.loads((tmp_path / "bundle" / "train_config.json").read_text())["sampler_stage"]
    assert saved["w_cross_style"] == 2.0 and saved["w_style"] == 0.5
    stamps = [(tmp_path / "run" / d / "weights.safetensors").stat().st_mtime_ns for d in ("critic", "critic-acceleration")]
    (tmp_path / "run" / "sampler" / "checkpoint.json").unlink()  # retrain the sampler only
    assert main(args) == 0
    assert [(tmp_path / "run" / d / "weights.safetensors").stat().st_mtime_ns
            for d in ("critic", "critic-acceleration")] == stamps
