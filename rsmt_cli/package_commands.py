"""The ``rsmt package`` command: a copy of a trained bundle made ready to ship; and ``rsmt bundle add-styles``.

Training writes float32 weights and the default output settings; the shipped default model is
float16 with its output steps and int8 LSTM cell switched on in ``config.json``. This command
does those steps, so a training recipe ends in a command rather than hand edits. ``--styles DIR``
stores built-in style clips in the copy (``styles/``, served as ``builtin:NAME``).

``rsmt bundle add-styles BUNDLE --from DIR | --from-data DATA`` writes (replaces) only a bundle's
``styles/`` folder, in place: its weights and config stay as they are. ``--from-data`` picks one
train-split walking clip per style of a dataset (:mod:`model.data.style_picks`); this is how the
default bundle's built-in styles are made::

    rsmt bundle add-styles model/default_bundle --from-data "$RSMT_DATA"
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
from pathlib import Path
from typing import Any

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
    p.add_argument("--styles", type=Path, metavar="DIR",
                   help="built-in style clips to store in the copy: one BVH per style (the file stem is the name) "
                        "or one folder per style (its first BVH); served as style ids builtin:NAME")
    add_output_arguments(p, "the bundle")
    p.set_defaults(func=_run)

    b = subparsers.add_parser("bundle", help="edit a bundle's built-in styles in place (weights untouched)")
    bsub = b.add_subparsers(dest="bundle_command", required=True, metavar="ACTION")
    a = bsub.add_parser("add-styles", help="write the bundle's styles/ folder (built-in styles, builtin:NAME)",
                        description="Replace BUNDLE/styles/ with the given clips; config.json and the weights are "
                                    "not touched, so the model's version and every style id stay the same.")
    a.add_argument("bundle", type=Path, metavar="BUNDLE")
    src = a.add_mutually_exclusive_group(required=True)
    src.add_argument("--from", dest="source", type=Path, metavar="DIR",
                     help="one BVH per style (file stem = name) or one folder per style")
    src.add_argument("--from-data", type=Path, metavar="DATA",
                     help="a motion dataset: one walking clip per style from its train split")
    a.add_argument("--frames", type=int, default=180, help="clip length with --from-data (default 180)")
    a.set_defaults(func=_add_styles)


def _run(args: argparse.Namespace) -> int:
    from model.inference.bundle import Bundle

    if args.out.resolve() == args.model.resolve():
        raise ValueError("--out must not be the --model folder")
    overrides = output_overrides(args)  # checked before anything is read or written
    bundle = Bundle.load(args.model)
    if args.styles is not None:
        bundle.styles = _read_styles(args.styles, bundle)
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
                      "output": bundle.output.to_dict(), "inference": bundle.inference.to_dict(),
                      "styles": sorted(bundle.styles)}, indent=1))
    return 0


def _read_styles(folder: Path, bundle: Any) -> dict[str, Any]:
    from model.inference.bundle_styles import styles_from_folder

    styles = styles_from_folder(folder, bundle.skeleton, bundle.config.fps)
    lo, hi = bundle.config.style_frames_min, bundle.config.style_frames_max
    for s in styles:
        if not lo <= s.frames <= hi:
            raise ValueError(f"style {s.name!r} ({s.source}) has {s.frames} frames at {bundle.config.fps:g} fps; a style "
                             f"clip of this model needs {lo} to {hi}: cut the file first")
    return {s.name: s for s in styles}


def _add_styles(args: argparse.Namespace) -> int:
    from model.data.style_picks import pick_style_clips
    from model.inference.bundle import Bundle, BundleError
    from model.inference.bundle_styles import save_styles

    bundle = Bundle.load(args.bundle)  # checks the folder is a bundle, and gives its rig and fps
    if args.source is not None:
        styles = list(_read_styles(args.source, bundle).values())
    else:
        lo, hi = bundle.config.style_frames_min, bundle.config.style_frames_max
        if not lo <= args.frames <= hi:
            raise ValueError(f"--frames must be between {lo} and {hi} (the model's style clip lengths)")
        styles = pick_style_clips(args.from_data, bundle.skeleton, bundle.config.fps, frames=args.frames)
    folder = save_styles(args.bundle, styles, bundle.skeleton, bundle.config.fps)
    try:
        Bundle.load(args.bundle)
    except BundleError as exc:  # what was written must load
        raise ValueError(str(exc)) from exc
    print(json.dumps({"bundle": str(args.bundle), "styles_folder": str(folder), "version": bundle.version,
                      "styles": [{"style_id": f"builtin:{s.name}", "frames": s.frames, "source": s.source}
                                 for s in styles]}, indent=1))
    return 0
