"""The ``rsmt finetune-style`` command: adapt a bundle to a new style from a few clips."""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path
from typing import Any

from rsmt_cli.train_commands import add_device_argument, resolve_cli_device

MIN_CLIPS, MAX_CLIPS = 1, 5


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "finetune-style", help="adapt a trained bundle to a style it never saw, from a few BVH clips",
        description="Train a bundle on a few clips of a new style (mirrored and time-rescaled copies added) and write "
                    "the adapted bundle with the new style built in (style id builtin:NAME, served like the others by "
                    "rsmt serve --models DIR). With --data, the data's styles are encoded by the adapted weights and "
                    "built in too; with --rehearsal as well, every step also trains on the styles the bundle was trained "
                    "on (the data's train split, without the styles its training held out).")
    p.add_argument("--model", type=Path, required=True, help="the trained bundle to adapt")
    p.add_argument("--clips", type=Path, nargs="+", required=True, metavar="BVH",
                   help=f"{MIN_CLIPS} to {MAX_CLIPS} clips of the new style (3 is the measured case)")
    p.add_argument("--name", required=True, help="name of the new style (its built-in style id is builtin:NAME)")
    p.add_argument("--data", type=Path, metavar="DATA",
                   help="the bundle's training data: build in one walking clip per style of its train split, encoded "
                        "by the adapted weights (a style of the same name as --name is left to the new clips); what "
                        "--rehearsal trains on")
    p.add_argument("--scope", choices=("network", "style"), default="network",
                   help="what learns: network (default; every sampler weight but the manifold decoder) or style (the "
                        "paper's: the style encoder and the FiLM/attention layers)")
    p.add_argument("--rehearsal", action=argparse.BooleanOptionalAction, default=False,
                   help="with --data, every step also trains on windows of the styles the bundle knows (default: off; "
                        "on validation it did not keep them and learned the new style less; see the model card)")
    p.add_argument("--out", type=Path, required=True, help="folder of the adapted bundle")
    p.add_argument("--iterations", type=int, default=300, help="optimiser steps (default 300)")
    p.add_argument("--run", type=Path, help="folder for checkpoints, resumed by the same command (default: "
                                            "OUT/../.finetune-NAME, where a run of other settings is replaced)")
    p.add_argument("--threads", type=int, default=0, help="torch threads")
    add_device_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    import torch

    from model.inference.bundle import Bundle
    from model.inference.bundle_styles import check_name
    from model.inference.engine import Engine
    from model.inference.style_packing import write_builtin_styles
    from model.motion.bvh_clip import load_clip
    from model.train.finetune import FinetuneConfig, finetune_style
    from model.train.finetune_data import rehearsal_motion

    if not MIN_CLIPS <= len(args.clips) <= MAX_CLIPS:
        raise ValueError(f"--clips takes {MIN_CLIPS} to {MAX_CLIPS} clips of the new style; got {len(args.clips)}")
    check_name(args.name)
    if args.rehearsal and args.data is None:
        raise ValueError("--rehearsal trains on the bundle's training data: give it with --data DATA")
    device = resolve_cli_device(args.device)  # first, so a missing GPU fails before anything is loaded
    if args.threads:
        torch.set_num_threads(args.threads)
    bundle = Bundle.load(args.model)
    engine = Engine(bundle)
    clips = [engine.conform(load_clip(path), str(path)) for path in args.clips]
    base_styles = _data_styles(args.data, bundle, args.name) if args.data is not None else []  # before the long part
    cfg = FinetuneConfig.for_scope(args.scope)
    cfg.loop.iterations = args.iterations
    cfg.loop.epoch_iterations = max(1, min(cfg.loop.epoch_iterations, args.iterations))
    run = args.run or args.out.parent / f".finetune-{args.name}"
    claim_run_folder(run, {"model": str(args.model.resolve()), "version": bundle.version, "name": args.name,
                           "clips": [str(c.resolve()) for c in args.clips], "scope": args.scope,
                           "iterations": args.iterations, "rehearsal": args.rehearsal}, replace=args.run is None)
    rehearsal = rehearsal_motion(args.data, bundle, args.model, args.name, progress=not args.quiet) if args.rehearsal else None
    tuned, result = finetune_style(bundle, clips, args.name, cfg, run, progress=not args.quiet, device=device,
                                   rehearsal=rehearsal)
    if not result.finished:
        print(f"stopped early; run again to resume from {run}")
        return 3
    tuned.styles = {}  # the base's codes belong to the weights before fine-tuning: written again below
    tuned.save(args.out)
    _, styles = write_builtin_styles(args.out, [*base_styles, _new_style(clips, args.clips, args.name, bundle)])
    print(json.dumps({"bundle": str(args.out), "device": str(device), "seconds": round(result.seconds, 1),
                      "history": result.history[-1:], "styles": [f"builtin:{s.name}" for s in styles]}, indent=1))
    print(f"fine-tuning changed weights every style shares: the known styles are weaker in this bundle than in "
          f"{args.model}; serve the two side by side (docs/service.md, built-in styles)", file=sys.stderr)
    if args.data is None:
        print(f"only builtin:{args.name} is built in: the model's other built-in styles were encoded by the weights "
              "before fine-tuning; give --data DATA to encode the data's styles with the adapted ones", file=sys.stderr)
    return 0


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


def _data_styles(data: Path, bundle: Any, name: str) -> list:
    from model.data.style_picks import pick_style_clips

    return [s for s in pick_style_clips(data, bundle.skeleton, bundle.config.fps) if s.name != name]
