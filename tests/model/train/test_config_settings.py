"""``--set KEY=VALUE``: one training setting from the command line, read with its setting's type."""

from __future__ import annotations

import pytest

from model.train.config_settings import setting_changes
from model.train.pipeline import TrainConfig
from model.train.presets import load_preset


def test_dotted_keys_nest_as_in_a_preset_and_values_take_the_settings_types():
    changes = setting_changes([
        "sampler_stage.loop.iterations=200", "sampler_stage.w_style=0.25", "augment=false", "name=mine",
        "sampler_stage.loop.restart_at=100,150", "sampler_stage.loop.restart_lr=3e-4,2e-4", "ratios=0.7,0.2,0.1",
        "holdout_styles=elderly,zombie", "profile=null", "sampler_stage.w_cross_style=0.5", "sampler.fps=24",
        "sampler_stage.loop.warmup=10", "sampler_stage.loop.warmup=20",  # the last one counts
    ], TrainConfig)
    assert changes == {
        "name": "mine", "augment": False, "ratios": (0.7, 0.2, 0.1), "holdout_styles": ("elderly", "zombie"),
        "profile": None, "sampler": {"fps": 24.0},
        "sampler_stage": {"w_style": 0.25, "w_cross_style": 0.5,
                          "loop": {"iterations": 200, "restart_at": (100, 150), "restart_lr": (3e-4, 2e-4), "warmup": 20}},
    }
    assert isinstance(changes["sampler"]["fps"], float)
    cfg = load_preset("smoke", changes=changes)
    assert (cfg.sampler_stage.loop.iterations, cfg.sampler_stage.loop.restarts()) == (200, [(100, 3e-4), (150, 2e-4)])
    one = setting_changes(["sampler_stage.loop.restart_at=120", "sampler_stage.w_cross_style=none"], TrainConfig)
    assert one == {"sampler_stage": {"loop": {"restart_at": 120}, "w_cross_style": None}}


@pytest.mark.parametrize(("text", "message"), [
    ("sampler_stage.loop.iteration=5", r"no setting 'iteration' in sampler_stage\.loop; the settings there: iterations"),
    ("nope=1", r"no setting 'nope'; the settings there: name, about"),
    ("sampler_stage.loop=5", r"sampler_stage\.loop is a group of settings; name one of them: sampler_stage\.loop\.iterations"),
    ("seed.x=5", r"seed is a single setting"),
    ("sampler_stage.loop.iterations=1.5", r"'sampler_stage\.loop\.iterations=1\.5': expected a whole number, got '1\.5'"),
    ("sampler_stage.w_style=heavy", r"expected a number, got 'heavy'"),
    ("augment=maybe", r"expected true or false"),
    ("ratios=0.5,0.5", r"expected 3 comma-separated values, got 2"),
    ("profile", r"write KEY=VALUE"),
    ("=3", r"write KEY=VALUE"),
    ("seed=null", r"expected a whole number, got 'null'"),  # a setting that cannot be unset
])
def test_an_unknown_key_or_a_bad_value_is_an_error_naming_it(text, message):
    with pytest.raises(ValueError, match=message):
        setting_changes([text], TrainConfig)


def test_a_value_of_the_right_type_is_still_checked_by_the_config():
    with pytest.raises(ValueError, match="critic_inputs must be distinct selections"):
        load_preset("smoke", changes=setting_changes(["sampler_stage.critic_inputs=dynamics,colour"], TrainConfig))
