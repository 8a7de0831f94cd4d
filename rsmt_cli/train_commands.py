"""The ``rsmt train`` command group: the RSMT training stages, one preset at a time or as a named recipe."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import shlex
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from model.data.location import require_data_dir

if TYPE_CHECKING:
    import torch

    from model.inference.bundle import Bundle
    from model.train.pipeline import TrainConfig
    from model.train.recipe_chains import Recipe, StageReport

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    train = subparsers.add_parser("train", help="train the RSMT model (phase, manifold, sampler, all) or the style classifier",
                                  description="Train the model's stages on a folder of BVH takes.")
    sub = train.add_subparsers(dest="train_command", required=True, metavar="STAGE")
    for stage, text in (
        ("phase", "the periodic autoencoder that labels phases"),
        ("manifold", "the motion manifold (needs the phase stage's weights in the run folder)"),
        ("sampler", "the style-conditioned sampler (needs the phase and manifold stages), then write the bundle"),
        ("all", "every stage in order, resuming where a previous run stopped, then write the bundle"),
    ):
        p = sub.add_parser(stage, help=text, description=f"Train {text}.")
        p.add_argument("--data", type=Path, help="folder of BVH takes (default: the RSMT_DATA setting)")
        add_data_arguments(p)
        p.add_argument("--out", type=Path, help="bundle folder to write when the sampler is trained")
        p.add_argument("--config", type=Path,
                       help="a complete training config JSON (e.g. a run's train_config.json); overrides --preset")
        p.add_argument("--preset", default="default",
                       help="a preset in model/train/recipes/ or its experiments/ by name (base.json with the preset's "
                            "changes): default, smoke, the shipped recipe's stages two-hour-*, cross-style-* and "
                            "control-1-one-frame, trials such as paper, ... (default: default)")
        # --run-dir: the same option under torchrun, whose own parser rejects --run as an ambiguous --run-path.
        p.add_argument("--run", "--run-dir", dest="run", type=Path,
                       help="run folder for checkpoints and stage weights (default: ~/.cache/rsmt/runs/NAME); "
                            "write --run-dir under torchrun")
        p.add_argument("--time-limit", type=float, default=0.0, metavar="S",
                       help="stop each stage after S seconds with a checkpoint; run again to resume")
        add_set_argument(p)
        p.add_argument("--threads", type=int, default=0,
                       help="torch threads (default: the config's threads, 1 in every preset; 0 there: torch's choice)")
        p.add_argument("--compile", action="store_true",
                       help="train the sampler's per-frame functions through torch.compile: about 20%% faster "
                            "sampler steps after a minute or two of compiling (needs a C++ compiler on the CPU)")
        add_device_argument(p)
        p.add_argument("--quiet", action="store_true", help="no progress bars")
        if stage == "sampler":
            p.add_argument("--from-bundle", type=Path, metavar="BUNDLE",
                           help="start from a packaged bundle (e.g. model/default_bundle) instead of a run folder's "
                                "earlier stages: its weights become the run's phase, manifold and a sampler checkpoint "
                                "at --at-step (ignored when the run folder has a sampler checkpoint: it resumes)")
            p.add_argument("--at-step", type=int, metavar="N",
                           help="with --from-bundle: the step the bundle's sampler stands for (the preset's schedule "
                                "goes on from there)")
        p.set_defaults(func=_run, stage=stage)
    _register_recipe(sub)
    from rsmt_cli import classifier_commands, judge_commands, sequence_judge_commands

    classifier_commands.register(sub)
    judge_commands.register(sub)
    sequence_judge_commands.register(sub)


def _register_recipe(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "recipe", help="a named chain of training stages, such as the shipped model's, run and packaged",
        description="Run a named recipe (model/train/recipes/chains/NAME.json): its stages in order in one run "
                    "folder, each an 'rsmt train all' or 'rsmt train sampler' with its preset, keeping each stage's "
                    "bundle in RUN/stages/LABEL; then package the last one into --out as the recipe says "
                    "(rsmt package). Prints each stage's wall time as it finishes, and the total. Resumable: run "
                    "the same command again after a stop: stages whose bundle exists are skipped, and a stage cut "
                    "short resumes from its last checkpoint in the run folder.")
    p.add_argument("name", nargs="?", metavar="NAME", help="the recipe, e.g. default-model (see --list)")
    p.add_argument("--list", action="store_true", help="list the recipes with what each is for, and stop")
    p.add_argument("--data", type=Path, help="folder of BVH takes (default: the RSMT_DATA setting)")
    add_data_arguments(p)
    p.add_argument("--run", type=Path, help="run folder of every stage (default: ~/.cache/rsmt/runs/recipe-NAME)")
    p.add_argument("--out", type=Path, help="folder of the packaged bundle")
    add_set_argument(p, "of every stage, on top of its preset and the recipe's changes")
    p.add_argument("--threads", type=int, default=0, help="torch threads (default: each preset's own setting)")
    p.add_argument("--compile", action="store_true",
                   help="train the sampler's per-frame functions through torch.compile (as rsmt train --compile)")
    p.add_argument("--holdout-style", action="append", default=[], metavar="STYLE",
                   help="leave this style out of every stage (repeatable): a model that never saw it, for scoring "
                        "unseen styles; the bundle's name gets '-without-STYLE...'")
    add_device_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run_recipe)


def add_set_argument(parser: argparse.ArgumentParser, what: str = "on top of --preset or --config") -> None:
    """``--set KEY=VALUE`` (repeatable): one training setting, dotted as in a preset file."""
    parser.add_argument("--set", dest="settings", action="append", default=[], metavar="KEY=VALUE",
                        help=f"change one training setting {what} (repeatable); the key dotted as in "
                             "model/train/recipes/base.json, the value of that setting's type, lists comma-separated: "
                             "--set sampler_stage.loop.iterations=200 --set sampler_stage.loop.restart_at=100,150")


def add_data_arguments(parser: argparse.ArgumentParser) -> None:
    """``--manifest``, ``--profile`` and ``--units``: how the takes of ``--data`` are labelled and read."""
    parser.add_argument("--manifest", type=Path, metavar="CSV",
                        help="CSV labelling the takes: columns file, style, content[, start, stop], paths relative to "
                             "it (default: labels from the file names; docs/your-rig.md)")
    parser.add_argument("--profile", metavar="FILE",
                        help="skeleton profile of the rig: a JSON file (rsmt profile guess DIR writes one) or a built-in "
                             "name (bandai-namco, 100style); replaces the preset's (default: a built-in that fits)")
    parser.add_argument("--units", metavar="U",
                        help="units of the takes: auto (read from the character's height), cm, m, mm, inch, or "
                             "centimetres per file unit such as 5.64; replaces the preset's (default: auto)")


def data_settings(args: argparse.Namespace) -> dict[str, str]:
    """The config settings that ``--profile`` and ``--units`` give (a profile file by its absolute path)."""
    from model.motion.rig_facts import parse_units
    from model.motion.skeleton import BUILTIN_PROFILES, SkeletonProfile

    out: dict[str, str] = {}
    if args.profile is not None:
        SkeletonProfile.load(args.profile)  # a bad profile fails here, before any data is read
        out["profile"] = args.profile if args.profile in BUILTIN_PROFILES else str(Path(args.profile).resolve())
    if args.units is not None:
        out["units"] = str(parse_units(args.units))
    if args.manifest is not None and not args.manifest.is_file():
        raise FileNotFoundError(f"no manifest {args.manifest}")
    return out


def add_device_argument(parser: argparse.ArgumentParser) -> None:
    """``--device auto|cpu|cuda``, shared by the training commands."""
    parser.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto",
                        help="where to train: cuda (a GPU), cpu, or auto = cuda when torch sees a GPU, else cpu "
                             "(default: auto)")


def resolve_cli_device(name: str) -> torch.device:
    """The torch device for ``--device``, announced once on stderr beside the progress bars
    (stdout ends with the JSON summary). A ValueError (e.g. cuda without a GPU) becomes main's error line."""
    import torch

    from model.train.loop import resolve_device

    device = resolve_device(name)
    gpu = f" ({torch.cuda.get_device_name(device)})" if device.type == "cuda" else ""
    print(f"training on {device}{gpu}", file=sys.stderr, flush=True)
    return device


