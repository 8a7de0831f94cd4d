"""The engine settings a caller may override, each declared once: its name, kind, range and help.

A bundle's ``output`` / ``inference`` sections, :class:`~model.inference.overrides.Overrides`, the CLI flags
(``rsmt_cli.output_arguments``), the service's ``RSMT_<NAME>`` variables (``service.settings``) and the settings
table of docs/service.md all come from :data:`SETTINGS`, and :meth:`Setting.check` is the one range check. A
setting marked ``per_request`` is also a field a request may set for itself (:data:`REQUEST_CONTROLS`): the
service's request bodies, :class:`model.inference.controls.Controls` and the engine step that reads it are all the
code it needs (docs/architecture.md, "Adding a request field"). This module imports nothing heavy: ``rsmt --help``
reads it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Kind = Literal["switch", "float", "int"]  # on / off; a number in [low, high] (or [low, high)); a whole number


@dataclass(frozen=True)
class Setting:
    """One setting: ``name`` (the bundle field, the CLI flag with dashes, ``RSMT_<NAME>``), ``kind``, its range
    ``[low, high]`` (``[low, high)`` with ``high_open``; no ``high``: no upper bound; a switch has none), ``help``
    (a phrase: what a value does, without the range or the default), ``metavar`` (the CLI flag's value) and
    ``per_request``: a request may set it for itself (a field of ``POST /v1/transition`` and the stream's ``start``;
    unset there: the engine's setting)."""

    name: str
    kind: Kind
    help: str
    low: float = 0.0
    high: float | None = None
    high_open: bool = False
    metavar: str | None = None
    per_request: bool = False

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    @property
    def env(self) -> str:
        return f"RSMT_{self.name.upper()}"

    @property
    def python_type(self) -> type:
        return {"switch": bool, "float": float, "int": int}[self.kind]

    def range_words(self, switch: str = "on or off") -> str:
        """The accepted values in words: ``in [0, 1)``, ``0 or more``, or ``switch`` for a switch."""
        if self.kind == "switch":
            return switch
        if self.high is None:
            return f"{self.low:g} or more"
        return f"in [{self.low:g}, {self.high:g}{')' if self.high_open else ']'}"

    def check(self, value: float) -> None:
        """A ValueError ``"<name> must be in [0, 1), got 1.5"`` where ``value`` is outside the range."""
        if self.kind == "switch":
            return
        above = self.high is not None and (value >= self.high if self.high_open else value > self.high)
        if value < self.low or above:
            raise ValueError(f"{self.name} must be {self.range_words()}, got {value}")


SETTINGS: tuple[Setting, ...] = (
    Setting("smoothing", "float", "causal output-filter strength (0: off, the network's raw frames); given alone it "
            "applies to the root too", high=1.0, high_open=True, metavar="A"),
    Setting("root_smoothing", "float", "output-filter strength for the root position alone (unset: as smoothing "
            "when that is given)", high=1.0, high_open=True, metavar="B"),
    Setting("foot_lock", "switch", "hold planted feet by leg IK"),
    Setting("steering", "int", "steer each character's root toward its target over its last this many frames "
            "(0: every part of steering off)", high=240, metavar="FRAMES"),
    Setting("floor", "switch", "lift a body whose feet sink under its context's floor"),
    Setting("stride_warp", "float", "stretch the strides where steering carries the body, up to 1 + this times the "
            "network's (0: off)", high=4.0, metavar="R"),
    Setting("foot_plant", "switch", "bring a still foot that stands higher than its style's capture allows (the "
            "bundle's gait limits, planted_rise_cm) down to the floor"),
    Setting("int8_lstm", "switch", "run the LSTM cell of the per-frame step with int8 weights"),
    Setting("style_strength", "float", "move every style away from the bundle's neutral style (the mean of its "
            "built-in styles) by this factor (1: as encoded)", high=4.0, metavar="K", per_request=True),
)
BY_NAME = {s.name: s for s in SETTINGS}
#: The settings a request may set for itself, in declaration order.
REQUEST_CONTROLS: tuple[Setting, ...] = tuple(s for s in SETTINGS if s.per_request)
