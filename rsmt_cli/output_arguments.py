"""The engine's per-bundle setting flags (output steps, int8 LSTM), shared by ``rsmt eval``, ``rsmt bench`` and
``rsmt package``, built from their declarations (:mod:`model.inference.declared_settings`)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from model.inference.declared_settings import BY_NAME, SETTINGS  # light: no torch

if TYPE_CHECKING:  # imported where used: `rsmt --help` loads no torch
    from model.inference.overrides import Overrides


def add_output_arguments(p: argparse.ArgumentParser, owner: str) -> None:
    """A flag per declared setting (:data:`~model.inference.declared_settings.SETTINGS`: ``--smoothing``,
    ``--root-smoothing``, ``--foot-lock``, ...), its help from the declaration; ``owner`` names whose settings they
    override in the help ("each bundle", "the bundle")."""
    for s in SETTINGS:
        help_text = f"{s.help}, {s.range_words()} (default: {owner}'s own setting)"
        if s.kind == "switch":
            p.add_argument(s.flag, choices=("on", "off"), default=None, help=help_text)
        else:
            p.add_argument(s.flag, type=s.python_type, default=None, metavar=s.metavar, help=help_text)


def output_overrides(args: argparse.Namespace) -> Overrides:
    """The flags as the engine's :class:`~model.inference.overrides.Overrides` (None: the bundle's own), checked
    here so that an error names the flag. Each flag is its setting's name with dashes."""
    from model.inference.overrides import Overrides

    given = {}
    for s in SETTINGS:
        value = getattr(args, s.name)
        given[s.name] = value == "on" if s.kind == "switch" and value is not None else value
    try:
        return Overrides(**given)
    except ValueError as exc:  # "NAME must be ..., got X": the flag's name instead
        name = str(exc).split(" ", 1)[0]
        raise ValueError(str(exc).replace(name, BY_NAME[name].flag, 1).split(", got ")[0]) from exc


def output_flags(args: argparse.Namespace) -> list[str]:
    """The flags given, as a command line that repeats them."""
    parts: list[str] = []
    for s in SETTINGS:
        value = getattr(args, s.name)
        if value is not None:
            parts += [s.flag, f"{value:g}" if isinstance(value, float) else str(value)]
    return parts