def load_config(args: argparse.Namespace) -> TrainConfig:
    """The config of ``--config`` (a complete one), else of ``--preset``, with the ``--set`` settings."""
    from model.train.config_settings import setting_changes
    from model.train.pipeline import TrainConfig
    from model.train.presets import deep_merge, load_preset

    changes = setting_changes(args.settings, TrainConfig)
    if args.config is None:
        return load_preset(args.preset, changes=changes)
    if not args.config.is_file():
        raise FileNotFoundError(f"no training config {args.config}")
    cfg = TrainConfig.load(args.config)
    try:
        return TrainConfig.from_dict(deep_merge(cfg.to_dict(), changes))
    except TypeError as exc:
        raise ValueError(f"{args.config} with --set: not a valid training config: {exc}") from exc


def _run(args: argparse.Namespace) -> int:
    """One stage or all; under ``torchrun`` every process runs this, in one process group
    (:mod:`model.train.distributed`), and rank 0 writes the files and the summary."""
    from model.train import distributed

    device = resolve_cli_device(args.device)  # first, so a missing GPU fails before any data is read
    device = distributed.start(device)  # under torchrun: join the group (cuda: this local rank's GPU)
    try:
        return _train(args, device)
    finally:
        distributed.stop()


def _train(args: argparse.Namespace, device: torch.device) -> int:
    from model.train.pipeline import STAGES, run

    cfg = _command_config(args)
    data = require_data_dir(args.data)
    run_dir = args.run or Path.home() / ".cache" / "rsmt" / "runs" / cfg.name
    stages = STAGES if args.stage == "all" else (args.stage,)
    if "sampler" in stages and args.out is None:
        raise ValueError("training the sampler writes a bundle: pass --out BUNDLE")
    if getattr(args, "from_bundle", None) is not None:
        _seed_from_bundle(args, cfg, run_dir)
    command = "rsmt " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv else None
    bundle = run(cfg, Path(data), run_dir, stages, args.out, progress=not args.quiet, command=command, device=device,
                 compile=args.compile, manifest=args.manifest)
    return _report_training(args, stages, bundle, run_dir, device)


