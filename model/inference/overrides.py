"""A caller's overrides of a bundle's engine settings: its output steps and how it runs its network.

One object, keyword-only, with one field per setting of :data:`model.inference.declared_settings.SETTINGS` (its
name, kind, range and help, from which the CLI flags and the ``RSMT_*`` variables are built too); None keeps the
bundle's own setting. Every caller that lets a user change these (``rsmt eval``, ``rsmt bench``, ``rsmt package``,
the service's settings) builds one of these and hands it on whole.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from model.inference.declared_settings import SETTINGS
from model.inference.output.settings import OutputConfig
from model.inference.settings import InferenceConfig


@dataclass(frozen=True, kw_only=True)
class Overrides:
    """One field per declared setting, in the order of :data:`~model.inference.declared_settings.SETTINGS`
    (what each does and its range are declared there; each value given is checked against its range)."""

    smoothing: float | None = None
    root_smoothing: float | None = None
    foot_lock: bool | None = None
    steering: int | None = None
    floor: bool | None = None
    stride_warp: float | None = None
    foot_plant: bool | None = None
    int8_lstm: bool | None = None
    style_strength: float | None = None

    def __post_init__(self) -> None:
        for setting in SETTINGS:
            if (value := getattr(self, setting.name)) is not None:
                setting.check(value)

    def given(self) -> dict[str, float | int | bool]:
        """The settings this object changes, by name."""
        return {f.name: v for f in fields(self) if (v := getattr(self, f.name)) is not None}

    def output(self, settings: OutputConfig) -> OutputConfig:
        """A bundle's output settings with these overrides. Once either strength is given, the root follows
        ``root_smoothing`` alone: unset, it takes ``smoothing``'s value."""
        return settings.with_overrides(smoothing=self.smoothing, root_smoothing=self.root_smoothing,
                                       foot_lock=self.foot_lock, steering=self.steering, floor=self.floor,
                                       stride_warp=self.stride_warp, foot_plant=self.foot_plant)

    def inference(self, settings: InferenceConfig) -> InferenceConfig:
        """A bundle's inference settings with these overrides."""
        return settings.with_overrides(int8_lstm=self.int8_lstm, style_strength=self.style_strength)


# A field per declaration, in its order, of its kind's type (the annotations are strings here).
if [(f.name, f.type) for f in fields(Overrides)] != [(s.name, f"{s.python_type.__name__} | None") for s in SETTINGS]:
    raise TypeError("Overrides' fields must be the settings of model.inference.declared_settings.SETTINGS")
