"""Named recipes: chains of presets run in one run folder, resumed by skipping finished stages, then packaged."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path
from typing import Any

import pytest
import torch

from model.data.synthetic import SYNTHETIC_STYLES, synthetic_skeleton, synthetic_walk, write_synthetic_dataset
from model.inference.bundle import Bundle
from model.inference.engine import Engine
from model.train.pipeline import fit_to_skeleton
from model.train.presets import load_preset
from model.train.recipe_chains import (
    ChainStage,
    PackageSettings,
    Recipe,
    load_recipe,
    recipe_names,
    run_recipe,
    stage_folder,
)
from rsmt_cli import package_commands
from rsmt_cli.main import main

pytestmark = pytest.mark.usefixtures("one_thread")


def test_every_recipe_loads_and_names_presets_that_exist():
    assert {"default-model", "smoke"} <= set(recipe_names())
    for name in recipe_names():
        recipe = load_recipe(name)
        assert recipe.about and recipe.stages[0].command == "all"
        for stage in recipe.stages:
            load_preset(stage.preset)
    shipped = load_recipe("default-model")
    assert [(s.label, s.command, s.preset) for s in shipped.stages] == [
        ("A", "all", "two-hour-1-frames"), ("B", "sampler", "two-hour-2-critics"),
        ("C", "sampler", "two-hour-3-accuracy"), ("D", "sampler", "two-hour-4-accuracy"),
        ("E1", "sampler", "cross-style-1-critics"), ("E2", "sampler", "cross-style-2-arrival"),
        ("E3", "sampler", "cross-style-3-accuracy"), ("F", "sampler", "control-1-one-frame")]
    assert shipped.package == PackageSettings(name="rsmt-default", float16=True, smoothing=0.3, foot_lock=True,
                                              int8_lstm=True, steering=40, turn_window=5, height_window=5,
                                              retarget_turn_window=20, retarget_max_turn_deg=10.0, floor=True,
                                              stride_warp=2.0, max_step_cm=15.0)


def test_chains_with_the_old_package_names_still_load():
    old = {"about": "x", "stages": [{"label": "A", "command": "all", "preset": "smoke"}],
           "package": {"steer_facing": 5, "steer_height": 4, "retarget_facing": 20, "retarget_turn_cap": 10.0,
                       "steer_cap": 15.0}}
    with pytest.warns(DeprecationWarning, match="steer_cap.*max_step_cm"):
        package = Recipe.from_dict("r", old).package
    assert package == PackageSettings(turn_window=5, height_window=4, retarget_turn_window=20,
                                      retarget_max_turn_deg=10.0, max_step_cm=15.0)


def test_recipe_files_are_checked():
    good: dict[str, Any] = {"about": "x", "stages": [{"label": "A", "command": "all", "preset": "smoke"}]}
    assert Recipe.from_dict("r", good).package == PackageSettings()
    for bad, message in (
        ({**good, "stage": []}, "unknown recipe setting"),
        ({**good, "stages": []}, "no stages"),
        ({**good, "stages": [{"label": "A", "command": "phase", "preset": "smoke"}]}, "command must be one of all, sampler"),
        ({**good, "stages": [{"label": "A", "command": "sampler", "preset": "smoke"}]}, "first stage must train every"),
        ({**good, "stages": good["stages"] * 2}, "labels must differ"),
        ({**good, "stages": [{"label": "../A", "command": "all", "preset": "smoke"}]}, "plain folder name"),
        ({**good, "package": {"float_16": True}}, "unknown package setting"),
    ):
        with pytest.raises(ValueError, match=message):
            Recipe.from_dict("r", bad)


def test_package_settings_are_the_package_command_options():
    settings = PackageSettings(name="shipped", float16=True, smoothing=0.3, foot_lock=True, int8_lstm=False, steering=40,
                               turn_window=10, height_window=0, retarget_turn_window=20, retarget_max_turn_deg=7.5,
                               floor=True, stride_warp=1.5, max_step_cm=12.0)
    options = settings.arguments()
    assert options == ["--float16", "--name", "shipped", "--smoothing", "0.3", "--foot-lock", "on", "--int8-lstm", "off",
                       "--floor", "on", "--steering", "40", "--turn-window", "10", "--height-window", "0",
                       "--retarget-turn-window", "20", "--retarget-max-turn-deg", "7.5", "--stride-warp", "1.5",
                       "--max-step-cm", "12.0"]
    parser = argparse.ArgumentParser()
    package_commands.register(parser.add_subparsers())
    args = parser.parse_args(["package", "--model", "m", "--out", "o", *options])
    assert (args.name, args.float16, args.smoothing, args.foot_lock, args.int8_lstm, args.steering, args.turn_window,
            args.height_window, args.floor) == ("shipped", True, 0.3, "on", "off", 40, 10, 0, "on")
    assert (args.retarget_turn_window, args.retarget_max_turn_deg, args.stride_warp, args.max_step_cm) == (20, 7.5, 1.5, 12.0)
    assert PackageSettings().arguments() == []


def test_list_names_every_recipe_with_its_about(capsys):
    assert main(["train", "recipe", "--list"]) == 0
    out = capsys.readouterr().out
    for name in recipe_names():
        assert f"{name}: {load_recipe(name).about}" in out
    assert main(["train", "recipe"]) == 2
    assert "name a recipe" in capsys.readouterr().err


def _stage_lines(out: str) -> list[str]:
    return [line for line in out.splitlines() if line.startswith("stage ")]


def _check_stage_report(out: str) -> None:
    """The run prints one timed line per stage, naming the command it ran, then the total."""
    lines = _stage_lines(out)
    assert len(lines) == 2
    assert re.match(r"stage 1/2 A \(rsmt train all --preset smoke\): \d+ s", lines[0])
    assert re.match(r"stage 2/2 B \(rsmt train sampler --preset smoke-critics\): \d+ s", lines[1])
    assert re.search(r"^total: \d+ s", out, re.M)


def _check_shipped_bundle(ship: Bundle, ship_dir: Path, run_dir: Path, out: str) -> None:
    """The packaged bundle: its name, gait limits and output settings, the last stage's weights in float16 and
    the last preset's config; it generates frames."""
    assert ship.meta.name == "rsmt-smoke"
    # The capture's gait limits of the training takes come with it: every style it trained on, speeds measured.
    assert ship.gait_limits is not None and set(ship.gait_limits.styles) == set(SYNTHETIC_STYLES)
    assert all(g.max_speed_cm_s > 0 for g in ship.gait_limits.styles.values()) and "gait limits: " in out
    assert (ship.output.smoothing, ship.output.foot_lock, ship.inference.int8_lstm) == (0.3, True, True)
    # The last stage's bundle, packaged: its config is the last preset's, its weights float16.
    last = Bundle.load(stage_folder(run_dir, load_recipe("smoke").stages[-1])).tensors()
    shipped = ship.tensors()
    assert shipped.keys() == last.keys()
    assert all(torch.equal(shipped[k], v.half().float() if v.is_floating_point() else v) for k, v in last.items())
    saved = json.loads((ship_dir / "train_config.json").read_text())
    assert saved["sampler_stage"] == json.loads(json.dumps(load_preset("smoke-critics").to_dict()))["sampler_stage"]
    engine = Engine(ship)
    walk = synthetic_walk(frames=60)
    style, _ = engine.encode_style(walk.window(10, 50))
    rot, _ = engine.generate([engine.prepare(walk.window(0, 10), walk.window(30, 32), 8, style, deterministic=True)])[0]
    assert rot.shape[0] == 8


