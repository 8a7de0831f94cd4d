"""What the commands that train a style reader (``rsmt train judge``, ``sequence-judge``, ``classifier``) share:
the motion cache they load, the style labels they learn, and how a judge's report is written and printed."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from model.data.location import require_data_dir


def load_training_cache(args: argparse.Namespace) -> tuple[Path, Any]:
    """Apply --threads, then load the motion cache of --data (default: the RSMT_DATA setting): the folder and the
    cache."""
    import torch

    from model.data.preprocessed import load_motion_cache

    if args.threads:
        torch.set_num_threads(args.threads)
    data = require_data_dir(args.data)
    return data, load_motion_cache(Path(data), progress=not args.quiet)


def style_labels(cache: Any, styles: Sequence[str]) -> Any:
    """``[N]`` tensor: each window's style as its index in ``cache.styles``."""
    import torch

    index = {s: k for k, s in enumerate(cache.styles)}
    return torch.tensor([index[s] for s in styles])


def save_judge(judge: Any, out: Path, command: str, info: dict[str, Any], training: dict[str, Any]) -> None:
    """Record ``command`` and ``info`` in the judge, write it to ``out`` and ``training`` to out/training.json."""
    judge.info.update({"command": command, **info})
    judge.save(out)
    (Path(out) / "training.json").write_text(json.dumps({"command": command, **training}, indent=1))


def print_groups(prefix: str, report: dict[str, Any]) -> None:
    """A report's accuracy per style and per content, one line each ('–' where a group has no windows)."""
    for group in ("per_style", "per_content"):
        print(f"{prefix} {group.replace('_', ' ')}: " + ", ".join(
            f"{k} {'–' if a is None else f'{a:.3f}'}" for k, a in report[group].items()))
