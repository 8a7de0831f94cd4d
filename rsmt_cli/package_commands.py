"""The ``rsmt package`` command: a copy of a trained bundle made ready to ship.

Training writes float32 weights and the default output settings; the shipped default model is
float16 with its output steps and int8 LSTM cell switched on in ``config.json``. This command
does those steps, so a training recipe ends in a command rather than hand edits.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
from pathlib import Path

from rsmt_cli.output_arguments import add_output_arguments, output_overrides


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "package", help="copy a bundle for shipping: float16 weights, a name, output and inference settings",
        description="Write a copy of a bundle with its weights, optionally stored as float16, and with the given "
                    "output and inference settings saved in its config.json (unset flags keep the bundle's own). "
                    "The training config beside the weights is copied too.")
    p.add_argument("--model", type=Path, required=True, metavar="BUNDLE", help="the bundle folder to copy")
    p.add_argument("--out", type=Path, required=True, help="folder of the new bundle")
    p.add_argument("--name", help="model name in the new bundle's config (default: the bundle's own)")
    p.add_argument("--float16", action="store_true", help="store the weights as float16 (half the file)")
    add_output_arguments(p, "the bundle")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from model.inference.bundle import Bundle

    if args.out.resolve() == args.model.resolve():
        raise ValueError("--out must not be the --model folder")
    overrides = output_overrides(args)  # checked before anything is read or written
    bundle = Bundle.load(args.model)
    bundle.output = bundle.output.with_overrides(overrides["smoothing"], overrides["root_smoothing"],
                                                 overrides["foot_lock"])
    bundle.inference = bundle.inference.with_overrides(overrides["int8_lstm"])
    if args.name:
        bundle.meta = dataclasses.replace(bundle.meta, name=args.name)
    bundle.save(args.out, weights_dtype="float16" if args.float16 else "float32")
    train_config = args.model / "train_config.json"
    if train_config.is_file():
        shutil.copyfile(train_config, args.out / "train_config.json")
    print(json.dumps({"bundle": str(args.out), "version": bundle.version, "name": bundle.meta.name,
                      "output": bundle.output.to_dict(), "inference": bundle.inference.to_dict()}, indent=1))
    return 0
