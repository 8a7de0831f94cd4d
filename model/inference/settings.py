"""How the engine runs a bundle's network: a bundle setting, like the output steps (:mod:`model.inference.output.settings`).

A bundle saved without this section runs its network in float32 throughout.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from model.inference.style_strength import check_strength


@dataclass(frozen=True)
class InferenceConfig:
    """``int8_lstm``: run the recurrent core's LSTM cell with int8 weights in the per-frame step
    (:mod:`model.inference.int8_step`). The cell holds 43% of the weights a frame reads, and at batch 1 a
    frame is bound by reading them; the rest of the network stays float32, because quantising all
    of it cost same-style accuracy (docs/experiments/2026-11-benchmark-runs.md). ``style_strength``: every
    style's context moved away from the bundle's neutral style by this factor (1: as encoded;
    :mod:`model.inference.style_strength`)."""

    int8_lstm: bool = False
    style_strength: float = 1.0

    def __post_init__(self) -> None:
        check_strength(self.style_strength)

    def with_overrides(self, int8_lstm: bool | None = None, style_strength: float | None = None) -> InferenceConfig:
        """These settings with a caller's overrides (None keeps a setting)."""
        return InferenceConfig(self.int8_lstm if int8_lstm is None else bool(int8_lstm),
                               self.style_strength if style_strength is None else float(style_strength))

    def to_dict(self) -> dict:
        """The settings as a bundle saves them; a style strength of 1 is left out, so a bundle that does not use
        it still loads in releases from before it."""
        data = asdict(self)
        if self.style_strength == 1.0:
            del data["style_strength"]
        return data

    @classmethod
    def from_dict(cls, data: dict) -> InferenceConfig:
        unknown = set(data) - {"int8_lstm", "style_strength"}
        if unknown:
            raise ValueError(f"unknown inference settings: {', '.join(sorted(unknown))}")
        if not isinstance(data.get("int8_lstm", False), bool):
            raise ValueError("int8_lstm must be true or false")
        return cls(**data)
