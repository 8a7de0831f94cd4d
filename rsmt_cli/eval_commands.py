"""The ``rsmt eval`` command: score model bundles and baselines side by side on fixed cases of a split."""

from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path
from typing import TYPE_CHECKING

from model.data.location import find_data_dir, require_data_dir
from rsmt_cli.output_arguments import add_output_arguments, output_flags, output_overrides

if TYPE_CHECKING:
    from model.evaluation.methods import Method
    from model.evaluation.runner import EvalRun, EvalSettings
    from model.evaluation.sequence_judge import SequenceJudge
    from model.evaluation.style_judge import StyleJudge
    from model.inference.overrides import Overrides
    from model.nets.style_classifier import StyleClassifier


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "eval", help="evaluate bundles and baselines (L2P, L2Q, NPSS, foot skate, style, diversity)",
        description=(
            "Run each --model on the same deterministic cases of a split (10 context frames; gaps of 10, 20 and "
            "40 frames; on the 40 gap the target moved by d = 2 and d = -1 and the duration scaled by dt = 0.5 "
            "and 2, and on the locomotion cases the target turned by +-90 degrees and moved 1 m sideways) and "
            "print Markdown tables side by side: the locomotion cases (walk, walk turns, run) first, all "
            "contents second. Models are sent the target frame alone (--target-frames 2: with the frame before "
            "it). Scores are taken in the canonical frame of the last context frame; L2P is standardised with "
            "training-split statistics. With --out, also writes report.json, report.md, PNG plots and a contact "
            "sheet of a few transitions."))
    p.add_argument("--model", action="append", required=True, metavar="BUNDLE|interp|zerovel|gt",
                   help="a model bundle folder, or a baseline: interp, zerovel (gt: the ground truth, a sanity "
                        "check); repeat to compare")
    p.add_argument("--data", type=Path, help="folder of BVH takes (default: the RSMT_DATA setting)")
    p.add_argument("--split", default="test", choices=["train", "val", "test", "holdout"],
                   help="split to evaluate (default test; holdout: every take of the --holdout-style styles)")
    p.add_argument("--holdout-style", action="append", default=[], metavar="STYLE",
                   help="put STYLE aside from the split, as `rsmt train ... --holdout-style` does (repeatable): motion "
                        "matching and the reference statistics then use the training split such a model saw")
    p.add_argument("--clips-only", action="append", default=[], metavar="TAKE",
                   help="a take (by id, e.g. data/dataset-1_walk-left_angry_001) that gives no case but may serve as a "
                        "style clip, such as a clip a style was fine-tuned on (repeatable)")
    p.add_argument("--style-set", action="append", default=[], metavar="TAKE,TAKE,...",
                   help="1 to 5 takes of one style, by id: that style's cases are asked with their clips (the first "
                        "120 frames of each) encoded together, as POST /v1/styles encodes several motions "
                        "(repeatable, one per style)")
    p.add_argument("--classifier", type=Path, metavar="DIR",
                   help="style classifier folder (rsmt train classifier) for style accuracy and FMD")
    p.add_argument("--judge", type=Path, metavar="DIR",
                   help="style judge folder (rsmt train judge): the style accuracy of the acceptance figures")
    p.add_argument("--judge2", type=Path, metavar="DIR",
                   help="second style judge folder (rsmt train sequence-judge), reported beside the first")
    p.add_argument("--network-alone", action="store_true",
                   help="also run each bundle with steering off (--steering 0: the network alone carries the body), "
                        "reported as NAME (steering 0) beside its own settings")
    p.add_argument("--source", default="network", metavar="SOURCE[,SOURCE...]",
                   help="what makes each bundle's motion, as the service's RSMT_SOURCE: network (default), matching "
                        "(its motion database) or hybrid; several, comma-separated, run side by side in one report "
                        "(NAME (matching), ...)")
    p.add_argument("--no-motion-matching", action="store_true",
                   help="leave out the motion-matching baseline (built from the training split; run by default)")
    p.add_argument("--target-frames", type=int, default=1, choices=[1, 2],
                   help="target frames sent to bundles: 1, the target alone (what a game has; default), or 2, "
                        "with the frame before it (the target's velocity)")
    p.add_argument("--noise", action="store_true",
                   help="bundles sample their per-transition noise (a seed per case from --seed), as a request with "
                        "the API's default \"deterministic\": false does; default: no noise")
    p.add_argument("--out", type=Path, metavar="DIR", help="folder for report.json, report.md and the pictures")
    p.add_argument("--limit", type=int, metavar="N", help="evaluate at most N cases, spread evenly over the split")
    p.add_argument("--styles", nargs="+", default=[], metavar="STYLE",
                   help="only cases of these styles, e.g. a style held out of training (style clips still come from all)")
    p.add_argument("--seed", type=int, default=0, help="seed of the noisy samples (diversity, --noise; default 0)")
    p.add_argument("--diversity-cases", type=int, default=32, metavar="N",
                   help="cases used for diversity, spread evenly (default 32; 0 skips diversity)")
    p.add_argument("--diversity-samples", type=int, default=10, metavar="N",
                   help="noisy transitions per case for diversity (default 10)")
    p.add_argument("--render-cases", type=int, default=4, metavar="N", help="cases on the contact sheet (default 4)")
    p.add_argument("--batch", type=int, default=128, help="transitions generated together by a bundle (default 128)")
    p.add_argument("--exact-arrival", action="store_true",
                   help="run bundles with the engine's exact-arrival option (the last frames bend onto the target)")
    add_output_arguments(p, "each bundle")
    p.add_argument("--backend", choices=["torch", "onnxruntime"], default="torch",
                   help="what runs each bundle's per-frame graphs (default torch; onnxruntime: float32, no int8 LSTM)")
    p.add_argument("--stream-retarget", action="store_true",
                   help="also stream each bundle's locomotion cases and retarget them at frame 20 of 40 to the target "
                        "moved 1 m sideways (model/evaluation/stream_retarget.py)")
    p.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's choice)")
    p.add_argument("--json", action="store_true", help="print the JSON report instead of the Markdown tables")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=eval_command)


