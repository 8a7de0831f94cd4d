"""Entry point of the ``rsmt`` console command."""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence
from types import ModuleType

# The command groups in the order of ``rsmt --help``: each module exposes ``register(subparsers)`` and adds the
# commands listed beside it. ``rsmt COMMAND ...`` imports only COMMAND's module (``rsmt client ...`` starts without
# the data, training or load-test modules' imports); ``rsmt``, ``rsmt --help`` and an unknown command import all.
GROUPS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("data_commands", ("data",)),
    ("train_commands", ("train",)),
    ("bench_commands", ("bench",)),
    ("serve_commands", ("serve",)),
    ("eval_commands", ("eval",)),
    ("finetune_commands", ("finetune-style",)),
    ("style_probe_commands", ("style-probe",)),
    ("average_commands", ("average",)),
    ("package_commands", ("package", "bundle")),
    ("export_commands", ("export",)),
    ("client_commands", ("client",)),
    ("loadtest_commands", ("loadtest",)),
    ("rig_commands", ("rig",)),
    ("profile_commands", ("profile",)),
)


def group_modules(argv: Sequence[str] | None = None) -> list[ModuleType]:
    """The group modules a command line needs: its command's, or all of them (``argv`` None: all)."""
    command = next((a for a in argv if not a.startswith("-")), None) if argv is not None else None
    names = [module for module, commands in GROUPS if command in commands] or [module for module, _ in GROUPS]
    return [importlib.import_module(f"rsmt_cli.{name}") for name in names]


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser of ``rsmt``; given ``argv``, only with the command group that line needs."""
    parser = argparse.ArgumentParser(prog="rsmt", description="Real-time stylized motion transitions.")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for group in group_modules(argv):
        group.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; a reader that stops reading (``rsmt client demo | head -5``) ends it quietly."""
    try:
        try:
            return _main(argv)
        finally:
            sys.stdout.flush()  # here, where a closed pipe is still caught, not at the interpreter's exit
    except BrokenPipeError:
        return _reader_gone()


# The exit status of a command killed by SIGPIPE (128 + 13), as a shell reports it.
EXIT_BROKEN_PIPE = 141


def _reader_gone() -> int:
    """Stdout points at /dev/null from now on, so the interpreter's last flush finds no closed pipe to report."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # no file descriptor (a test's captured stdout): nothing to flush there
        pass
    return EXIT_BROKEN_PIPE


def _main(argv: Sequence[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)]
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s %(message)s")
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except (ValueError, FileNotFoundError) as exc:
        print(f"rsmt: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
