"""The ``rsmt finetune-style`` command: teach a bundle a new style from a few clips, as a style adapter."""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from rsmt_cli.train_commands import add_device_argument, resolve_cli_device

MIN_CLIPS, MAX_CLIPS = 1, 5
_STARTED = time.perf_counter()  # about when the command started: this module is imported before torch is


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "finetune-style", help="teach a trained bundle a style it never saw, from a few BVH clips",
        description="Train on a few clips of a new style (mirrored and time-rescaled copies added) and write the bundle "
                    "with the new style built in (style id builtin:NAME, served like the others by rsmt serve --models "
                    "DIR). The tuned weights are stored beside the bundle's own as a style adapter: the new style runs "
                    "on them, every other style on the bundle's weights, unchanged.")
    p.add_argument("--model", type=Path, required=True, help="the trained bundle to teach")
    p.add_argument("--clips", type=Path, nargs="+", required=True, metavar="BVH",
                   help=f"{MIN_CLIPS} to {MAX_CLIPS} clips of the new style (3 is the measured case)")
    p.add_argument("--name", required=True, help="name of the new style (its built-in style id is builtin:NAME)")
    p.add_argument("--scope", choices=("network", "style"), default="network",
                   help="what learns: network (default; every sampler weight but the manifold decoder) or style (the "
                        "paper's: the style encoder and the FiLM/attention layers)")
    p.add_argument("--out", type=Path, required=True,
                   help="folder of the bundle with the new style: a new or empty folder (the bundle is copied there), "
                        "or the --model folder itself to add the style in place")
    p.add_argument("--iterations", type=int, help="optimiser steps (default: 400 for --scope network, 300 for style)")
    p.add_argument("--blend", type=float, metavar="A",
                   help="keep A x the tuned weights + (1 - A) x the bundle's, in (0, 1] (default: 0.5 for --scope "
                        "network, chosen on validation: closer to the captured motion, less of the new style; 1 keeps "
                        "the tuned weights as they are)")
    p.add_argument("--run", type=Path, help="folder for checkpoints, resumed by the same command (default: "
                                            "OUT/../.finetune-NAME, where a run of other settings is replaced)")
    p.add_argument("--threads", type=int, default=0, help="torch threads")
    add_device_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)


def _check_paths(args: argparse.Namespace) -> None:
    """The clip files and the bundle folder, before anything is loaded."""
    for clip in args.clips:
        if not clip.is_file():
            raise FileNotFoundError(f"--clips {clip}: no such file")
    if len({c.resolve() for c in args.clips}) < len(args.clips):
        raise ValueError("--clips names the same file twice: give different clips of the new style")
    if not args.model.is_dir():
        raise FileNotFoundError(f"--model {args.model}: no such folder (a bundle folder, e.g. model/default_bundle)")
    if not (args.model / "config.json").is_file():
        raise ValueError(f"--model {args.model} is not a model bundle: it has no config.json")


def _check_arguments(args: argparse.Namespace) -> bool:
    """The command line's own checks, before torch is imported; whether --out is the --model folder itself."""
    from model.inference.bundle_styles import check_name

    if not MIN_CLIPS <= len(args.clips) <= MAX_CLIPS:
        raise ValueError(f"--clips takes {MIN_CLIPS} to {MAX_CLIPS} clips of the new style; got {len(args.clips)}")
    check_name(args.name)
    if args.iterations is not None and args.iterations < 1:
        raise ValueError(f"--iterations must be at least 1; got {args.iterations}")
    if args.blend is not None and not 0.0 < args.blend <= 1.0:
        raise ValueError(f"--blend must be in (0, 1]; got {args.blend}")
    in_place: bool = args.out.resolve() == args.model.resolve()
    if not in_place and args.out.exists() and (not args.out.is_dir() or any(args.out.iterdir())):
        raise ValueError(f"--out {args.out} is not empty: give a new folder, or --out {args.model} to add the style to "
                         "the bundle in place")
    return in_place


def _config(args: argparse.Namespace) -> Any:
    """The fine-tuning settings of --scope, with --iterations and --blend where given."""
    from model.train.finetune import FinetuneConfig

    cfg = FinetuneConfig.for_scope(args.scope)
    if args.iterations is not None:
        cfg.loop.iterations = args.iterations
    if args.blend is not None:  # applied to the trained weights: the run folder's checkpoints do not depend on it
        cfg.blend = args.blend
    cfg.loop.epoch_iterations = cfg.loop.iterations  # one validation, at the end (it never changes the steps)
    return cfg


