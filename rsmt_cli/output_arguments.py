"""The engine's per-bundle setting flags (output steps, int8 LSTM), shared by ``rsmt eval`` and ``rsmt bench``."""

from __future__ import annotations

import argparse
from dataclasses import fields
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported where used: `rsmt --help` loads no torch
    from model.inference.overrides import Overrides


def add_output_arguments(p: argparse.ArgumentParser, owner: str) -> None:
    """``--smoothing``, ``--root-smoothing``, ``--foot-lock``, ``--steering``, ``--floor``, ``--stride-warp``,
    ``--foot-plant``, ``--int8-lstm`` and ``--style-strength``; ``owner`` names whose settings they override in the
    help ("each bundle", "the bundle")."""
    p.add_argument("--smoothing", type=float, default=None, metavar="A",
                   help=f"output-filter strength, in [0, 1) (default: {owner}'s own setting; 0 gives the network's "
                        "raw frames)")
    p.add_argument("--root-smoothing", type=float, default=None, metavar="B",
                   help=f"output-filter strength for the root position (default: as --smoothing when that is given, "
                        f"else {owner}'s own)")
    p.add_argument("--foot-lock", choices=("on", "off"), default=None,
                   help=f"foot locking on or off (default: {owner}'s own setting)")
    p.add_argument("--steering", type=int, default=None, metavar="FRAMES",
                   help=f"steer the root toward the target over the last FRAMES frames (0: off; default: {owner}'s "
                        "own setting)")
    p.add_argument("--floor", choices=("on", "off"), default=None,
                   help=f"lift a body whose feet sink under its context's floor, on or off (default: {owner}'s own "
                        "setting)")
    p.add_argument("--stride-warp", type=float, default=None, metavar="R",
                   help="stretch the strides where steering carries the body, up to 1 + R times the network's "
                        f"(0: off; default: {owner}'s own setting)")
    p.add_argument("--foot-plant", choices=("on", "off"), default=None,
                   help="bring a still foot that stands higher than its style's capture allows (the bundle's "
                        f"gait_limits.json, planted_rise_cm) down to the floor, on or off (default: {owner}'s own "
                        "setting)")
    p.add_argument("--int8-lstm", choices=("on", "off"), default=None,
                   help=f"run the LSTM cell of the per-frame step with int8 weights, on or off (default: {owner}'s "
                        "own setting)")
    p.add_argument("--style-strength", type=float, default=None, metavar="K",
                   help="move every style away from the bundle's neutral style (the mean of its built-in styles) by "
                        f"K, in [0, 4] (1: as encoded; default: {owner}'s own setting)")


SWITCHES = ("foot_lock", "floor", "foot_plant", "int8_lstm")  # the settings given as on / off


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def output_overrides(args: argparse.Namespace) -> Overrides:
    """The flags as the engine's :class:`~model.inference.overrides.Overrides` (None: the bundle's own), checked
    here so that an error names the flag. Each flag is its setting's name with dashes."""
    from model.inference.overrides import Overrides

    given = {}
    for f in fields(Overrides):
        value = getattr(args, f.name)
        given[f.name] = value == "on" if f.name in SWITCHES and value is not None else value
    try:
        return Overrides(**given)
    except ValueError as exc:  # "NAME must be ..., got X": the flag's name instead
        name = str(exc).split(" ", 1)[0]
        raise ValueError(str(exc).replace(name, _flag(name), 1).split(", got ")[0]) from exc


def output_flags(args: argparse.Namespace) -> list[str]:
    """The flags given, as a command line that repeats them."""
    from model.inference.overrides import Overrides

    parts: list[str] = []
    for f in fields(Overrides):
        value = getattr(args, f.name)
        if value is not None:
            parts += [_flag(f.name), f"{value:g}" if isinstance(value, float) else str(value)]
    return parts