def eval_command(args: argparse.Namespace) -> int:
    import torch

    from model.data.preprocessed import load_motion_cache
    from model.evaluation import evaluate
    from model.evaluation.motion_matching import MotionMatchingMethod
    from model.evaluation.report import markdown
    from model.evaluation.runner import eval_split

    if args.threads:
        torch.set_num_threads(args.threads)
    if args.limit is not None and args.limit < 1:
        raise ValueError("--limit must be at least 1")
    data = require_data_dir(args.data)
    methods = _methods(args, output_overrides(args))
    classifier, judge, judge2 = _scorers(args)
    cache = load_motion_cache(Path(data), progress=not args.quiet)
    settings = _settings(args)
    if not args.no_motion_matching:
        methods.append(MotionMatchingMethod(cache, eval_split(cache, settings).train))
    run = evaluate(cache, methods, settings, classifier, _path_text(args.classifier),
                   progress=not args.quiet, judge=judge, judge_path=_path_text(args.judge),
                   judge2=judge2, judge2_path=_path_text(args.judge2))
    command = _command(args)
    run.report["command"] = command
    text = markdown(run.report, command)
    if args.stream_retarget:
        text += "\n" + _stream_retarget(run, methods, args.target_frames)
    if args.out:
        write_outputs(run, args.out, text)
    print(json.dumps(run.report, indent=1) if args.json else text)
    return 0


def _methods(args: argparse.Namespace, overrides: Overrides) -> list[Method]:
    """The --model methods (each bundle followed by its steering-0 twin with --network-alone), bundles on --backend."""
    from model.evaluation import resolve_method
    from model.evaluation.methods import BundleMethod
    from model.export.backends import with_backend

    sources = [s.strip() for s in args.source.split(",") if s.strip()]
    unknown = sorted(set(sources) - {"network", "matching", "hybrid"})
    if unknown or not sources:
        raise ValueError(f"--source takes network, matching or hybrid, comma-separated; not {args.source!r}")
    methods = [resolve_method(spec, args.batch, args.exact_arrival, overrides, source)
               for spec in args.model for source in (sources if Path(spec).is_dir() else sources[:1])]
    if args.network_alone:
        methods = _with_network_alone(methods, overrides, args.batch, args.exact_arrival)
    if args.backend != "torch" and sources != ["network"]:
        raise ValueError("--source matching or hybrid runs on the torch backend only (the ONNX graphs hold the network)")
    for method in methods:
        if isinstance(method, BundleMethod):
            with_backend(method.engine, args.backend)
    return methods


def _scorers(args: argparse.Namespace) -> tuple[StyleClassifier | None, StyleJudge | None, SequenceJudge | None]:
    """The style classifier and the two judges given (None for each one that is not)."""
    from model.evaluation.sequence_judge import SequenceJudge
    from model.evaluation.style_judge import StyleJudge
    from model.nets.style_classifier import StyleClassifier

    classifier = StyleClassifier.load(args.classifier) if args.classifier else None
    judge = StyleJudge.load(args.judge) if args.judge else None
    judge2 = SequenceJudge.load(args.judge2) if args.judge2 else None
    return classifier, judge, judge2


def _settings(args: argparse.Namespace) -> EvalSettings:
    """What to evaluate, from the command's arguments."""
    from model.evaluation import EvalSettings

    return EvalSettings(split=args.split, limit=args.limit, seed=args.seed, diversity_cases=args.diversity_cases,
                        diversity_samples=args.diversity_samples, render_cases=args.render_cases,
                        styles=tuple(args.styles), target_frames=args.target_frames, noise=args.noise,
                        holdout_styles=tuple(sorted(set(args.holdout_style))), clips_only=tuple(args.clips_only),
                        style_sets=tuple(tuple(t for t in s.split(",") if t) for s in args.style_set))


def _path_text(path: Path | None) -> str | None:
    """A scorer's folder as the report names it (None when not given)."""
    return str(path) if path else None


