"""Entry point of the ``rsmt`` console command."""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence

from rsmt_cli import (
    average_commands,
    bench_commands,
    client_commands,
    data_commands,
    eval_commands,
    finetune_commands,
    loadtest_commands,
    package_commands,
    rig_commands,
    serve_commands,
    train_commands,
)

# Each command group module exposes ``register(subparsers)``; later groups are appended here.
GROUPS = [data_commands, train_commands, bench_commands, serve_commands, eval_commands, finetune_commands, average_commands,
          package_commands, client_commands, loadtest_commands, rig_commands]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rsmt", description="Real-time stylized motion transitions.")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for group in GROUPS:
        group.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
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
