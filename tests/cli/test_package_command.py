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
            "--name", "shipped", "--smoothing", "0.3", "--foot-lock", "on", "--int8-lstm", "on", "--foot-plant", "on"]
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    ship = Bundle.load(tmp_path / "ship")
    assert report["version"] == ship.version != source.version  # float16 storage changes the hash
    assert ship.meta.name == "shipped" and report["name"] == "shipped"
    assert (ship.output.smoothing, ship.output.foot_lock, ship.inference.int8_lstm) == (0.3, True, True)
    assert ship.output.foot_plant and not source.output.foot_plant
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
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "x"), "--turn-window", "-1"]) == 2
    assert "--turn-window must be 0 (off) or more frames" in capsys.readouterr().err and not (tmp_path / "x").exists()
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "x"),
                 "--retarget-max-turn-deg", "0"]) == 2
    assert "--retarget-max-turn-deg must be a positive" in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_package_sets_the_facing_and_height_steering(tmp_path, capsys):
    tiny_bundle(5).save(tmp_path / "trained")
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "a"), "--steering", "40",
                 "--turn-window", "10", "--height-window", "8"]) == 0
    steering = Bundle.load(tmp_path / "a").output.steering
    assert (steering.window, steering.turn_window, steering.height_window) == (40, 10, 8)
    # Unset flags keep the copied bundle's own; 0 switches a part off.
    assert main(["package", "--model", str(tmp_path / "a"), "--out", str(tmp_path / "b"), "--height-window", "0"]) == 0
    steering = Bundle.load(tmp_path / "b").output.steering
    assert (steering.window, steering.turn_window, steering.height_window) == (40, 10, 0)
    assert (steering.retarget_turn_window, steering.retarget_max_turn_deg) == (0, 4.0)  # off unless asked
    assert main(["package", "--model", str(tmp_path / "b"), "--out", str(tmp_path / "c"), "--retarget-turn-window", "20",
                 "--retarget-max-turn-deg", "10"]) == 0
    steering = Bundle.load(tmp_path / "c").output.steering
    assert (steering.turn_window, steering.retarget_turn_window, steering.retarget_max_turn_deg) == (10, 20, 10.0)
    assert main(["package", "--model", str(tmp_path / "c"), "--out", str(tmp_path / "d"), "--max-step-cm", "15",
                 "--stride-warp", "2"]) == 0
    copy = Bundle.load(tmp_path / "d")
    assert (copy.output.steering.max_step_cm, copy.output.steering.turn_window, copy.output.stride_warp) == (15.0, 10, 2.0)
    assert main(["package", "--model", str(tmp_path / "c"), "--out", str(tmp_path / "e"), "--max-step-cm", "0"]) == 2
    assert "--max-step-cm must be a positive" in capsys.readouterr().err and not (tmp_path / "e").exists()
    # The flags' old names still work for one release, and say so.
    assert main(["package", "--model", str(tmp_path / "c"), "--out", str(tmp_path / "f"), "--steer-cap", "12",
                 "--steer-facing", "6", "--steer-height", "3", "--retarget-facing", "15", "--retarget-turn-cap", "8"]) == 0
    err = capsys.readouterr().err
    assert "--steer-cap is deprecated and goes in the next release: use --max-step-cm" in err
    assert "--retarget-turn-cap is deprecated" in err
    steering = Bundle.load(tmp_path / "f").output.steering
    assert (steering.max_step_cm, steering.turn_window, steering.height_window, steering.retarget_turn_window,
            steering.retarget_max_turn_deg) == (12.0, 6, 3, 15, 8.0)


def test_package_stores_builtin_styles_and_add_styles_changes_only_the_styles(tmp_path, capsys):
    from model.data.synthetic import synthetic_walk
    from model.motion.bvh_clip import dump_clip

    tiny_bundle(5).save(tmp_path / "trained")
    clips = tmp_path / "clips"
    clips.mkdir()
    (clips / "slow.bvh").write_text(dump_clip(synthetic_walk(40, speed_cm_s=60.0)))
    (clips / "brisk.bvh").write_text(dump_clip(synthetic_walk(61, fps=60.0, speed_cm_s=160.0)))
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "ship"),
                 "--styles", str(clips)]) == 0
    assert json.loads(capsys.readouterr().out)["styles"] == ["brisk", "slow"]
    ship = Bundle.load(tmp_path / "ship")
    assert {n: s.frames for n, s in ship.styles.items()} == {"brisk": 31, "slow": 40}

    weights = (tmp_path / "ship" / "weights.safetensors").read_bytes()
    config = (tmp_path / "ship" / "config.json").read_text()
    (clips / "slow.bvh").unlink()
    assert main(["bundle", "add-styles", str(tmp_path / "ship"), "--from", str(clips)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [s["style_id"] for s in report["styles"]] == ["builtin:brisk"]
    assert (tmp_path / "ship" / "weights.safetensors").read_bytes() == weights
    assert (tmp_path / "ship" / "config.json").read_text() == config
    assert sorted(Bundle.load(tmp_path / "ship").styles) == ["brisk"]
    # A clip too long for the model's style encoder is refused, naming the fix.
    (clips / "long.bvh").write_text(dump_clip(synthetic_walk(300)))
    assert main(["bundle", "add-styles", str(tmp_path / "ship"), "--from", str(clips)]) == 2
    assert "cut the file first" in capsys.readouterr().err


def test_package_keeps_codes_only_for_the_same_weights(tmp_path, capsys):
    from safetensors.torch import load_file

    from model.data.synthetic import synthetic_walk
    from model.motion.bvh_clip import dump_clip

    tiny_bundle(6).save(tmp_path / "trained")
    clips = tmp_path / "clips"
    clips.mkdir()
    (clips / "slow.bvh").write_text(dump_clip(synthetic_walk(40, speed_cm_s=60.0)))
    assert main(["bundle", "add-styles", str(tmp_path / "trained"), "--from", str(clips)]) == 0
    capsys.readouterr()
    # Same weights: the codes are copied as they are.
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "same")]) == 0
    assert json.loads(capsys.readouterr().out)["styles"] == ["slow"]
    copied, source = (load_file(str(tmp_path / d / "styles" / "codes.safetensors")) for d in ("same", "trained"))
    assert copied.keys() == source.keys() and all(torch.equal(copied[k], source[k]) for k in source)
    # float16 weights are other weights (another version): the codes are not copied, and the command says so.
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "half"), "--float16"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["styles"] == [] and "rsmt bundle add-styles" in out.err
    assert not (tmp_path / "half" / "styles").exists() and Bundle.load(tmp_path / "half").styles == {}
    # With --styles the clips are encoded by the copy's own (float16) weights.
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "half"), "--float16",
                 "--styles", str(clips)]) == 0
    half = Bundle.load(tmp_path / "half")
    assert sorted(half.styles) == ["slow"] and half.styles["slow"].version == half.version != Bundle.load(
        tmp_path / "trained").version


