"""``rsmt train judge``: fit the style judge that ``rsmt eval --judge`` scores style with."""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from rsmt_cli.judge_training import load_training_cache, print_groups, save_judge, style_labels


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``judge`` stage to ``rsmt train``."""
    p = sub.add_parser(
        "judge", help="the style judge for evaluation: logistic regression on window statistics, unlike any critic",
        description=(
            "Fit the style judge (model/evaluation/style_judge.py): multinomial logistic regression on summary "
            "statistics of 41-pose windows (joint speeds, speeds relative to the root, spread of heights and reach, root "
            "bob; no postures, no accelerations), taken "
            "every --step frames of the train split's takes. Prints its accuracy on the val split's windows, "
            "overall, on the locomotion contents, per style and per content. Writes DIR/judge.json and "
            "DIR/weights.safetensors."))
    p.add_argument("--data", type=Path, help="folder of BVH takes (default: the RSMT_DATA setting)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="judge folder to write")
    p.add_argument("--step", type=int, default=10, help="frames between training windows (default 10)")
    p.add_argument("--l2", type=float, default=1e-3, help="L2 penalty on the weights (default 0.001)")
    p.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's choice)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=judge_command)


def judge_command(args: argparse.Namespace) -> int:
    from model.evaluation.cases import LOCOMOTION
    from model.evaluation.style_judge import accuracy_report, fit_judge, take_windows

    if args.step < 1:
        raise ValueError("--step must be at least 1")
    data, cache = load_training_cache(args)
    split = cache.split
    feats, styles, contents = take_windows(cache, split.train, args.step, progress=not args.quiet)
    skeleton = cache.skeleton(split.train[0])
    judge = fit_judge(feats, style_labels(cache, styles), cache.styles, list(skeleton.names), cache.fps,
                      skeleton.roles.root, l2=args.l2)
    train = accuracy_report(judge, feats, styles, contents, LOCOMOTION)
    vf, vs, vc = take_windows(cache, split.val, args.step, progress=not args.quiet)
    val = accuracy_report(judge, vf, vs, vc, LOCOMOTION)
    command = "rsmt train judge " + " ".join(shlex.quote(a) for a in _argv(args, data))
    save_judge(judge, args.out, command, {"data": str(data), "train_accuracy": train["accuracy"],
                                         "val_accuracy": val["accuracy"],
                                         "val_locomotion_accuracy": val["locomotion_accuracy"],
                                         "val_windows": val["windows"]}, {"train": train, "val": val})
    print(f"train windows {train['windows']}: accuracy {train['accuracy']:.4f}")
    print(f"val windows {val['windows']}: accuracy {val['accuracy']:.4f}, locomotion {val['locomotion_accuracy']:.4f} "
          f"(chance {val['chance']:.3f})")
    print_groups("val", val)
    print(f"wrote {args.out}")
    return 0


def _argv(args: argparse.Namespace, data: Path) -> list[str]:
    return ["--data", str(data), "--out", str(args.out), "--step", str(args.step), "--l2", f"{args.l2:g}"]
