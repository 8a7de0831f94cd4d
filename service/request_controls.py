"""The request fields that set an engine setting for one request: one optional field per setting declared
``per_request`` (:data:`model.inference.declared_settings.REQUEST_CONTROLS`), built from its declaration (kind,
range, help), and shared by ``POST /v1/transition`` and the stream's ``start`` (:mod:`service.schemas`).

A request's :attr:`ControlFields.controls` is what it set, by name; the service hands it to the engine whole
(:meth:`model.inference.engine.Engine.prepare`), so no code between the body and the engine step names a control.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated, Any, ClassVar

from pydantic import BaseModel, Field, StrictBool, StrictInt, create_model

from model.inference.declared_settings import REQUEST_CONTROLS, Setting


class ControlFields(BaseModel):
    """The base of a request's control fields (:func:`control_fields` adds one per declared control)."""

    control_names: ClassVar[tuple[str, ...]] = ()

    @property
    def controls(self) -> dict[str, Any]:
        """The controls this request set, by name (a field left out or null is not among them)."""
        values = {name: getattr(self, name) for name in self.control_names}
        return {name: value for name, value in values.items() if value is not None}


def control_field(setting: Setting) -> tuple[Any, None]:
    """``setting`` as an optional request field (default null: the server's setting), with its declared range and
    help in the OpenAPI contract."""
    bounds: dict[str, Any] = {}
    if setting.kind != "switch":
        bounds["ge"] = setting.low
        if setting.high is not None:
            bounds["lt" if setting.high_open else "le"] = setting.high
    base: Any = {"switch": StrictBool, "float": float, "int": StrictInt}[setting.kind]
    described: Any = Annotated[base, Field(description=f"{setting.help}; default: the server's setting ({setting.env})",
                                      **bounds)]
    return (described | None, None)


def control_fields(settings: Sequence[Setting] = REQUEST_CONTROLS) -> type[ControlFields]:
    """A pydantic mixin with one optional field per setting of ``settings``."""
    fields: dict[str, Any] = {s.name: control_field(s) for s in settings}
    mixin = create_model("RequestControls", __base__=ControlFields, **fields)
    mixin.control_names = tuple(s.name for s in settings)
    return mixin


if TYPE_CHECKING:
    RequestControls = ControlFields
else:
    RequestControls = control_fields()
