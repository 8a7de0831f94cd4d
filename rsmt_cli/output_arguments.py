"""The engine's per-bundle setting flags (output steps, int8 LSTM), shared by ``rsmt eval`` and ``rsmt bench``."""

from __future__ import annotations

import argparse

from model.inference.overrides import Overrides


def add_output_arguments(p: argparse.ArgumentParser, owner: str) -> None:
    """``--smoothing``, ``--root-smoothing``, ``--foot-lock``, ``--steering``, ``--floor``, ``--stride-warp`` and
    ``--int8-lstm``; ``owner`` names whose settings they override in the help ("each bundle", "the bundle")."""
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
    p.add_argument("--int8-lstm", choices=("on", "off"), default=None,
                   help=f"run the LSTM cell of the per-frame step with int8 weights, on or off (default: {owner}'s "
                        "own setting)")


def output_overrides(args: argparse.Namespace) -> Overrides:
    """The flags as the engine's :class:`~model.inference.overrides.Overrides` (None: the bundle's own), checked
    here so that an error names the flag."""
    for flag, value in (("--smoothing", args.smoothing), ("--root-smoothing", args.root_smoothing)):
        if value is not None and not 0.0 <= value < 1.0:
            raise ValueError(f"{flag} must be in [0, 1)")
    if args.steering is not None and args.steering < 0:
        raise ValueError("--steering must be 0 (off) or more frames")
    if args.stride_warp is not None and not 0.0 <= args.stride_warp <= 4.0:
        raise ValueError("--stride-warp must be in [0, 4]")
    return Overrides(steering=args.steering, smoothing=args.smoothing, root_smoothing=args.root_smoothing,
                     foot_lock=None if args.foot_lock is None else args.foot_lock == "on",
                     floor=None if args.floor is None else args.floor == "on", stride_warp=args.stride_warp,
                     int8_lstm=None if args.int8_lstm is None else args.int8_lstm == "on")
