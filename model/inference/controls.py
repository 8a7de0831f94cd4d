"""A request's own values of the settings a request may set for itself (``per_request`` in
:mod:`model.inference.declared_settings`), carried whole from the route to the engine step that reads them.

The service hands the fields it received to :meth:`Controls.of`, which checks them against their declarations; the
engine keeps the result in the character's request, and the step that uses a value asks for it by name
(:meth:`Controls.get`). Nothing between the two names a control, so a new one is its declaration, the step that
reads it and the clients (docs/architecture.md, "Adding a request field").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from model.inference import declared_settings
from model.inference.declared_settings import Setting

Value = float | int | bool


@dataclass(frozen=True)
class Controls:
    """The controls a request set, as ``(name, value)`` pairs in declaration order; a control it left out is
    absent (the engine's setting applies)."""

    values: tuple[tuple[str, Value], ...] = ()

    @classmethod
    def of(cls, given: Mapping[str, Any] | None, declared: Sequence[Setting] | None = None) -> Controls:
        """The controls in ``given`` (None values dropped), each converted to its declared kind and range-checked;
        ``declared``: the settings a request may set (default: :data:`declared_settings.REQUEST_CONTROLS`). A name
        not declared, a value of the wrong kind or out of its range is a ValueError that names the setting."""
        settings = declared_settings.REQUEST_CONTROLS if declared is None else tuple(declared)
        given = dict(given or {})
        unknown = sorted(set(given) - {s.name for s in settings})
        if unknown:
            raise ValueError(f"unknown request control(s) {', '.join(unknown)}; a request may set "
                             f"{', '.join(s.name for s in settings) or 'none'}")
        values: list[tuple[str, Value]] = []
        for setting in settings:
            raw = given.get(setting.name)
            if raw is not None:
                values.append((setting.name, _value(setting, raw)))
        return cls(tuple(values))

    def get(self, name: str, default: Value | None = None) -> Value | None:
        """The value the request set for ``name``; ``default`` where it set none."""
        return dict(self.values).get(name, default)

    def to_dict(self) -> dict[str, Value]:
        return dict(self.values)


def _value(setting: Setting, raw: Any) -> Value:
    """``raw`` as ``setting``'s kind, in its range; else a ValueError naming the setting."""
    if setting.kind == "switch":
        if not isinstance(raw, bool):
            raise ValueError(f"{setting.name} must be true or false, got {raw!r}")
        return raw
    if isinstance(raw, bool) or not isinstance(raw, (int, float)):
        raise ValueError(f"{setting.name} must be a number, got {raw!r}")
    if setting.kind == "int" and not float(raw).is_integer():
        raise ValueError(f"{setting.name} must be a whole number, got {raw!r}")
    if not math.isfinite(raw):
        raise ValueError(f"{setting.name} must be a finite number, got {raw!r}")
    value: Value = int(raw) if setting.kind == "int" else float(raw)
    setting.check(value)
    return value