def test_the_default_bundles_styles_are_remade_from_the_train_split(tmp_path, capsys):
    import shutil

    import pytest

    from model.data.location import find_data_dir
    from model.data.preprocessed import load_motion_cache
    from model.inference.bundle import DEFAULT_BUNDLE

    data = find_data_dir()
    if data is None:
        pytest.skip("motion data not found (set RSMT_DATA)")
    shipped = Bundle.load(DEFAULT_BUNDLE)
    assert len(shipped.styles) == 7
    copy = tmp_path / "default"
    shutil.copytree(DEFAULT_BUNDLE, copy)
    assert main(["bundle", "add-styles", str(copy), "--from-data", str(data)]) == 0
    report = json.loads(capsys.readouterr().out)
    remade = Bundle.load(copy)
    assert remade.version == shipped.version and sorted(remade.styles) == sorted(shipped.styles)
    for name, style in shipped.styles.items():  # the shipped codes are those of the train-split clips
        for f in ("gamma1", "beta1", "keys1", "values1", "gamma2", "beta2", "keys2", "values2"):
            assert torch.allclose(getattr(remade.styles[name].context, f), getattr(style.context, f), atol=1e-5), name
        assert torch.equal(remade.styles[name].context.mask, style.context.mask)
        assert 120 <= style.frames <= 240 and remade.styles[name].source == style.source
    cache = load_motion_cache(data, progress=False, workers=1)
    train = {cache.takes[i].take_id for i in cache.split.train}
    for s in report["styles"]:
        take_id = s["source"].split(" frames ")[0]
        assert take_id in train and "_walk_" in take_id, s


def test_package_keeps_style_adapters_only_for_the_same_weights(tmp_path, capsys):
    import copy

    from model.data.synthetic import synthetic_walk
    from model.inference.bundle_adapters import adapter_from
    from model.inference.bundle_styles import StyleClip
    from model.inference.style_packing import write_adapter

    tiny_bundle(7).save(tmp_path / "trained")
    bundle = Bundle.load(tmp_path / "trained")
    tuned = copy.deepcopy(bundle.sampler)
    with torch.no_grad():
        next(tuned.film1.parameters()).add_(0.1)
    write_adapter(tmp_path / "trained", adapter_from(bundle.sampler, tuned, "limp", bundle.version),
                  StyleClip("limp", synthetic_walk(40), "limp.bvh"))
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "same"),
                 "--name", "shipped"]) == 0
    assert json.loads(capsys.readouterr().out)["styles"] == ["limp"]
    assert sorted(Bundle.load(tmp_path / "same").adapters) == ["limp"]
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "half"), "--float16"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["styles"] == [] and "fine-tune them again" in out.err
    assert not (tmp_path / "half" / "adapters").exists()


def test_gait_limits_are_measured_into_a_bundle_and_packaged_with_it(tmp_path, capsys, monkeypatch):
    from model.data.synthetic import SYNTHETIC_STYLES, write_synthetic_dataset
    from model.motion.gait_limits import GAIT_LIMITS_FILE

    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    write_synthetic_dataset(tmp_path / "data", takes_per_pair=2, frames=60)
    tiny_bundle(6).save(tmp_path / "trained")
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "bare")]) == 0
    assert "no gait limits" in capsys.readouterr().err and not (tmp_path / "bare" / GAIT_LIMITS_FILE).exists()
    assert main(["bundle", "gait-limits", str(tmp_path / "trained"), "--from-data", str(tmp_path / "data")]) == 0
    report = json.loads(capsys.readouterr().out)
    assert set(report["styles"]) == set(SYNTHETIC_STYLES)
    measured = Bundle.load(tmp_path / "trained").gait_limits
    assert measured is not None and measured.styles["slow"].max_speed_cm_s < measured.styles["brisk"].max_speed_cm_s
    # A copy keeps the source's limits; --gait-data measures them again.
    assert main(["package", "--model", str(tmp_path / "trained"), "--out", str(tmp_path / "ship"), "--float16"]) == 0
    assert json.loads(capsys.readouterr().out)["gait_limits"] == measured.to_dict()
    assert (tmp_path / "ship" / GAIT_LIMITS_FILE).read_text() == (tmp_path / "trained" / GAIT_LIMITS_FILE).read_text()
    assert main(["package", "--model", str(tmp_path / "bare"), "--out", str(tmp_path / "again"),
                 "--gait-data", str(tmp_path / "data")]) == 0
    again = Bundle.load(tmp_path / "again").gait_limits
    assert again is not None and again.to_dict() == measured.to_dict()
