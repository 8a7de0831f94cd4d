"""The ``rsmt package`` command: a copy of a trained bundle made ready to ship; and ``rsmt bundle add-styles``.

Training writes float32 weights and the default output settings; the shipped default model is
float16 with its output steps and int8 LSTM cell switched on in ``config.json``. This command
does those steps, so a training recipe ends in a command rather than hand edits. ``--styles DIR``
encodes one clip per style with the copy's own weights and stores the codes (``styles/``, served as
``builtin:NAME``; no motion is stored, :mod:`model.inference.style_packing`).

``rsmt bundle add-styles BUNDLE --from DIR | --from-data DATA`` writes (replaces) only a bundle's
``styles/`` folder, in place: its weights and config stay as they are. ``--from-data`` picks one
train-split walking clip per style of a dataset (:mod:`model.data.style_picks`); this is how the
default bundle's built-in styles are made (and remade after its weights change)::

    rsmt bundle add-styles model/default_bundle --from-data "$RSMT_DATA"

``rsmt bundle gait-limits BUNDLE --from-data DATA`` measures the capture's speed and hips height limits
per style on the data's train split (:mod:`model.data.gait_capture`) and writes ``BUNDLE/gait_limits.json``;
``rsmt package --gait-data DATA`` does the same for the copy (without it, the copy keeps the bundle's own).
``rsmt bundle database BUNDLE --from-data DATA`` writes its motion database (:mod:`rsmt_cli.database_commands`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rsmt_cli.database_commands import add_bundle_and_data, add_database_parser
from rsmt_cli.output_arguments import add_output_arguments, output_overrides
from rsmt_cli.renamed_flags import add_renamed

if TYPE_CHECKING:
    from model.inference.bundle import Bundle
    from model.inference.bundle_styles import BuiltinStyle, StyleClip
    from model.inference.output.steering import SteeringConfig
    from model.inference.overrides import Overrides

# The parts of steering rsmt package sets, by their names in the bundle (steering.NAME; the flag: dashes).
STEERING_PARTS = ("turn_window", "height_window", "retarget_turn_window", "max_step_cm", "retarget_max_turn_deg")
# Their flags before they took those names: they still work until the next release, with a warning.
RENAMED_STEERING_FLAGS = (("--steer-facing", "--turn-window", int), ("--steer-height", "--height-window", int),
                          ("--retarget-facing", "--retarget-turn-window", int), ("--steer-cap", "--max-step-cm", float),
                          ("--retarget-turn-cap", "--retarget-max-turn-deg", float))


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
                   help="built-in styles to encode into the copy: one BVH per style (the file stem is the name) "
                        "or one folder per style (its first BVH); the copy stores their codes, served as style ids "
                        "builtin:NAME")
    p.add_argument("--gait-data", type=Path, metavar="DATA",
                   help="measure the capture's gait limits (root speed, hips height) per style on this data's train "
                        "split and save them in the copy (default: the bundle's own gait_limits.json, if any)")
    add_output_arguments(p, "the bundle")
    # The parts of steering, each flag named as its setting in the bundle (steering.NAME).
    p.add_argument("--turn-window", type=int, default=None, metavar="FRAMES",
                   help="turn the body toward the target's facing over the last FRAMES frames (0: off; default: the "
                        "bundle's own setting)")
    p.add_argument("--height-window", type=int, default=None, metavar="FRAMES",
                   help="bring the root to the target's height over the last FRAMES frames (0: off; default: the "
                        "bundle's own setting)")
    p.add_argument("--retarget-turn-window", type=int, default=None, metavar="FRAMES",
                   help="for a character retargeted mid-stream, turn the body toward the new target's facing over "
                        "the last FRAMES frames instead (0: as the others; default: the bundle's own setting)")
    p.add_argument("--max-step-cm", type=float, default=None, metavar="CM",
                   help="the most steering moves the body in one frame, cm (default: the bundle's own setting)")
    p.add_argument("--retarget-max-turn-deg", type=float, default=None, metavar="DEG",
                   help="the most a retargeted character's facing turns in one frame, degrees (default: the "
                        "bundle's own setting)")
    for old, new, kind in RENAMED_STEERING_FLAGS:
        add_renamed(p, old, new, kind)
    p.set_defaults(func=_run)

    b = subparsers.add_parser("bundle", help="edit a bundle's built-in styles, gait limits or motion database in place "
                                             "(weights untouched)")
    bsub = b.add_subparsers(dest="bundle_command", required=True, metavar="ACTION")
    a = bsub.add_parser("add-styles", help="write the bundle's styles/ folder (built-in styles, builtin:NAME)",
                        description="Encode the given clips with the bundle's weights and replace BUNDLE/styles/ with "
                                    "their codes (no motion is stored); config.json and the weights are not touched, "
                                    "so the model's version and every style id stay the same. Run it again after the "
                                    "weights change: codes of other weights do not load.")
    a.add_argument("bundle", type=Path, metavar="BUNDLE")
    src = a.add_mutually_exclusive_group(required=True)
    src.add_argument("--from", dest="source", type=Path, metavar="DIR",
                     help="one BVH per style (file stem = name) or one folder per style")
    src.add_argument("--from-data", type=Path, metavar="DATA",
                     help="a motion dataset: one walking clip per style from its train split")
    a.add_argument("--frames", type=int, default=180, help="clip length with --from-data (default 180)")
    a.set_defaults(func=_add_styles)
    g = bsub.add_parser("gait-limits", help="write the bundle's gait_limits.json (the capture's speed and hips height)",
                        description="Measure, per style, the largest and 99th-percentile hips speed and the hips "
                                    "height range per gait over the train split of a motion dataset, and write them "
                                    "to BUNDLE/gait_limits.json (weights, config and styles untouched). The engine "
                                    "keeps the root within the style's speed and says when a target is out of reach.")
    add_bundle_and_data(g)
    g.set_defaults(func=_gait_limits)
    add_database_parser(bsub)


def _run(args: argparse.Namespace) -> int:
    from model.inference.bundle import Bundle

    if args.out.resolve() == args.model.resolve():
        raise ValueError("--out must not be the --model folder")
    overrides = output_overrides(args)  # checked before anything is read or written
    _check_finishing(args)
    bundle = Bundle.load(args.model, styles=args.styles is None)
    clips = _read_styles(args.styles, bundle) if args.styles is not None else None
    # Codes belong to the weights that made them: they are written after the copy's weights (float16 or not).
    # Adapters (fine-tuned styles) keep their own codes; they fit the copy only if its weights are the same.
    kept = {n: s for n, s in bundle.styles.items() if not s.weights}
    bundle.styles = {n: s for n, s in bundle.styles.items() if s.weights}
    _apply_settings(args, bundle, overrides)
    _set_gait_limits(args, bundle)
    if (args.out / "styles").is_dir():  # never leave a copy with the codes of some earlier weights
        shutil.rmtree(args.out / "styles")
    bundle.save(args.out, weights_dtype="float16" if args.float16 else "float32")
    if bundle.adapters and not (args.out / "adapters").is_dir():
        print(f"rsmt package: the style adapters of {args.model} ({', '.join(sorted(bundle.adapters))}) were tuned from "
              f"its weights, not the copy's (version {bundle.version}); they are not copied: fine-tune them again "
              "from the copy", file=sys.stderr)
    _copy_styles(args, bundle, clips, kept)
    train_config = args.model / "train_config.json"
    if train_config.is_file():
        shutil.copyfile(train_config, args.out / "train_config.json")
    print(json.dumps({"bundle": str(args.out), "version": bundle.version, "name": bundle.meta.name,
                      "output": bundle.output.to_dict(), "inference": bundle.inference.to_dict(),
                      "styles": sorted(Bundle.load(args.out).styles),
                      "gait_limits": bundle.gait_limits.to_dict() if bundle.gait_limits else None}, indent=1))
    return 0


def _apply_settings(args: argparse.Namespace, bundle: Bundle, overrides: Overrides) -> None:
    """The copy's output settings (steering parts included), inference settings and name, from the flags."""
    bundle.output = overrides.output(bundle.output)
    bundle.output = dataclasses.replace(bundle.output, steering=_finishing_steering(args, bundle.output.steering))
    bundle.inference = overrides.inference(bundle.inference)
    if args.name:
        bundle.meta = dataclasses.replace(bundle.meta, name=args.name)


