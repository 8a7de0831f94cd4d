"""The ``rsmt train`` command group: the RSMT training stages and the whole recipe."""

from __future__ import annotations

import argparse
import json
import logging
import shlex
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from model.data.location import find_data_dir

if TYPE_CHECKING:
    import torch

log = logging.getLogger(__name__)

PRESET_DIR = Path(__file__).resolve().parent.parent / "model" / "train" / "configs"


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
        p.add_argument("--out", type=Path, help="bundle folder to write when the sampler is trained")
        p.add_argument("--config", type=Path, help="training config JSON (see configs/*.json); overrides --preset")
        p.add_argument("--preset", default="default",
                       help="a config in model/train/configs/ by name: default, paper, smoke, the default model's "
                            "continuations default-continue-*, ... (default: default)")
        p.add_argument("--run", type=Path, help="run folder for checkpoints and stage weights (default: ~/.cache/rsmt/runs/NAME)")
        p.add_argument("--time-limit", type=float, default=0.0, metavar="S",
                       help="stop each stage after S seconds with a checkpoint; run again to resume")
        p.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's choice)")
        p.add_argument("--compile", action="store_true",
                       help="train the sampler's per-frame functions through torch.compile: about a third faster "
                            "per step after a minute or two of compiling (needs a C++ compiler on the CPU)")
        add_device_argument(p)
        p.add_argument("--quiet", action="store_true", help="no progress bars")
        p.set_defaults(func=_run, stage=stage)
    from rsmt_cli import classifier_commands

    classifier_commands.register(sub)


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


def load_config(args: argparse.Namespace):
    from model.train.pipeline import TrainConfig

    path = args.config or PRESET_DIR / f"{args.preset}.json"
    if not path.is_file():
        raise FileNotFoundError(f"no training config {path}; presets: {', '.join(p.stem for p in PRESET_DIR.glob('*.json'))}")
    return TrainConfig.load(path)


def _run(args: argparse.Namespace) -> int:
    from model.train.pipeline import STAGES, run

    device = resolve_cli_device(args.device)  # first, so a missing GPU fails before any data is read
    cfg = load_config(args)
    if args.threads:
        cfg.threads = args.threads
    if args.time_limit:
        for st in (cfg.phase_stage, cfg.manifold_stage, cfg.sampler_stage):
            st.loop.time_limit_s = args.time_limit
    data = args.data or find_data_dir()
    if data is None:
        raise FileNotFoundError("no data folder: pass --data DIR or set RSMT_DATA")
    run_dir = args.run or Path.home() / ".cache" / "rsmt" / "runs" / cfg.name
    stages = STAGES if args.stage == "all" else (args.stage,)
    if "sampler" in stages and args.out is None:
        raise ValueError("training the sampler writes a bundle: pass --out BUNDLE")
    command = "rsmt " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv else None
    bundle = run(cfg, Path(data), run_dir, stages, args.out, progress=not args.quiet, command=command, device=device,
                 compile=args.compile)
    if "sampler" in stages and bundle is None:
        print(f"stopped before the end (time limit); run the same command again to resume from {run_dir}")
        return 3
    timings = json.loads((run_dir / "timings.json").read_text()) if (run_dir / "timings.json").is_file() else {}
    print(json.dumps({"run": str(run_dir), "bundle": str(args.out) if bundle else None, "device": str(device),
                      "timings_s": timings}, indent=1))
    return 0
