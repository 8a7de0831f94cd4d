"""Flags renamed to the one name a setting has everywhere; the old spelling keeps working for one release."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any


class RenamedFlag(argparse.Action):
    """An old flag: stores into the new flag's setting and says, on stderr, that it goes in the next release."""

    def __init__(self, option_strings: Sequence[str], dest: str, new: str = "", **kwargs: Any) -> None:
        super().__init__(option_strings, dest, help=argparse.SUPPRESS, **kwargs)
        self.new = new

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        print(f"rsmt: {option_string} is deprecated and goes in the next release: use {self.new}", file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_renamed(p: argparse.ArgumentParser, old: str, new: str, kind: type) -> None:
    """Accept ``old`` as a deprecated spelling of the flag ``new`` (already added to ``p``)."""
    p.add_argument(old, dest=new.lstrip("-").replace("-", "_"), type=kind, action=RenamedFlag, new=new,
                   default=argparse.SUPPRESS)
