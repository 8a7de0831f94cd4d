"""How fast and how high the capture moves, per style: the limits the engine keeps generated motion within.

Measured once from a data set's train split (:mod:`model.data.gait_capture`) and stored in a bundle as
``gait_limits.json`` beside its ``config.json`` (a few hundred bytes). Per style:

* ``max_speed_cm_s``: the largest horizontal speed of the hips over every train take of the style, all
  its locomotion included (walks, runs, dashes), frame to frame at the data's rate; ``p99_speed_cm_s``:
  the 99th percentile of the same speeds, over the frames where the hips move faster than 30 cm/s;
* ``hips_cm``: the hips' height range ``[lowest, highest]`` per gait (:func:`gait_of` the take's content);
* ``foot_lift_cm``: the most the lowest foot joint of a frame rises above the lowest it reaches in its take (a
  run's flight): a generated body whose feet are all higher than that above its floor floats, and is lowered;
* ``planted_rise_cm``: the most a planted foot's lowest joint stands above its take's floor
  (:mod:`model.motion.planted_feet`): a generated foot planted higher floats, and is brought down.

A style that is not built in (registered from a clip, or fine-tuned) moves within the largest maximum of
the built-in styles (:meth:`GaitLimits.max_speed` of a name it does not hold).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

GAIT_LIMITS_FILE = "gait_limits.json"
GAIT_LIMITS_FORMAT = "rsmt-gait-limits/1"
GAITS = ("walk", "run", "stand")


def gait_of(content: str) -> str:
    """The gait of a take's content label: ``run`` (runs and dashes), ``walk`` (any walk) or ``stand``."""
    c = content.lower()
    if "run" in c or "dash" in c:
        return "run"
    return "walk" if "walk" in c else "stand"


@dataclass(frozen=True)
class StyleGait:
    """One style's capture limits (see the module doc); ``takes``: the train takes they were measured on."""

    max_speed_cm_s: float
    p99_speed_cm_s: float
    hips_cm: dict[str, tuple[float, float]] = field(default_factory=dict)
    takes: int = 0
    foot_lift_cm: float = math.inf  # inf: not measured (a file written before it was)
    planted_rise_cm: float = math.inf  # inf: not measured (a file written before it was)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_speed_cm_s) and self.max_speed_cm_s > 0):
            raise ValueError(f"a style's capture maximum speed must be a positive number, got {self.max_speed_cm_s}")
        for gait, (lo, hi) in self.hips_cm.items():
            if gait not in GAITS or not lo <= hi:
                raise ValueError(f"bad hips height range for gait {gait!r}: [{lo}, {hi}]")


@dataclass(frozen=True)
class GaitLimits:
    """The capture limits of every built-in style, the data they came from and its frame rate."""

    styles: dict[str, StyleGait]
    source: str = ""
    fps: float = 30.0

    def __post_init__(self) -> None:
        if not self.styles:
            raise ValueError("gait limits need at least one style")

    def style(self, name: str | None) -> StyleGait | None:
        """The limits of the built-in style ``name``; None for a style the capture does not hold."""
        return self.styles.get(name) if name else None

    def max_speed(self, name: str | None) -> float:
        """The largest hips speed (cm/s) the style ``name`` may move at: its own capture maximum, or the largest
        of every built-in style's for a style the capture does not hold (registered from a clip)."""
        own = self.style(name)
        return own.max_speed_cm_s if own is not None else max(s.max_speed_cm_s for s in self.styles.values())

    def foot_lift(self, name: str | None) -> float:
        """The most the feet of the style ``name`` rise off the floor all at once (cm): its own capture's, or the
        largest of every built-in style's for a style the capture does not hold."""
        own = self.style(name)
        return own.foot_lift_cm if own is not None else max(s.foot_lift_cm for s in self.styles.values())

    def planted_rise(self, name: str | None) -> float:
        """The most a planted foot of the style ``name`` stands above the floor (cm): its own capture's, or the
        largest of every built-in style's for a style the capture does not hold (inf: not measured)."""
        own = self.style(name)
        return own.planted_rise_cm if own is not None else max(s.planted_rise_cm for s in self.styles.values())

    def to_dict(self) -> dict[str, Any]:
        return {"format": GAIT_LIMITS_FORMAT, "source": self.source, "fps": self.fps,
                "styles": {n: {"max_speed_cm_s": round(s.max_speed_cm_s, 1),
                               "p99_speed_cm_s": round(s.p99_speed_cm_s, 1),
                               "hips_cm": {g: [round(lo, 1), round(hi, 1)] for g, (lo, hi) in sorted(s.hips_cm.items())},
                               "takes": s.takes,
                               **({"foot_lift_cm": round(s.foot_lift_cm, 1)} if math.isfinite(s.foot_lift_cm) else {}),
                               **({"planted_rise_cm": round(s.planted_rise_cm, 1)}
                                  if math.isfinite(s.planted_rise_cm) else {})}
                           for n, s in sorted(self.styles.items())}}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> GaitLimits:
        if data.get("format") != GAIT_LIMITS_FORMAT:
            raise ValueError(f"unsupported gait limits format {data.get('format')!r} (expected {GAIT_LIMITS_FORMAT})")
        styles = {n: StyleGait(float(s["max_speed_cm_s"]), float(s["p99_speed_cm_s"]),
                               {g: (float(r[0]), float(r[1])) for g, r in s.get("hips_cm", {}).items()},
                               int(s.get("takes", 0)), float(s.get("foot_lift_cm", math.inf)),
                               float(s.get("planted_rise_cm", math.inf)))
                  for n, s in data["styles"].items()}
        return cls(styles, str(data.get("source", "")), float(data.get("fps", 30.0)))

    def save(self, folder: str | Path) -> Path:
        """Write ``folder/gait_limits.json``; returns its path."""
        path = Path(folder) / GAIT_LIMITS_FILE
        path.write_text(json.dumps(self.to_dict(), indent=1) + "\n")
        return path

    @classmethod
    def load(cls, folder: str | Path) -> GaitLimits | None:
        """The limits saved in ``folder`` (a bundle), or None where it has none; a bad file is a ValueError."""
        path = Path(folder) / GAIT_LIMITS_FILE
        if not path.is_file():
            return None
        try:
            return cls.from_dict(json.loads(path.read_text()))
        except (json.JSONDecodeError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}: bad gait limits: {exc}") from exc
