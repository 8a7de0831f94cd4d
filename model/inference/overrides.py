"""A caller's overrides of a bundle's engine settings: its output steps and how it runs its network.

One object, keyword-only, with one name per setting (the name the bundle's ``output`` / ``inference``
section, the CLI flag and the ``RSMT_*`` variable use); None keeps the bundle's own setting. Every
caller that lets a user change these (``rsmt eval``, ``rsmt bench``, ``rsmt package``, the service's
settings) builds one of these and hands it on whole.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from model.inference.output.settings import OutputConfig
from model.inference.settings import InferenceConfig
from model.inference.style_strength import check_strength


@dataclass(frozen=True, kw_only=True)
class Overrides:
    """``smoothing`` / ``root_smoothing``: the output filter's strengths, in [0, 1) (a ``smoothing`` given
    alone applies to the root too); ``foot_lock``, ``floor``: those steps on or off; ``steering``: the
    steering window in frames (0: every part of steering off); ``stride_warp``: the stride warp's reach,
    in [0, 4] (0: off); ``foot_plant``: the foot plant on or off (it acts only where the bundle's gait limits
    give a style its planted rise); ``int8_lstm``: the LSTM cell of the per-frame step with int8 weights;
    ``style_strength``: every style moved away from the bundle's neutral style by this factor, in [0, 4]."""

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
        for name in ("smoothing", "root_smoothing"):
            value = getattr(self, name)
            if value is not None and not 0.0 <= value < 1.0:
                raise ValueError(f"{name} must be in [0, 1), got {value}")
        if self.steering is not None and self.steering < 0:
            raise ValueError(f"steering must be 0 (off) or more frames, got {self.steering}")
        if self.style_strength is not None:
            check_strength(self.style_strength)
        if self.stride_warp is not None and not 0.0 <= self.stride_warp <= 4.0:
            raise ValueError(f"stride_warp must be in [0, 4], got {self.stride_warp}")

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
