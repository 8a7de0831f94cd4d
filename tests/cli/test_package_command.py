"""``rsmt package``: a shippable copy of a bundle with float16 weights, a name, and settings in its config."""

from __future__ import annotations

import json

import torch

from model.inference.bundle import Bundle
from rsmt_cli.main import main
from tests.model.tiny_bundles import tiny_bundle


def test_package_writes_float16_weights_and_the_settings(tmp_path, capsys):
    source = tiny_bundle(3)
    source.save(tmp_path / "trained")
    (tmp_path / "trained" / "train_config.json").write_text('{"name": "recipe"}')
    args = ["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "ship"), "--float16",
            "--name", "shipped", "--smoothing", "0.3", "--foot-lock", "on", "--int8-lstm", "on"]
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    ship = Bundle.load(tmp_path / "ship")
    assert report["version"] == ship.version != source.version  # float16 storage changes the hash
    assert ship.meta.name == "shipped" and report["name"] == "shipped"
    assert (ship.output.smoothing, ship.output.foot_lock, ship.inference.int8_lstm) == (0.3, True, True)
    config = json.loads((tmp_path / "ship" / "config.json").read_text())
    assert config["output"]["smoothing"] == 0.3 and config["inference"] == {"int8_lstm": True}
    assert (tmp_path / "ship" / "train_config.json").read_text() == '{"name": "recipe"}'
    # The weights are the source's, rounded to float16 and nothing else.
    for key, value in source.tensors().items():
        got = ship.tensors()[key]
        if value.is_floating_point():
            assert torch.equal(got, value.half().float()), key
        else:
            assert torch.equal(got, value), key


def test_package_keeps_unset_settings_and_refuses_bad_ones(tmp_path, capsys):
    source = tiny_bundle(4)
    source.save(tmp_path / "trained")
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "copy")]) == 0
    copy = Bundle.load(tmp_path / "copy")
    assert copy.version == source.version and copy.output == source.output and copy.inference == source.inference
    capsys.readouterr()
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "x"), "--smoothing", "1.5"]) == 2
    assert "--smoothing must be in [0, 1)" in capsys.readouterr().err and not (tmp_path / "x").exists()
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "trained")]) == 2
    assert "must not be the --model folder" in capsys.readouterr().err
