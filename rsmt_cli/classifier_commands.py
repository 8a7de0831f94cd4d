"""``rsmt train classifier``: train the style classifier used by ``rsmt eval`` for style accuracy and FMD."""

from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path

from model.data.location import find_data_dir
from rsmt_cli.judge_training import load_training_cache

# model.nets.style_classifier.INPUTS, repeated here so that building the parser does not import torch
# (tests/cli/test_startup.py checks that the two agree).
INPUTS = ("pose", "motion", "deviation", "velocity", "dynamics", "acceleration")


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``classifier`` stage to ``rsmt train``."""
    p = sub.add_parser(
        "classifier", help="the style classifier for evaluation (style accuracy, FMD)",
        description=(
            "Train a small temporal CNN that recognises the style of 40-frame windows of motion (each frame in its "
            "own facing frame), on the train split, keeping the epoch with the best validation accuracy. Prints "
            "the accuracy on the test split's real windows per style and per content, and the accuracy it gives "
            "interpolated transitions (near chance means it reads motion, not posture). Writes DIR/config.json "
            "and DIR/weights.safetensors."))
    p.add_argument("--data", type=Path, help="folder of BVH takes (default: the RSMT_DATA setting)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="classifier folder to write")
    p.add_argument("--holdout-style", action="append", default=[], metavar="S",
                   help="hold a style out of the split and of the classes (repeatable), as for a few-shot model")
    p.add_argument("--inputs", default="acceleration", choices=INPUTS,
                   help="what the classifier sees (default acceleration; see model/nets/style_classifier.py)")
    p.add_argument("--epochs", type=int, default=8, help="epochs (default 8)")
    p.add_argument("--iterations", type=int, default=150, help="batches per epoch (default 150)")
    p.add_argument("--batch", type=int, default=128, help="windows per batch (default 128)")
    p.add_argument("--step", type=int, default=5, help="frames between training windows (default 5)")
    p.add_argument("--no-mirror", action="store_true", help="do not add left/right mirrored training takes")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=classifier_command)


def classifier_command(args: argparse.Namespace) -> int:
    from model.nets.style_classifier import StyleClassifierConfig
    from model.train.classifier_stage import TrainSettings, build_windows, check_classifier, format_check, train_classifier

    data, cache = load_training_cache(args)
    progress = not args.quiet
    unknown = [s for s in args.holdout_style if s not in cache.styles]
    if unknown:
        raise ValueError(f"unknown style(s) {', '.join(unknown)}; the data has {', '.join(cache.styles)}")
    split = cache.make_split(holdout_styles=args.holdout_style) if args.holdout_style else cache.split
    styles = [s for s in cache.styles if s not in args.holdout_style]
    config = StyleClassifierConfig(styles=styles, joints=cache.skeleton(split.train[0]).num_joints, inputs=args.inputs)
    settings = TrainSettings(epochs=args.epochs, iterations=args.iterations, batch=args.batch, step=args.step,
                             mirror=not args.no_mirror, seed=args.seed)
    print(f"styles: {', '.join(styles)}; inputs: {args.inputs}; splits: {split.sizes()}", flush=True)
    train = build_windows(cache, split.train, config.window, settings.step, settings.mirror, styles, progress, "train windows")
    val = build_windows(cache, split.val, config.window, settings.eval_step, False, styles, progress, "val windows")
    print(f"{len(train)} training windows ({int(train.mirrored.sum())} mirrored), {len(val)} validation windows", flush=True)
    result = train_classifier(train, val, config, settings, progress, report=lambda line: print(line, flush=True))
    print(f"best epoch {result.best_epoch} (validation accuracy "
          f"{result.history[result.best_epoch - 1].get('val_accuracy', float('nan')):.3f}), {result.seconds:.0f} s", flush=True)
    test = check_classifier(result.model, cache, split.test, settings.eval_step)
    print(format_check(test, "test split"), flush=True)
    command = "rsmt train classifier " + " ".join(shlex.quote(a) for a in _argv(args))
    record = {
        "command": command,
        "data": str(data),
        "cache": cache.key,
        "license": "CC BY-NC 4.0 when trained on the Bandai-Namco data (inherits the training data's licence)",
        "holdout_styles": list(args.holdout_style),
        "split_sizes": split.sizes(),
        "settings": vars(settings),
        "training_windows": len(train),
        "validation_windows": len(val),
        "history": result.history,
        "best_epoch": result.best_epoch,
        "seconds": round(result.seconds, 1),
        "test": test,
    }
    result.model.save(args.out, record)
    print(json.dumps({"classifier": str(args.out), "test_accuracy": test["accuracy"],
                      "interpolation_accuracy": test["interpolation"]["accuracy"]}), flush=True)
    return 0


def _argv(args: argparse.Namespace) -> list[str]:
    out = ["--data", str(args.data or find_data_dir()), "--out", str(args.out)]
    for s in args.holdout_style:
        out += ["--holdout-style", s]
    out += ["--inputs", args.inputs, "--epochs", str(args.epochs), "--iterations", str(args.iterations),
            "--seed", str(args.seed)]
    if args.no_mirror:
        out.append("--no-mirror")
    return out
