"""The ``rsmt style-probe`` command: how well a bundle's style encoder tells the styles of a split apart."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from model.data.location import require_data_dir

LOCOMOTION_ONLY = "locomotion"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "style-probe", help="how well a bundle's style encoder tells the styles of a split apart (its code space)",
        description="Encode windows of every take of a split with each bundle's style encoder, average each code over "
                    "time and score the codes per style: nearest-centroid accuracy with each take left out of its own "
                    "style's centroid, what a style is read as otherwise, and how far its centroid sits from the "
                    "nearest other style's, against its own spread (model/evaluation/style_code_probe.py). A style a "
                    "model never trained on that its encoder still separates has room in the code space.")
    p.add_argument("--model", type=Path, action="append", required=True, metavar="BUNDLE",
                   help="a bundle folder (repeat to compare)")
    p.add_argument("--data", type=Path, help="folder of BVH takes (default: the RSMT_DATA setting)")
    p.add_argument("--split", choices=("train", "val", "test"), default="test", help="takes to encode (default test)")
    p.add_argument("--contents", nargs="+", default=[LOCOMOTION_ONLY], metavar="CONTENT",
                   help="contents of the takes used (default: locomotion, i.e. walk, turns and run; 'all' for every one)")
    p.add_argument("--frames", type=int, default=120, help="frames of each clip (default 120, the evaluation's)")
    p.add_argument("--step", type=int, default=60, help="frames between clips of one take (default 60)")
    p.add_argument("--out", type=Path, metavar="JSON", help="also write the figures to this file")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    import torch
    from tqdm import tqdm

    from model.data.preprocessed import load_motion_cache
    from model.evaluation.cases import LOCOMOTION
    from model.evaluation.style_code_probe import encode_clips, probe_codes, probe_table
    from model.inference.bundle import Bundle
    from model.inference.engine import Engine

    if args.frames < 1 or args.step < 1:
        raise ValueError("--frames and --step must be at least 1")
    cache = load_motion_cache(Path(require_data_dir(args.data)), progress=not args.quiet)
    contents = LOCOMOTION if args.contents == [LOCOMOTION_ONLY] else () if args.contents == ["all"] else args.contents
    clips, labels, takes = [], [], []
    for i in getattr(cache.split, args.split):
        take = cache.takes[i]
        if contents and take.content not in contents:
            continue
        for start in range(0, cache.num_frames(i) - args.frames + 1, args.step):
            clips.append(cache.clip(i).window(start, start + args.frames).to(torch.float32))
            labels.append(take.style)
            takes.append(take.take_id)
    if not clips:
        raise ValueError(f"no take of the {args.split} split has {args.frames} frames of the contents asked for")
    results = {}
    for path in args.model:
        engine = Engine(Bundle.load(path))
        codes = encode_clips(engine, tqdm(clips, desc=f"codes {path.name}", unit="clip", disable=args.quiet,
                                          leave=False, file=sys.stderr))
        probe = probe_codes(codes, labels, takes)
        results[str(path)] = probe.to_dict()
        print("\n".join(probe_table(str(path), probe)))
    if args.out is not None:
        args.out.write_text(json.dumps({"split": args.split, "contents": list(contents) or "all", "frames": args.frames,
                                        "step": args.step, "models": results}, indent=1))
        print(f"wrote {args.out}")
    return 0
