"""What the engine does to the network's frames before they leave: a bundle setting.

Every step is causal and per character, so whole transitions and streams get the same frames. The
filter and the foot lock hand the arrival frame back untouched (see :mod:`model.inference.output.smoothing`,
:mod:`model.inference.output.foot_lock`); floor contact lifts any frame whose feet sink, the arrival frame
included (:mod:`model.inference.output.floor_contact`). A bundle saved without this section gets the
network's frames as they are.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from model.inference.declared_settings import BY_NAME
from model.inference.output.steering import SteeringConfig


@dataclass(frozen=True)
class OutputConfig:
    """``smoothing``: the causal output filter's weight of the previous emitted frame for the joint
    rotations, in [0, 1) (0: off); ``root_smoothing``: the same for the root position (None: as
    ``smoothing``). ``foot_lock``: hold planted feet by leg IK. ``steering``: keep the root on course
    for the target (:mod:`model.inference.output.steering`; its window 0: off). ``floor``: lift a body whose
    feet sink under the floor of its context (:mod:`model.inference.output.floor_contact`). ``stride_warp``: the
    longest stride the feet are stretched to where steering carries the body, as a share of the
    network's stride beyond 1 (:mod:`model.inference.output.stride_warp`; 0: off). ``foot_plant``: bring a planted
    foot that stands higher than its style's capture down to the floor (:mod:`model.inference.output.foot_plant`)."""

    smoothing: float = 0.0
    foot_lock: bool = False
    root_smoothing: float | None = None
    steering: SteeringConfig = field(default_factory=SteeringConfig)
    floor: bool = False
    stride_warp: float = 0.0
    foot_plant: bool = False

    def __post_init__(self) -> None:
        for name, value in (("stride_warp", self.stride_warp), ("smoothing", self.smoothing),
                            ("root_smoothing", self.root_strength)):
            BY_NAME[name].check(value)  # the ranges the overrides, flags and RSMT_* variables check

    @property
    def root_strength(self) -> float:
        return self.smoothing if self.root_smoothing is None else self.root_smoothing

    @property
    def smooths(self) -> bool:
        return self.smoothing > 0 or self.root_strength > 0

    def with_overrides(self, *, smoothing: float | None = None, root_smoothing: float | None = None,
                       foot_lock: bool | None = None, steering: int | None = None,
                       floor: bool | None = None, stride_warp: float | None = None,
                       foot_plant: bool | None = None) -> OutputConfig:
        """These settings with a caller's overrides (None keeps a setting). Once either strength is
        given, the root follows ``root_smoothing`` alone: unset, it takes ``smoothing``'s value.
        ``steering`` is the ground steering window in frames (0: every part of steering off)."""
        if smoothing is not None or root_smoothing is not None:
            rot = self.smoothing if smoothing is None else float(smoothing)
            root = None if root_smoothing is None else float(root_smoothing)
        else:
            rot, root = self.smoothing, self.root_smoothing
        steer = self.steering if steering is None else self.steering.with_window(int(steering))
        return OutputConfig(rot, self.foot_lock if foot_lock is None else bool(foot_lock), root, steer,
                            self.floor if floor is None else bool(floor),
                            self.stride_warp if stride_warp is None else float(stride_warp),
                            self.foot_plant if foot_plant is None else bool(foot_plant))

    def in_words(self) -> str:
        """These settings as a short phrase, e.g. ``smoothing 0.3/0.3, foot lock on, steering 40 (facing 5),
        floor contact, stride warp 2`` (a part that is off is left out; the stride warp needs steering)."""
        steer = self.steering
        finish = ", ".join(f"{part} {frames}" for part, frames in (("facing", steer.turn_window),
                                                                   ("height", steer.height_window)) if frames)
        steering = f", steering {steer.window}{f' ({finish})' if finish else ''}" if steer.on else ""
        return (f"smoothing {self.smoothing:g}/{self.root_strength:g}, foot lock {'on' if self.foot_lock else 'off'}"
                f"{steering}{', floor contact' if self.floor else ''}"
                f"{f', stride warp {self.stride_warp:g}' if self.stride_warp and steer.on else ''}"
                f"{', foot plant' if self.foot_plant else ''}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> OutputConfig:
        unknown = set(data) - {"smoothing", "root_smoothing", "foot_lock", "steering", "floor", "stride_warp",
                               "foot_plant"}
        if unknown:
            raise ValueError(f"unknown output settings: {', '.join(sorted(unknown))}")
        data = dict(data)
        if "steering" in data:
            data["steering"] = SteeringConfig.from_dict(data["steering"])
        return cls(**data)