def _with_network_alone(methods: list[Method], overrides: Overrides, batch: int, exact_arrival: bool) -> list[Method]:
    """``methods`` with, after each bundle, the same bundle with steering off (named ``NAME (steering 0)``)."""
    from dataclasses import replace

    from model.evaluation.methods import BundleMethod

    out: list[Method] = []
    for method in methods:
        out.append(method)
        if isinstance(method, BundleMethod):
            out.append(BundleMethod(method.path, batch, name=f"{method.name} (steering 0)", exact_arrival=exact_arrival,
                                    source=method.source,
                                    overrides=replace(overrides, steering=0)))
    return out


def _stream_retarget(run: EvalRun, methods: list[Method], target_frames: int) -> str:
    """Each bundle's stream-retarget figures (added to the report) as a Markdown table."""
    from model.evaluation.methods import BundleMethod
    from model.evaluation.stream_retarget import RetargetSettings, retarget_report

    if run.loco is None:
        return "No locomotion cases: no stream-retarget figures.\n"
    exact = " (exact arrival)" if any(getattr(m, "exact_arrival", False) for m in methods) else ""
    lines = [f"### Stream retargeted at frame 20 of 40 to the target moved 1 m sideways (locomotion){exact}", "",
             "| method | arrival cm (mean / median / p90) | sent from the start | max root speed cm/s (mean / worst) |",
             "|---|---|---|---|"]
    for method, (name, entry) in zip(methods, run.report["methods"].items(), strict=True):
        if not isinstance(method, BundleMethod):
            continue
        r = retarget_report(method, run.loco, RetargetSettings(target_frames=target_frames))
        entry["stream_retarget"] = r
        a, s = r["retargeted"], r["from_start"]
        lines.append(f"| {name} | {a['arrival_cm']} / {a['arrival_cm_median']} / {a['arrival_cm_p90']} | "
                     f"{s['arrival_cm']} | {a['max_root_speed_cm_s']} / {a['max_root_speed_cm_s_worst']} |")
    return "\n".join(lines) + "\n"


def _command(args: argparse.Namespace) -> str:
    """The command line that reproduces this run (from the parsed arguments)."""
    parts = ["rsmt", "eval"]
    for m in args.model:
        parts += ["--model", str(m)]
    parts += ["--data", str(args.data or find_data_dir()), "--split", args.split]
    for flag, optional in (("--classifier", args.classifier), ("--judge", args.judge), ("--judge2", args.judge2),
                           ("--out", args.out),
                           ("--limit", args.limit)):
        if optional is not None:
            parts += [flag, str(optional)]
    parts += ["--target-frames", str(args.target_frames)]
    if args.styles:
        parts += ["--styles", *args.styles]
    parts += [part for style in args.holdout_style for part in ("--holdout-style", style)]
    parts += [part for take in args.clips_only for part in ("--clips-only", take)]
    parts += [part for takes in args.style_set for part in ("--style-set", takes)]
    parts += ["--seed", str(args.seed)]
    parts += [flag for flag, on in (("--noise", args.noise), ("--exact-arrival", args.exact_arrival),
                                    ("--no-motion-matching", args.no_motion_matching),
                                    ("--stream-retarget", args.stream_retarget)) if on]
    parts += output_flags(args)
    for flag, value, default in (("--diversity-cases", args.diversity_cases, 32),
                                 ("--diversity-samples", args.diversity_samples, 10)):
        if value != default:
            parts += [flag, str(value)]
    return " ".join(shlex.quote(p) for p in parts)


def write_outputs(run: EvalRun, folder: Path, text: str) -> list[Path]:
    """report.json, report.md, reference_stats.json, metrics_over_gap.png, controls.png and contact sheets
    (contact_sheet.png: the 40-frame gap; contact_sheet_d-1.png: its target moved behind, d = -1)."""
    from model.evaluation.cases import variant
    from model.evaluation.plots import contact_sheet, plot_controls, plot_gap_metrics
    from model.evaluation.report import write_report

    folder = Path(folder)
    paths = write_report(folder, run.report, text)
    stats = folder / "reference_stats.json"
    stats.write_text(json.dumps(run.stats.to_dict()))
    paths.append(stats)
    paths.append(plot_gap_metrics(run.report, folder / "metrics_over_gap.png"))
    paths.append(plot_controls(run.report, folder / "controls.png"))
    cases = run.cases
    idx = run.render_index
    if idx:
        labels = [f"{c.style}, {c.content}\n{Path(c.id.split('@')[0]).name} @ {c.start}"
                  for c in (cases.cases[i] for i in idx)]
        for name, file in (("gap40", "contact_sheet.png"), ("gap40-d-1", "contact_sheet_d-1.png")):
            v = variant(name)
            targets = cases.frame.positions_to(cases.target_positions(v).unsqueeze(1))[idx, 0]
            sheet = contact_sheet(run.render, targets, labels, cases.skeleton, folder / file, variant=name)
            if sheet is not None:
                paths.append(sheet)
    return paths
