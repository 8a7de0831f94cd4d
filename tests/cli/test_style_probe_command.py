"""``rsmt style-probe``: a bundle's style codes of a split's takes, scored per style."""

from __future__ import annotations

import json

import pytest

from model.data.synthetic import synthetic_skeleton, write_synthetic_dataset
from model.inference.bundle import Bundle
from rsmt_cli.main import main

pytestmark = pytest.mark.usefixtures("one_thread")


def test_the_probe_scores_every_style_of_the_split(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    Bundle.create(synthetic_skeleton()).save(tmp_path / "m")
    data = tmp_path / "data"
    write_synthetic_dataset(data, takes_per_pair=3, frames=150)
    out = tmp_path / "probe.json"
    assert main(["style-probe", "--model", str(tmp_path / "m"), "--data", str(data), "--split", "train",
                 "--contents", "all", "--frames", "60", "--step", "45", "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "Style codes of" in text and "| style | clips |" in text
    report = json.loads(out.read_text())
    probe = report["models"][str(tmp_path / "m")]
    assert len(probe["styles"]) >= 2 and report["split"] == "train"
    for style in probe["styles"]:
        assert 0.0 <= probe["accuracy"][style] <= 1.0 and probe["separation"][style] >= 0.0
        assert sum(probe["read_as"][style].values()) == pytest.approx(1.0)
    # A clip longer than every take: refused with the reason.
    assert main(["style-probe", "--model", str(tmp_path / "m"), "--data", str(data), "--frames", "5000", "--quiet"]) == 2
    assert "5000 frames" in capsys.readouterr().err
