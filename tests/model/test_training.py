"""The whole training recipe runs on synthetic data, writes a loadable bundle, and resumes."""

from __future__ import annotations

import json

import pytest

from model.bundle import Bundle
from model.engine import Engine
from model.synthetic import synthetic_walk, write_synthetic_dataset
from rsmt_cli.main import main

pytestmark = pytest.mark.usefixtures("one_thread")


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
