"""The ``rsmt average`` command: a weighted mean of bundles continued from one parent."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "average", help="average the weights of bundles fine-tuned from one parent (a model soup)",
        description="Write a bundle whose weights are the weighted mean of the given bundles' (same configs and "
                    "skeleton; the first bundle's output settings and model card fields). Only meaningful for "
                    "a bundle and its own continuations: see model/train/weight_average.py.")
    p.add_argument("--model", type=Path, action="append", required=True, metavar="BUNDLE",
                   help="a bundle folder; repeat, at least twice")
    p.add_argument("--weight", type=float, action="append", metavar="W",
                   help="weight of each --model in order (default: equal); normalised to sum 1")
    p.add_argument("--name", help="model name in the new bundle's config (default: the first bundle's)")
    p.add_argument("--float16", action="store_true", help="store the weights as float16 (half the file)")
    p.add_argument("--out", type=Path, required=True, help="folder of the new bundle")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from model.inference.bundle import Bundle
    from model.train.weight_average import average_bundles

    if args.out.resolve() in {m.resolve() for m in args.model}:
        raise ValueError("--out must not be one of the averaged bundles")
    bundles = [Bundle.load(m) for m in args.model]
    mixed = average_bundles(bundles, args.weight, args.name)
    mixed.save(args.out, weights_dtype="float16" if args.float16 else "float32")
    print(json.dumps({"bundle": str(args.out), "version": mixed.version, "notes": mixed.meta.notes}, indent=1))
    return 0