def _set_gait_limits(args: argparse.Namespace, bundle: Bundle) -> None:
    """The copy's gait limits measured on --gait-data; without it the bundle's own, and a warning when it has none."""
    if args.gait_data is not None:
        from model.data.gait_capture import gait_limits_from_data

        bundle.gait_limits = gait_limits_from_data(args.gait_data, bundle.config.fps)
    elif bundle.gait_limits is None:
        print(f"rsmt package: {args.model} has no gait limits: the copy's root speed is not capped and no request "
              "is told its target is out of reach; give --gait-data DATA (the training data)", file=sys.stderr)


def _copy_styles(args: argparse.Namespace, bundle: Bundle, clips: list[StyleClip] | None,
                 kept: dict[str, BuiltinStyle]) -> None:
    """The copy's built-in styles: the --styles clips encoded by its weights, else the bundle's own codes where
    the copy's weights made them (else a warning saying how to re-encode them)."""
    from model.inference.bundle_styles import save_styles
    from model.inference.style_packing import write_builtin_styles

    if clips is not None:
        write_builtin_styles(args.out, clips)
    elif kept and all(s.version == bundle.version for s in kept.values()):
        save_styles(args.out, kept.values(), bundle.skeleton, bundle.config.fps, bundle.version)
    elif kept:
        print(f"rsmt package: the built-in styles of {args.model} were encoded by its weights (version "
              f"{next(iter(kept.values())).version}), not by the copy's (version {bundle.version}); they are not "
              f"copied: re-encode them with `rsmt bundle add-styles {args.out} --from DIR` (or --from-data DATA), "
              "or package with --styles DIR", file=sys.stderr)


