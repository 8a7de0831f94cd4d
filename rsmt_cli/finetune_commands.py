"""The ``rsmt finetune-style`` command: adapt a bundle to a new style from a few clips."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rsmt_cli.train_commands import add_device_argument, resolve_cli_device


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "finetune-style", help="adapt a trained bundle to a style it never saw, from a few BVH clips",
        description="Train only the style encoder and the FiLM/attention linear layers on a few clips of a new "
                    "style (mirrored and time-rescaled copies added), and write the adapted bundle.")
    p.add_argument("--model", type=Path, required=True, help="the trained bundle to adapt")
    p.add_argument("--clips", type=Path, nargs="+", required=True, metavar="BVH", help="clips of the new style")
    p.add_argument("--name", required=True, help="name of the new style")
    p.add_argument("--out", type=Path, required=True, help="folder of the adapted bundle")
    p.add_argument("--iterations", type=int, default=300, help="optimiser steps (default 300)")
    p.add_argument("--run", type=Path, help="folder for checkpoints (default: OUT/../.finetune-NAME)")
    p.add_argument("--threads", type=int, default=0, help="torch threads")
    add_device_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    import torch

    from model.inference.bundle import Bundle
    from model.inference.engine import Engine
    from model.motion.bvh_clip import load_clip
    from model.train.finetune import FinetuneConfig, finetune_style

    device = resolve_cli_device(args.device)  # first, so a missing GPU fails before anything is loaded
    if args.threads:
        torch.set_num_threads(args.threads)
    bundle = Bundle.load(args.model)
    engine = Engine(bundle)
    clips = [engine.conform(load_clip(path), str(path)) for path in args.clips]
    cfg = FinetuneConfig()
    cfg.loop.iterations = args.iterations
    cfg.loop.epoch_iterations = max(1, min(cfg.loop.epoch_iterations, args.iterations))
    run = args.run or args.out.parent / f".finetune-{args.name}"
    tuned, result = finetune_style(bundle, clips, args.name, cfg, run, progress=not args.quiet, device=device)
    if not result.finished:
        print(f"stopped early; run again to resume from {run}")
        return 3
    tuned.save(args.out)
    print(json.dumps({"bundle": str(args.out), "device": str(device), "seconds": round(result.seconds, 1),
                      "history": result.history[-1:]}, indent=1))
    return 0