def _check_rerun_skips_finished_stages(args: list[str], run_dir: Path, ship_again: Path, ship: Bundle,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    """Run again: both stages are found finished and skipped, their bundles untouched; packaging runs again."""
    stamps = [(stage_folder(run_dir, s) / "weights.safetensors").stat().st_mtime_ns for s in load_recipe("smoke").stages]
    assert main([*args[:-2], str(ship_again), "--quiet"]) == 0
    again = _stage_lines(capsys.readouterr().out)
    assert [line.split(":")[1].strip() for line in again] == ["done before, skipped; bundle " + str(run_dir / "stages" / s)
                                                              for s in ("A", "B")]
    assert [(stage_folder(run_dir, s) / "weights.safetensors").stat().st_mtime_ns
            for s in load_recipe("smoke").stages] == stamps
    assert Bundle.load(ship_again).version == ship.version


@pytest.mark.slow  # trains a recipe and its stages by hand
def test_a_recipe_runs_end_to_end_packages_and_skips_finished_stages(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    data = tmp_path / "data"
    write_synthetic_dataset(data)
    run_dir = tmp_path / "run"
    # On the CPU, whatever the machine: the by-hand run below must train the same weights.
    args = ["train", "recipe", "smoke", "--data", str(data), "--run", str(run_dir), "--device", "cpu", "--out",
            str(tmp_path / "ship"), "--quiet"]
    assert main(args) == 0
    out = capsys.readouterr().out
    _check_stage_report(out)
    ship = Bundle.load(tmp_path / "ship")
    _check_shipped_bundle(ship, tmp_path / "ship", run_dir, out)
    _check_rerun_skips_finished_stages(args, run_dir, tmp_path / "ship-again", ship, capsys)

    # The recipe trains what its commands run by hand give.
    hand = ["--data", str(data), "--run", str(tmp_path / "hand"), "--device", "cpu", "--quiet"]
    assert main(["train", "all", "--preset", "smoke", "--out", str(tmp_path / "A"), *hand]) == 0
    assert main(["train", "sampler", "--preset", "smoke-critics", "--out", str(tmp_path / "B"), *hand]) == 0
    assert main(["package", "--model", str(tmp_path / "B"), "--out", str(tmp_path / "hand-ship"),
                 *load_recipe("smoke").package.arguments()]) == 0
    assert Bundle.load(tmp_path / "hand-ship").version == ship.version


def _finished(run_dir, label: str, preset: str) -> None:
    """A stage's bundle folder as a run leaves it: its train_config.json (fitted to the rig) written last."""
    folder = run_dir / "stages" / label
    folder.mkdir(parents=True)
    sk = synthetic_skeleton()
    (folder / "train_config.json").write_text(json.dumps(fit_to_skeleton(load_preset(preset), sk.num_joints,
                                                                         sk.roles.root).to_dict()))


def test_a_run_folder_with_a_gap_or_other_settings_is_refused_before_training(tmp_path):
    recipe = load_recipe("smoke")
    _finished(tmp_path / "gap", "B", "smoke-critics")
    with pytest.raises(ValueError, match="stage A has no bundle .* but later stages do \\(B\\)"):
        run_recipe(recipe, tmp_path / "no-data", tmp_path / "gap")
    _finished(tmp_path / "other", "A", "smoke-critics")
    with pytest.raises(ValueError, match="trained with other settings than stage A's \\(sampler_stage"):
        run_recipe(recipe, tmp_path / "no-data", tmp_path / "other")
    assert not (tmp_path / "gap" / "recipe.json").exists()
    stage = ChainStage("A", "all", "smoke")
    assert stage_folder(tmp_path, stage) == tmp_path / "stages" / "A"


@pytest.mark.slow  # trains a recipe
def test_held_out_styles_reach_every_stage_and_the_bundle_name(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    data = tmp_path / "data"
    write_synthetic_dataset(data)
    run_dir = tmp_path / "run"
    assert main(["train", "recipe", "smoke", "--data", str(data), "--run", str(run_dir), "--device", "cpu",
                 "--out", str(tmp_path / "ship"), "--quiet", "--holdout-style", "bouncy"]) == 0
    for stage in load_recipe("smoke").stages:
        saved = json.loads((stage_folder(run_dir, stage) / "train_config.json").read_text())
        assert saved["holdout_styles"] == ["bouncy"]
    critic = json.loads((run_dir / "critic" / "config.json").read_text())
    assert "bouncy" not in critic["styles"] and len(critic["styles"]) == 2
    assert Bundle.load(tmp_path / "ship").meta.name == "rsmt-smoke-without-bouncy"
    # The same run folder without the holdout trains other settings: refused, not overwritten.
    with pytest.raises(ValueError, match="holdout_styles"):
        run_recipe(load_recipe("smoke"), data, run_dir)


def test_a_recipe_may_extend_another_and_change_every_stage(tmp_path):
    base = {"about": "parent", "stages": [{"label": "A", "command": "all", "preset": "smoke"},
                                          {"label": "B", "command": "sampler", "preset": "smoke-critics"}],
            "package": {"name": "p", "float16": True}, "changes": {"sampler_stage": {"warp_batch": 2}}}
    (tmp_path / "parent.json").write_text(json.dumps(base))
    child = {"extends": "parent", "about": "child", "package": {"name": "c"},
             "changes": {"sampler_stage": {"w_warp_foot": 0.5}}}
    (tmp_path / "child.json").write_text(json.dumps(child))
    recipe = load_recipe("child", tmp_path)
    assert recipe.about == "child" and [s.preset for s in recipe.stages] == ["smoke", "smoke-critics"]
    assert recipe.package == PackageSettings(name="c", float16=True)
    assert recipe.changes == {"sampler_stage": {"warp_batch": 2, "w_warp_foot": 0.5}}
    for stage in recipe.stages:
        cfg, plain = recipe.stage_config(stage), load_preset(stage.preset)
        assert (cfg.sampler_stage.warp_batch, cfg.sampler_stage.w_warp_foot) == (2, 0.5)
        assert cfg.to_dict()["sampler_stage"] | {"warp_batch": 0, "w_warp_foot": 0.0} == \
               plain.to_dict()["sampler_stage"] | {"warp_batch": 0, "w_warp_foot": 0.0}
    # A run folder holding the plain preset's stage is not this recipe's: refused before anything trains.
    _finished(tmp_path / "plain", "A", "smoke")
    with pytest.raises(ValueError, match="other settings than stage A's .*warp_batch"):
        run_recipe(recipe, tmp_path / "no-data", tmp_path / "plain")
    for name, bad, message in (
        ("typo", {**child, "changes": {"sampler_stage": {"warp_batches": 8}}},
         "unknown setting 'changes.sampler_stage.warp_batches'"),
        ("loop", {**child, "extends": "loop"}, "in a circle: loop -> loop"),
        ("orphan", {**child, "extends": "missing"}, "no training recipe 'missing'"),
    ):
        (tmp_path / f"{name}.json").write_text(json.dumps(bad))
        with pytest.raises((ValueError, FileNotFoundError), match=message):
            load_recipe(name, tmp_path)


def test_the_warped_recipe_is_the_shipped_one_with_warped_windows_in_every_stage():
    shipped, warped = load_recipe("default-model"), load_recipe("default-model-warped")
    assert warped.stages == shipped.stages and warped.package == shipped.package and not shipped.changes
    for stage in warped.stages:
        cfg = warped.stage_config(stage).sampler_stage
        assert (cfg.warp_batch, cfg.w_warp_foot, cfg.train_decoder) == (8, 0.5, False)
