"""``rsmt train ... --set KEY=VALUE``: the settings reach the config a stage trains with, a bad one stops the command."""

from __future__ import annotations

import json

from model.data.synthetic import synthetic_skeleton
from model.train.pipeline import TrainConfig, fit_to_skeleton
from model.train.presets import load_preset
from rsmt_cli.main import build_parser, main
from rsmt_cli.train_commands import load_config


def _config(*argv: str) -> TrainConfig:
    return load_config(build_parser(["train", *argv]).parse_args(["train", *argv]))


def test_set_changes_a_preset_and_a_config_file(tmp_path):
    cfg = _config("all", "--preset", "smoke", "--set", "sampler_stage.loop.iterations=7", "--set", "seed=3")
    smoke = load_preset("smoke")
    assert (cfg.sampler_stage.loop.iterations, cfg.seed) == (7, 3)
    assert cfg.to_dict() | {"seed": 0} != smoke.to_dict()  # the iterations changed too
    cfg.sampler_stage.loop.iterations, cfg.seed = smoke.sampler_stage.loop.iterations, smoke.seed
    assert cfg == smoke  # and nothing else
    saved = tmp_path / "train_config.json"
    saved.write_text(json.dumps(smoke.to_dict()))
    from_file = _config("sampler", "--config", str(saved), "--set", "sampler_stage.w_style=0.5")
    assert from_file.sampler_stage.w_style == 0.5 and from_file.name == smoke.name


def test_an_unknown_key_or_a_bad_value_stops_the_command_naming_it(tmp_path, capsys):
    for setting, message in (("sampler_stage.loop.iteration=5", "no setting 'iteration' in sampler_stage.loop"),
                             ("sampler_stage.batch=many", "expected a whole number, got 'many'")):
        status = main(["train", "all", "--preset", "smoke", "--data", str(tmp_path), "--device", "cpu",
                       "--set", setting])
        assert status == 2
        assert message in capsys.readouterr().err


def test_the_recipe_command_takes_settings_for_every_stage(tmp_path, capsys):
    """A run folder holding the plain preset's stage A is not the recipe's with a setting changed: refused before
    anything trains, naming that setting."""
    folder = tmp_path / "run" / "stages" / "A"
    folder.mkdir(parents=True)
    sk = synthetic_skeleton()
    (folder / "train_config.json").write_text(
        json.dumps(fit_to_skeleton(load_preset("smoke"), sk.num_joints, sk.roles.root).to_dict()))
    status = main(["train", "recipe", "smoke", "--out", str(tmp_path / "b"), "--data", str(tmp_path), "--run",
                   str(tmp_path / "run"), "--device", "cpu", "--set", "sampler_stage.w_pos=2.5"])
    assert status == 2
    assert "trained with other settings than stage A's (sampler_stage.w_pos)" in capsys.readouterr().err