def _command_config(args: argparse.Namespace) -> TrainConfig:
    """The training config with the command's data settings, --threads and --time-limit (every stage's) applied."""
    cfg = load_config(args)
    for key, value in data_settings(args).items():
        setattr(cfg, key, value)
    if args.threads:
        cfg.threads = args.threads
    if args.time_limit:
        for st in (cfg.phase_stage, cfg.manifold_stage, cfg.sampler_stage):
            st.loop.time_limit_s = args.time_limit
    return cfg


def _seed_from_bundle(args: argparse.Namespace, cfg: TrainConfig, run_dir: Path) -> None:
    """Seed the run folder from --from-bundle at --at-step (rank 0 writes; every rank waits for it)."""
    from model.train import distributed
    from model.train.from_bundle import seed_run

    if args.at_step is None:
        raise ValueError("--from-bundle needs --at-step N: the step of the preset's schedule the bundle stands for")
    if distributed.is_main() and seed_run(args.from_bundle, cfg, run_dir, args.at_step):
        print(f"seeded {run_dir} from {args.from_bundle} at step {args.at_step}")
    distributed.barrier()  # the run folder is seeded before any rank reads it


def _report_training(args: argparse.Namespace, stages: tuple[str, ...], bundle: Bundle | None, run_dir: Path,
                     device: torch.device) -> int:
    """Say how the run ended (each process on stderr under torchrun; rank 0 the summary) and give its exit
    status: 3 when the sampler stopped at the time limit before writing its bundle, else 0."""
    from model.train import distributed

    stopped = "sampler" in stages and bundle is None
    if distributed.world_size() > 1:  # one line per process, on stderr: every rank trained to the end
        print(f"process {distributed.rank()} of {distributed.world_size()}: "
              f"{'stopped (time limit)' if stopped else 'trained'} {', '.join(stages)}",
              file=sys.stderr, flush=True)
    if not distributed.is_main():
        return 3 if stopped else 0
    if stopped:
        print(f"stopped before the end (time limit); run the same command again to resume from {run_dir}")
        return 3
    timings = json.loads((run_dir / "timings.json").read_text()) if (run_dir / "timings.json").is_file() else {}
    print(json.dumps({"run": str(run_dir), "bundle": str(args.out) if bundle else None,
                      "device": str(device), "timings_s": timings}, indent=1))
    return 0