def _run(args: argparse.Namespace) -> int:
    in_place = _check_arguments(args)
    import torch

    from model.inference.bundle import Bundle
    from model.inference.engine import Engine
    from model.inference.style_packing import write_adapter
    from model.motion.bvh_clip import load_clip
    from model.train.finetune import check_clips, finetune_style

    device = resolve_cli_device(args.device)  # first, so a missing GPU fails before anything is loaded
    _check_paths(args)
    if args.threads:
        torch.set_num_threads(args.threads)
    bundle = Bundle.load(args.model)
    if args.name in bundle.styles:
        raise ValueError(f"{args.model} already has a built-in style {args.name!r}: pick another --name")
    engine = Engine(bundle)
    clips = [engine.conform(load_clip(path), str(path)) for path in args.clips]
    cfg = _config(args)
    check_clips(bundle, clips, cfg)  # before the long part, and before a run folder is made
    style_clip = _new_style(clips, args.clips, args.name, bundle)
    loaded = time.perf_counter()
    run = args.run or args.out.parent / f".finetune-{args.name}"
    claim_run_folder(run, {"model": str(args.model.resolve()), "version": bundle.version, "name": args.name,
                           "clips": [str(c.resolve()) for c in args.clips], "scope": args.scope,
                           "iterations": cfg.loop.iterations}, replace=args.run is None)
    adapter, result = finetune_style(bundle, clips, args.name, cfg, run, progress=not args.quiet, device=device)
    tuned = time.perf_counter()
    if not result.finished:
        print(f"stopped early; run again to resume from {run}")
        return 3
    if not in_place:
        shutil.copytree(args.model, args.out, dirs_exist_ok=True)  # the bundle as it is, byte for byte
    write_adapter(args.out, adapter, style_clip)
    styles = sorted(Bundle.load(args.out).styles)
    done = time.perf_counter()
    timings = {"startup": loaded - _STARTED, "preparing": tuned - loaded - result.seconds, "training": result.seconds,
               "saving": done - tuned, "total": done - _STARTED}
    print(json.dumps({"bundle": str(args.out), "device": str(device), "seconds": round(result.seconds, 1),
                      "timings_s": {k: round(v, 1) for k, v in timings.items()}, "cpu_s": round(_cpu_seconds(), 1),
                      "threads": torch.get_num_threads(), "load_average": _load_average(),
                      "history": result.history[-1:], "adapter_mb": round(adapter.nbytes / 2**20, 2),
                      "styles": [f"builtin:{s}" for s in styles]}, indent=1))
    return 0


def _cpu_seconds() -> float:
    """This process's CPU time so far, every thread's (beside the wall time: on a shared machine, the work)."""
    use = resource.getrusage(resource.RUSAGE_SELF)
    return use.ru_utime + use.ru_stime


def _load_average() -> float | None:
    """The machine's 1-minute load average (how shared it was), where the system tells it."""
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):
        return None


def claim_run_folder(run: Path, request: dict[str, Any], replace: bool = False) -> None:
    """Resume only the same run: a run folder (checkpoints) holding another request is never mixed in; it is
    refused, or with ``replace`` (the default folder, ours) started afresh."""
    marker = run / "request.json"
    if marker.is_file():
        held = json.loads(marker.read_text())
        if held != request:
            changed = sorted(k for k in {*held, *request} if held.get(k) != request.get(k))
            if not replace:
                raise ValueError(f"{run} holds a fine-tuning run with other settings ({', '.join(changed)}): remove "
                                 "it, or give another --run folder")
            print(f"{run}: a run with other settings ({', '.join(changed)}) is replaced", file=sys.stderr)
            shutil.rmtree(run)
    elif run.is_dir() and any(run.iterdir()):
        if not replace:
            raise ValueError(f"{run} is not empty and holds no fine-tuning request: remove it, or give another --run "
                             "folder")
        print(f"{run}: an earlier run without a request is replaced", file=sys.stderr)
        shutil.rmtree(run)
    run.mkdir(parents=True, exist_ok=True)
    marker.write_text(json.dumps(request, indent=1))


def _new_style(clips: list, paths: list[Path], name: str, bundle: Any) -> Any:
    """The new style's built-in clip: the middle of the longest clip, at most the model's longest style clip."""
    from model.inference.bundle_styles import StyleClip

    i = max(range(len(clips)), key=lambda k: clips[k].num_frames)
    clip, c = clips[i], bundle.config
    frames = min(clip.num_frames, c.style_frames_max)
    if frames < c.style_frames_min:
        raise ValueError(f"{paths[i]}: {clip.num_frames} frames; a style clip of this model needs at least "
                         f"{c.style_frames_min} at {c.fps:g} fps")
    start = (clip.num_frames - frames) // 2
    return StyleClip(name, clip.window(start, start + frames),
                     f"{paths[i].name} frames {start}-{start + frames} at {c.fps:g} fps (fine-tuning clip)")
