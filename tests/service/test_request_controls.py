"""Request controls in the contract (service/request_controls.py): one optional field per setting declared
``per_request``, in both request bodies, with its declared range, handed to the engine by name."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from model.inference.controls import Controls
from model.inference.declared_settings import REQUEST_CONTROLS, Setting
from service.request_controls import control_fields
from service.schemas import StartMessage, TransitionRequest

TOY = Setting("toy_gain", "float", "a control only this test declares", high=2.0, high_open=True, per_request=True)
BODY = {"context": {"bvh": "x"}, "target": {"bvh": "x"}, "frames": 30, "style_id": "sty_x"}


@pytest.mark.parametrize("body", [TransitionRequest, StartMessage])
def test_every_declared_control_is_an_optional_field_with_its_range(body):
    props = body.model_json_schema()["properties"]
    for setting in REQUEST_CONTROLS:
        field = props[setting.name]
        assert field["default"] is None
        number = next(part for part in field["anyOf"] if part.get("type") != "null")
        assert number["minimum"] == setting.low and number["maximum"] == setting.high
        assert setting.help in number["description"] and setting.env in number["description"]


def test_a_body_s_controls_are_what_it_set():
    assert TransitionRequest.model_validate(BODY).controls == {}
    assert TransitionRequest.model_validate({**BODY, "style_strength": 2}).controls == {"style_strength": 2.0}
    start = StartMessage.model_validate({**BODY, "type": "start", "style_strength": 0.5})
    assert start.controls == {"style_strength": 0.5}
    with pytest.raises(ValidationError, match="style_strength"):
        TransitionRequest.model_validate({**BODY, "style_strength": 4.5})


def test_a_newly_declared_control_becomes_a_field_and_reaches_the_engine_s_controls():
    """A body built from the declarations carries a new control to :class:`Controls` with no code naming it."""
    declared = (*REQUEST_CONTROLS, TOY)

    class Body(control_fields(declared)):  # type: ignore[misc]  # a mixin built at run time, as the schemas' is
        frames: int

    assert Body.model_json_schema()["properties"]["toy_gain"]["anyOf"][0]["exclusiveMaximum"] == 2.0
    body = Body.model_validate({"frames": 3, "toy_gain": 1.5})
    assert body.controls == {"toy_gain": 1.5}
    assert Controls.of(body.controls, declared).get("toy_gain") == 1.5
    with pytest.raises(ValidationError, match="toy_gain"):
        Body.model_validate({"frames": 3, "toy_gain": 2.0})
