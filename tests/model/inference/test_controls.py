"""The settings a request sets for itself (model/inference/controls.py): checked against their declarations, carried
whole into the character's request, and read there by the engine step they belong to."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from model.data.synthetic import synthetic_walk
from model.inference import declared_settings
from model.inference.bundle import DEFAULT_BUNDLE, Bundle
from model.inference.controls import Controls
from model.inference.declared_settings import BY_NAME, REQUEST_CONTROLS, Setting
from model.inference.engine import Engine
from model.inference.errors import EngineError

STRENGTH = BY_NAME["style_strength"]
TOY = Setting("toy_gain", "float", "a control only this test declares", high=2.0, per_request=True)


def test_style_strength_is_a_request_control():
    assert STRENGTH in REQUEST_CONTROLS
    assert all(s.per_request for s in REQUEST_CONTROLS)


@given(st.floats(min_value=0.0, max_value=4.0))
def test_a_value_in_range_is_kept_as_given(value: float):
    controls = Controls.of({"style_strength": value})
    assert controls.get("style_strength") == value and controls.to_dict() == {"style_strength": value}


@given(st.one_of(st.floats(max_value=-1e-9), st.floats(min_value=4.0 + 1e-9), st.just(math.nan),
                 st.just(math.inf)))
def test_a_value_out_of_range_names_the_setting(value: float):
    with pytest.raises(ValueError, match="style_strength must be"):
        Controls.of({"style_strength": value})


@pytest.mark.parametrize("value", [True, "1.5", [1.0]])
def test_a_value_of_another_kind_is_refused(value: object):
    with pytest.raises(ValueError, match="style_strength must be a number"):
        Controls.of({"style_strength": value})


def test_none_is_left_out_and_an_unknown_name_is_refused():
    assert Controls.of({"style_strength": None}) == Controls() == Controls.of(None)
    assert Controls().get("style_strength", 2.0) == 2.0
    with pytest.raises(ValueError, match=r"unknown request control\(s\) speed; a request may set style_strength"):
        Controls.of({"speed": 1.0})


def test_kinds_follow_their_declaration():
    switch = Setting("toy_switch", "switch", "on or off", per_request=True)
    count = Setting("toy_count", "int", "a count", high=10, per_request=True)
    assert Controls.of({"toy_switch": True, "toy_count": 3.0}, [switch, count]).values == (("toy_switch", True),
                                                                                         ("toy_count", 3))
    with pytest.raises(ValueError, match="toy_switch must be true or false"):
        Controls.of({"toy_switch": 1}, [switch])
    with pytest.raises(ValueError, match="toy_count must be a whole number"):
        Controls.of({"toy_count": 2.5}, [count])


@pytest.fixture(scope="module")
def engine() -> Engine:
    return Engine(Bundle.load(DEFAULT_BUNDLE), threads=1)


def _prepare(engine: Engine, controls: dict[str, object]):
    walk = synthetic_walk(frames=160)
    style, _ = engine.encode_style(walk.window(20, 140))
    return engine.prepare(walk.window(0, 10), walk.window(40, 42), 20, style, deterministic=True, controls=controls)


def test_the_engine_keeps_a_request_s_controls_and_refuses_bad_ones(engine: Engine):
    ch = _prepare(engine, {"style_strength": 1.5})
    assert ch.request.controls.to_dict() == {"style_strength": 1.5}
    assert _prepare(engine, {}).request.controls == Controls()
    with pytest.raises(EngineError, match="style_strength must be in"):
        _prepare(engine, {"style_strength": 9.0})
    with pytest.raises(EngineError, match="unknown request control"):
        _prepare(engine, {"toy_gain": 1.0})


def test_a_newly_declared_control_reaches_the_request_with_no_other_code(engine: Engine, monkeypatch):
    """Declaring a control is all the engine needs to carry it to the step that reads it."""
    monkeypatch.setattr(declared_settings, "REQUEST_CONTROLS", (*REQUEST_CONTROLS, TOY))
    ch = _prepare(engine, {"toy_gain": 1.25, "style_strength": 1.0})
    assert ch.request.controls.get("toy_gain") == 1.25 and ch.request.controls.get("style_strength") == 1.0
    with pytest.raises(EngineError, match="toy_gain must be in"):
        _prepare(engine, {"toy_gain": 3.0})