def _run_recipe(args: argparse.Namespace) -> int:
    from model.train import distributed
    from model.train.recipe_chains import load_recipe, recipe_names, run_recipe

    if args.list:
        for name in recipe_names():
            print(f"{name}: {load_recipe(name).about}")
        return 0
    if args.name is None or args.out is None:
        raise ValueError("name a recipe and its bundle: rsmt train recipe NAME --out BUNDLE (--list shows the recipes)")
    recipe = load_recipe(args.name)
    if args.settings:
        from model.train.config_settings import setting_changes
        from model.train.pipeline import TrainConfig
        from model.train.presets import deep_merge

        changes = deep_merge(recipe.changes, setting_changes(args.settings, TrainConfig), new_keys=True)
        recipe = dataclasses.replace(recipe, changes=changes)
    if distributed.launched():
        raise ValueError("rsmt train recipe runs in one process; under torchrun, run its stages with rsmt train all|sampler")
    settings = data_settings(args)
    device = resolve_cli_device(args.device)
    data = require_data_dir(args.data)
    run_dir = args.run or Path.home() / ".cache" / "rsmt" / "runs" / f"recipe-{recipe.name}"
    began = time.monotonic()
    command = "rsmt " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:] else None
    held = tuple(sorted(set(args.holdout_style)))
    last = run_recipe(recipe, Path(data), run_dir, threads=args.threads, compile=args.compile, device=device,
                      progress=not args.quiet, command=command, report=_print_stage(recipe),
                      holdout_styles=held, manifest=args.manifest, data_settings=settings)
    if last is None:
        print(f"stopped before the end (time limit); run the same command again to resume from {run_dir}")
        return 3
    t0 = time.monotonic()
    package = recipe.package
    if held:
        package = dataclasses.replace(package, name=f"{package.name or recipe.name}-without-{'-'.join(held)}")
    _save_gait_limits(last, Path(data), args.manifest)  # into the last stage's bundle: the package copies them
    status = _package(package.arguments(), last, args.out)
    print(f"package: {time.monotonic() - t0:.1f} s", flush=True)
    print(f"total: {_duration(time.monotonic() - began)}", flush=True)
    return status


def _print_stage(recipe: Recipe) -> Callable[[StageReport], None]:
    def report(r: StageReport) -> None:
        what = f"stage {r.index + 1}/{len(recipe.stages)} {r.stage.label} ({recipe.stage_command(r.stage)})"
        done = "done before, skipped" if r.seconds is None else _duration(r.seconds)
        print(f"{what}: {done}; bundle {r.folder}", flush=True)

    return report


def _duration(seconds: float) -> str:
    minutes = seconds / 60
    return f"{seconds:.0f} s" + (f" ({int(minutes // 60)} h {minutes % 60:.0f} min)" if minutes >= 60 else
                                 f" ({minutes:.1f} min)" if seconds >= 60 else "")


def _save_gait_limits(stage: Path, data: Path, manifest: Path | None) -> None:
    """The capture's gait limits of the takes the recipe trained on (its train split, with the last stage's rig,
    units and held-out styles), saved in the stage's bundle, so that the packaged copy caps its root speed to
    them and tells requests out of reach (model/motion/gait_limits.py)."""
    from model.data.gait_capture import gait_limits_from_data
    from model.train.pipeline import TrainConfig

    cfg = TrainConfig.load(stage / "train_config.json")
    limits = gait_limits_from_data(data, cfg.fps, profile=cfg.profile, manifest=manifest, units=cfg.units,
                                   ratios=cfg.ratios, holdout_styles=cfg.holdout_styles)
    print(f"gait limits: {limits.save(stage)} ({len(limits.styles)} styles)", flush=True)


def _package(options: list[str], model: Path, out: Path) -> int:
    """``rsmt package --model MODEL --out OUT OPTIONS``, through that command's own parser and code."""
    from rsmt_cli import package_commands

    parser = argparse.ArgumentParser(prog="rsmt")
    package_commands.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["package", "--model", str(model), "--out", str(out), *options])
    return int(args.func(args) or 0)
