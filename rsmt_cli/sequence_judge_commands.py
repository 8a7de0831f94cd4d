"""``rsmt train sequence-judge``: train the second style judge (a temporal network) that ``rsmt eval --judge2`` reads."""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from rsmt_cli.judge_training import load_training_cache, print_groups, save_judge, style_labels


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``sequence-judge`` stage to ``rsmt train``."""
    p = sub.add_parser(
        "sequence-judge", help="the second style judge for evaluation: a temporal network over joint-distance rates",
        description=(
            "Train the sequence judge (model/evaluation/sequence_judge.py): a dilated temporal convolution over "
            "per-frame rates of change of key-joint distances, joint speeds relative to the root and the root's speed, "
            "on 41-pose windows every --step frames of the train split (every data folder given, backward takes "
            "included), each style and within it each content drawn equally often, beside windows of the same takes with "
            "their in-betweens interpolated that it is asked to read as no style (so style is read from the frames "
            "between two poses). Prints its accuracy on the --report-split windows: overall, "
            "per style, per content (walk-back: the real backward windows) and on interpolated windows (which should "
            "read near chance). About 14 CPU minutes at the defaults on both Bandai-Namco sets. Writes DIR/sequence_judge.json, "
            "DIR/weights.safetensors and DIR/training.json."))
    p.add_argument("--data", type=Path, help="folder(s) of BVH takes, ':'-separated (default: the RSMT_DATA setting)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="judge folder to write")
    p.add_argument("--step", type=int, default=10, help="frames between training windows (default 10)")
    p.add_argument("--steps", type=int, default=1500, help="optimiser steps (default 1500)")
    p.add_argument("--batch", type=int, default=256, help="windows per step (default 256)")
    p.add_argument("--interpolated-share", type=float, default=0.25,
                   help="interpolated windows per step as a share of --batch, asked to read as no style (default 0.25; "
                        "0: none)")
    p.add_argument("--reversed-share", type=float, default=0.0,
                   help="share of the real windows of each step played backwards in time, with their own style "
                        "(default 0: none; 0.25 measured no better on val)")
    p.add_argument("--style-only", action="store_true",
                   help="draw each style equally often but not each content within it (the first judge's draw)")
    p.add_argument("--report-split", default="val", choices=["val", "test"], help="split the accuracy is reported on")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's choice)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=sequence_judge_command)


def sequence_judge_command(args: argparse.Namespace) -> int:
    from model.evaluation.judge_windows import judge_report, real_windows
    from model.evaluation.sequence_judge import JudgeTraining, train_sequence_judge

    if args.step < 1 or args.steps < 1:
        raise ValueError("--step and --steps must be at least 1")
    data, cache = load_training_cache(args)
    split = cache.split
    windows, styles, contents = real_windows(cache, split.train, args.step)
    interpolated = real_windows(cache, split.train, args.step * 2, interpolated=True)[0] if args.interpolated_share else None
    skeleton = cache.skeleton(split.train[0])
    judge = train_sequence_judge(windows, style_labels(cache, styles), cache.styles, skeleton, cache.fps,
                                 JudgeTraining(steps=args.steps, batch=args.batch, seed=args.seed,
                                               interpolated_share=args.interpolated_share,
                                               reversed_share=args.reversed_share),
                                 contents=None if args.style_only else contents, interpolated=interpolated)
    report = judge_report(judge, cache, split[args.report_split], args.step)
    command = "rsmt train sequence-judge " + " ".join(shlex.quote(a) for a in [
        "--data", str(data), "--out", str(args.out), "--step", str(args.step), "--steps", str(args.steps),
        "--batch", str(args.batch), "--interpolated-share", str(args.interpolated_share),
        "--reversed-share", str(args.reversed_share),
        *(["--style-only"] if args.style_only else []), "--report-split", args.report_split, "--seed", str(args.seed)])
    save_judge(judge, args.out, command, {"data": str(data), "report_split": args.report_split,
                                         "accuracy": report["accuracy"],
                                         "interpolated_accuracy": report["interpolated_accuracy"],
                                         "backward_accuracy": report["per_content"].get("walk-back")},
               {args.report_split: report})
    print(f"trained on {judge.info['train_windows']} windows in {judge.info['train_seconds']} s")
    print(f"{args.report_split} windows {report['windows']}: real {report['accuracy']:.4f}, interpolated "
          f"{report['interpolated_accuracy']:.4f} (chance {report['chance']:.3f})")
    print_groups(args.report_split, report)
    print(f"wrote {args.out}")
    return 0
