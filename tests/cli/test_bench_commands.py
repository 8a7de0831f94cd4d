"""``rsmt bench``: the table names each model with the settings it runs with."""

from __future__ import annotations

import pytest

from model.inference.bundle import DEFAULT_BUNDLE, Bundle
from model.inference.engine import Engine
from model.inference.overrides import Overrides
from rsmt_cli.bench_commands import engine_label


def test_the_label_names_every_output_step_the_engine_runs():
    bundle = Bundle.load(DEFAULT_BUNDLE)
    label = engine_label(Engine(bundle, threads=1), DEFAULT_BUNDLE)
    assert label == (f"{bundle.meta.name} (default_bundle; smoothing 0.3/0.3, foot lock on, steering 40 (facing 5, "
                     "height 5), floor contact, stride warp 2, int8 LSTM)")
    plain = engine_label(Engine(bundle, threads=1, overrides=Overrides(
        steering=0, smoothing=0.0, foot_lock=False, floor=False, int8_lstm=False)), DEFAULT_BUNDLE)
    assert plain == f"{bundle.meta.name} (default_bundle; smoothing 0/0, foot lock off)"  # no steering: no warp
    planted = engine_label(Engine(bundle, threads=1, overrides=Overrides(foot_plant=True)), DEFAULT_BUNDLE)
    assert planted.endswith("stride warp 2, foot plant, int8 LSTM)")
    strong = engine_label(Engine(bundle, threads=1, overrides=Overrides(style_strength=1.25)), DEFAULT_BUNDLE)
    assert strong.endswith("int8 LSTM, style strength 1.25)")


def test_the_output_flags_are_the_overrides_and_repeat_as_given():
    import argparse

    from rsmt_cli.output_arguments import add_output_arguments, output_flags, output_overrides

    p = argparse.ArgumentParser()
    add_output_arguments(p, "the bundle")
    args = p.parse_args(["--foot-plant", "on", "--floor", "off", "--stride-warp", "1.5", "--style-strength", "1.25"])
    assert output_overrides(args) == Overrides(foot_plant=True, floor=False, stride_warp=1.5, style_strength=1.25)
    assert output_flags(args) == ["--floor", "off", "--stride-warp", "1.5", "--foot-plant", "on", "--style-strength",
                                  "1.25"]
    with pytest.raises(ValueError, match="--style-strength must be in"):
        output_overrides(p.parse_args(["--style-strength", "9"]))
    assert output_overrides(p.parse_args([])) == Overrides()



def test_every_source_of_a_database_bundle_is_benched_with_its_search(tmp_path, capsys) -> None:
    from rsmt_cli.main import main
    from tests.model.nets.walk_database import walk_bundle

    folder = walk_bundle(turns=(0.0,)).save(tmp_path / "db")
    assert main(["bench", "--model", str(folder), "--source", "all", "--batch-sizes", "1", "--budget", "0.3",
                 "--no-paper", "--threads", "1"]) == 0
    out = capsys.readouterr().out
    assert "matching source" in out and "hybrid source" in out and "Database search at batch 1 over 400 rows" in out