def _gait_limits(args: argparse.Namespace) -> int:
    from model.data.gait_capture import gait_limits_from_data
    from model.inference.bundle import Bundle

    bundle = Bundle.load(args.bundle, styles=False)  # checks the folder is a bundle, gives its fps
    limits = gait_limits_from_data(args.from_data, bundle.config.fps)
    path = limits.save(args.bundle)
    print(json.dumps({"bundle": str(args.bundle), "file": str(path), **limits.to_dict()}, indent=1))
    return 0


def _check_finishing(args: argparse.Namespace) -> None:
    for flag, frames in (("--turn-window", args.turn_window), ("--height-window", args.height_window),
                         ("--retarget-turn-window", args.retarget_turn_window)):
        if frames is not None and frames < 0:
            raise ValueError(f"{flag} must be 0 (off) or more frames")
    if args.retarget_max_turn_deg is not None and not args.retarget_max_turn_deg > 0:
        raise ValueError("--retarget-max-turn-deg must be a positive number of degrees")
    if args.max_step_cm is not None and not args.max_step_cm > 0:
        raise ValueError("--max-step-cm must be a positive number of cm")


def _finishing_steering(args: argparse.Namespace, steering: SteeringConfig) -> SteeringConfig:
    """``steering`` with the flags of its parts (``--turn-window`` ... ``--max-step-cm``; unset: kept)."""
    changes = {name: value for name in STEERING_PARTS if (value := getattr(args, name)) is not None}
    return dataclasses.replace(steering, **changes)


def _read_styles(folder: Path, bundle: Any) -> list[Any]:
    """The clips of ``folder`` (one per style) on the bundle's rig, checked against its style clip lengths."""
    from model.inference.bundle_styles import styles_from_folder

    styles = styles_from_folder(folder, bundle.skeleton, bundle.config.fps)
    lo, hi = bundle.config.style_frames_min, bundle.config.style_frames_max
    for s in styles:
        if not lo <= s.frames <= hi:
            raise ValueError(f"style {s.name!r} ({s.source}) has {s.frames} frames at {bundle.config.fps:g} fps; a style "
                             f"clip of this model needs {lo} to {hi}: cut the file first")
    return styles


def _add_styles(args: argparse.Namespace) -> int:
    from model.data.style_picks import pick_style_clips
    from model.inference.bundle import Bundle
    from model.inference.bundle_styles import StyleClip, clip_on_rig
    from model.inference.style_packing import write_builtin_styles

    # Checks the folder is a bundle and gives its rig and fps; its styles/ folder is not read (it may be of an
    # older format, or of other weights: that is what this command repairs).
    bundle = Bundle.load(args.bundle, styles=False)
    if args.source is not None:
        clips = _read_styles(args.source, bundle)
    else:
        lo, hi = bundle.config.style_frames_min, bundle.config.style_frames_max
        if not lo <= args.frames <= hi:
            raise ValueError(f"--frames must be between {lo} and {hi} (the model's style clip lengths)")
        fps = bundle.config.fps
        clips = [StyleClip(p.style, clip_on_rig(p.clip, bundle.skeleton, fps, p.take_id), p.source)
                 for p in pick_style_clips(args.from_data, fps, frames=args.frames)]
    folder, styles = write_builtin_styles(args.bundle, clips)
    print(json.dumps({"bundle": str(args.bundle), "styles_folder": str(folder), "version": bundle.version,
                      "styles": [{"style_id": f"builtin:{s.name}", "frames": s.frames, "source": s.source}
                                 for s in styles]}, indent=1))
    return 0
