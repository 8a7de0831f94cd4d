"""The ``rsmt data`` command group: ``rsmt data inspect`` reports what a folder of BVH takes holds."""

from __future__ import annotations

import argparse
import json
import logging
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

from model.data.splits import DEFAULT_RATIOS, SPLITS, Split, parse_ratios, split_takes
from model.data.takes import Problem, Take, TakeIndex, describe_layout, index_takes, read_bvh_header, relative_path

if TYPE_CHECKING:
    from model.motion.skeleton import SkeletonProfile

log = logging.getLogger(__name__)

MAX_PROBLEMS_SHOWN = 20


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``rsmt data ...`` to the top-level parser."""
    data = subparsers.add_parser("data", help="inspect and preprocess motion data",
                                 description="Inspect and preprocess folders of BVH takes.")
    sub = data.add_subparsers(dest="data_command", required=True, metavar="SUBCOMMAND")
    inspect = sub.add_parser(
        "inspect", help="takes, frames and minutes per style and content, split sizes and problems",
        description=(
            "Index a folder of BVH takes (labels from a manifest, a 100STYLE Frame_Cuts.csv, or "
            "Bandai-Namco file names, in that order of preference) and print takes, frames and minutes per "
            "style and per content, a style x content table (the longer label list runs down the rows), "
            "the train/val/test split sizes and every file that was skipped. Frames are read from the BVH "
            "headers at each file's own rate; --cache parses every file into the preprocessed cache "
            "instead and reports its frames."),
    )
    inspect.add_argument("folder", type=Path, metavar="DIR", help="folder of BVH takes (searched recursively)")
    inspect.add_argument("--manifest", type=Path, metavar="CSV",
                         help="CSV with columns file, style, content[, start, stop]; paths relative to it")
    inspect.add_argument("--profile", metavar="P",
                         help="skeleton profile: a built-in name (bandai-namco, 100style) or a JSON file; "
                              "default: the first built-in that fits each file")
    inspect.add_argument("--units", default="auto", metavar="U",
                         help="units of the takes: auto (read from the character's height), cm, m, mm, inch, or "
                              "centimetres per file unit (default: auto); takes are converted to centimetres")
    inspect.add_argument("--ratios", type=parse_ratios, default=DEFAULT_RATIOS, metavar="TRAIN,VAL,TEST",
                         help="split ratios (default 0.8,0.1,0.1)")
    inspect.add_argument("--holdout-style", action="append", default=[], metavar="STYLE",
                         help="hold a style out of the split entirely (repeatable)")
    inspect.add_argument("--cache", action="store_true",
                         help="build (or reuse) the preprocessed motion cache and report its frames and problems")
    inspect.add_argument("--fps", type=float, default=30.0, help="frame rate of the cache (with --cache; default 30)")
    inspect.add_argument("--json", action="store_true", help="print machine-readable JSON instead of tables")
    inspect.set_defaults(func=inspect_command)


# ---------------------------------------------------------------------------------- gathering
def _probe_headers(index: TakeIndex, profile: SkeletonProfile | None, units: str | float = "auto"
                   ) -> tuple[list[tuple[Take, int, float]], list[Problem], list[dict[str, Any]]]:
    """Frames and fps of each take from its BVH header, and each rig checked on its first take
    (the profile fits, the units, the facing joints stand apart)."""
    from model.data.rig_probe import RigReport, probe_rig  # imports torch: only when a command runs

    headers: list[tuple[Take, Any]] = []
    problems: list[Problem] = []
    for take in index.takes:
        try:
            headers.append((take, read_bvh_header(take.path)))
        except (OSError, ValueError) as exc:
            problems.append(Problem(relative_path(take.path, index.root), "unreadable", str(exc)))
    counts = Counter(h.joints for _, h in headers)
    rigs: dict[tuple[str, ...], RigReport | tuple[str, str]] = {}
    for take, header in headers:  # datasets share a handful of rigs: load one take of each
        if header.joints not in rigs:
            rigs[header.joints] = probe_rig(take.path, relative_path(take.path, index.root), counts[header.joints],
                                            profile, units)
    rows: list[tuple[Take, int, float]] = []
    for take, header in headers:
        rel = relative_path(take.path, index.root)
        rig = rigs[header.joints]
        if isinstance(rig, tuple):
            problems.append(Problem(rel, *rig))
            continue
        frames = header.frames
        if take.start is not None or take.stop is not None:
            lo, hi = take.start or 0, header.frames if take.stop is None else min(take.stop, header.frames)
            if hi <= lo:
                problems.append(Problem(rel, "bad-cut", f"cut [{take.start}, {take.stop}) leaves no frames of {header.frames}"))
                continue
            frames = hi - lo
        rows.append((take, frames, header.fps))
    return rows, problems, [r.to_dict() for r in rigs.values() if isinstance(r, RigReport)]


def _tally(rows: Sequence[tuple[Take, int, float]]) -> dict[str, float]:
    return {
        "takes": len(rows),
        "frames": sum(f for _, f, _ in rows),
        "minutes": round(sum(f / fps for _, f, fps in rows) / 60.0, 2),
    }


def inspect_data(
    folder: Path,
    manifest: Path | None = None,
    profile: str | None = None,
    ratios: Sequence[float] = DEFAULT_RATIOS,
    holdout_styles: Sequence[str] = (),
    use_cache: bool = False,
    fps: float = 30.0,
    units: str = "auto",
) -> dict[str, Any]:
    """The report that ``rsmt data inspect`` prints, as a JSON-ready dict."""
    from model.motion.rig_facts import parse_units
    from model.motion.skeleton import SkeletonProfile  # imports torch: only when a command runs

    index = index_takes(folder, manifest)
    unit = parse_units(units)
    prof = None if profile is None else SkeletonProfile.load(profile)
    if use_cache:
        rows, problems, rigs, cache_folder = _from_cache(folder, manifest, prof, fps, unit)
    else:
        rows, probe_problems, rigs = _probe_headers(index, prof, unit)
        problems, cache_folder = index.problems + probe_problems, None
    takes = [t for t, _, _ in rows]
    styles = sorted({t.style for t in takes})
    contents = sorted({t.content for t in takes})
    split = split_takes(takes, ratios, holdout_styles, frames=[f for _, f, _ in rows])
    return {
        "folder": str(index.root),
        "layout": index.layout,
        "labels": describe_layout(index),
        "frames_from": "cache" if use_cache else "headers",
        "cache": cache_folder,
        "fps": sorted({round(f, 3) for _, _, f in rows}),  # the rates frames are counted at
        "total": _tally(rows),
        "styles": styles,
        "contents": contents,
        **_tallies_by_label(rows, styles, contents),
        "split": _split_tallies(rows, split),
        "rigs": rigs,
        "problems": [asdict(p) for p in problems],
    }


def _from_cache(folder: Path, manifest: Path | None, profile: SkeletonProfile | None, fps: float,
                units: str | float) -> tuple[list[tuple[Take, int, float]], list[Problem], list[dict[str, Any]], str]:
    """Frames of each take as the preprocessed cache holds them (built or reused), its problems, no rig
    reports, and the cache's folder."""
    from model.data.preprocessed import load_motion_cache  # torch-heavy; only needed with --cache

    cache = load_motion_cache(folder, fps=fps, profile=profile, manifest=manifest, units=units)
    rows = [(t, n, cache.fps) for t, n in zip(cache.takes, cache.frame_counts)]
    return rows, list(cache.problems), [], str(cache.folder)


def _tallies_by_label(rows: Sequence[tuple[Take, int, float]], styles: Sequence[str],
                      contents: Sequence[str]) -> dict[str, Any]:
    """Tallies per style, per content, and per style and content (takes and frames only)."""
    return {
        "per_style": {s: _tally([r for r in rows if r[0].style == s]) for s in styles},
        "per_content": {c: _tally([r for r in rows if r[0].content == c]) for c in contents},
        "table": {
            s: {c: {k: v for k, v in _tally([r for r in rows if r[0].style == s and r[0].content == c]).items()
                    if k != "minutes"} for c in contents}
            for s in styles
        },
    }


def _split_tallies(rows: Sequence[tuple[Take, int, float]], split: Split) -> dict[str, Any]:
    """The split's ratios, held-out styles and a tally of each of its parts."""
    split_names = [*SPLITS, "holdout"] if split.holdout_styles else list(SPLITS)
    return {
        "ratios": list(split.ratios),
        "holdout_styles": list(split.holdout_styles),
        **{name: _tally([rows[i] for i in split[name]]) for name in split_names},
    }


# ---------------------------------------------------------------------------------- printing
def _table(header: Sequence[str], body: Sequence[Sequence[str]], left: int = 1) -> list[str]:
    """Text table: the first ``left`` columns flush left, the rest flush right."""
    widths = [max(len(str(r[i])) for r in [header, *body]) for i in range(len(header))]
    lines = []
    for r in [header, *body]:
        cells = [str(c).ljust(w) if i < left else str(c).rjust(w) for i, (c, w) in enumerate(zip(r, widths))]
        lines.append("  ".join(cells).rstrip())
    return lines


def format_report(report: dict[str, Any]) -> str:
    """The human-readable form of :func:`inspect_data`'s report."""
    total = report["total"]
    styles, contents = report["styles"], report["contents"]
    out = [
        f"Data folder: {report['folder']}",
        f"Layout:      {report['labels']}",
        f"Takes:       {total['takes']} takes, {total['frames']:,} frames, {total['minutes']:.1f} min; "
        f"{len(styles)} styles x {len(contents)} contents",
        _frames_line(report),
    ]
    if styles:
        out += _style_content_lines(report)
        out += _per_label_lines(report)
    for rig in report.get("rigs", []):
        out += _rig_lines(rig)
    out += _split_lines(report["split"])
    out += _problem_lines(report["problems"])
    return "\n".join(out)


def _frames_line(report: dict[str, Any]) -> str:
    """Where the frames were counted (the cache or the BVH headers) and at which rates."""
    rates = ", ".join(f"{f:g}" for f in report["fps"]) or "-"
    if report["frames_from"] == "cache":
        return f"Frames:      preprocessed at {rates} fps (cache {report['cache']})"
    return f"Frames:      from the BVH headers, at the files' own rate ({rates} fps); minutes at that rate"


def _style_content_lines(report: dict[str, Any]) -> list[str]:
    """The style x content table of takes/frames, with totals and minutes."""
    total = report["total"]
    styles, contents = report["styles"], report["contents"]
    # The longer label list runs down the rows so the table stays narrow (100STYLE: 100 styles).
    by_style = len(styles) > len(contents)
    rows_l, cols_l = (styles, contents) if by_style else (contents, styles)
    corner = "style \\ content" if by_style else "content \\ style"

    def cell(r: str, c: str) -> dict[str, int]:
        return report["table"][r][c] if by_style else report["table"][c][r]

    def sums(label: str, along_rows: bool) -> dict[str, float]:
        key = ("per_style" if by_style else "per_content") if along_rows else ("per_content" if by_style else "per_style")
        return report[key][label]

    body = []
    for r in rows_l:
        t = sums(r, True)
        body.append([r, *(f"{cell(r, c)['takes']}/{cell(r, c)['frames']:,}" for c in cols_l),
                     f"{t['takes']}/{t['frames']:,}", f"{t['minutes']:.1f}"])
    body.append(["total", *(f"{sums(c, False)['takes']}/{sums(c, False)['frames']:,}" for c in cols_l),
                 f"{total['takes']}/{total['frames']:,}", f"{total['minutes']:.1f}"])
    body.append(["minutes", *(f"{sums(c, False)['minutes']:.1f}" for c in cols_l), f"{total['minutes']:.1f}", ""])
    return ["", "Takes/frames per style and content (cell = takes/frames):",
            *_table([corner, *cols_l, "total", "minutes"], body)]


def _per_label_lines(report: dict[str, Any]) -> list[str]:
    """A table of takes, frames and minutes per style, then one per content."""
    out: list[str] = []
    for title, key in (("style", "per_style"), ("content", "per_content")):
        out += ["", f"Per {title}:"]
        out += _table([title, "takes", "frames", "minutes"],
                      [[k, v["takes"], f"{v['frames']:,}", f"{v['minutes']:.1f}"] for k, v in report[key].items()])
    return out


def _rig_lines(rig: dict[str, Any]) -> list[str]:
    """What the check of one rig found: its profile, joints, units, facing and dropped joints."""
    return ["", f"Rig of {rig['example']} ({rig['takes']} take(s) share it): profile {rig['profile']}, "
                f"{rig['joints']} of the file's {rig['file_joints']} joints kept, {rig['fps']:g} fps",
            f"  units:   {rig['cm_per_unit']:g} cm per file unit; head {rig['head_cm']:.1f} cm, "
            f"hips {rig['hips_cm']:.1f} cm above the lowest foot joint",
            f"  facing:  {rig['facing']} (pairs {rig['hips_spread_cm']:.1f} and "
            f"{rig['shoulders_spread_cm']:.1f} cm apart)",
            f"  dropped: {', '.join(rig['dropped']) or 'none'}"]


def _split_lines(split: dict[str, Any]) -> list[str]:
    """How the takes were split and the size of each part."""
    ratios = "/".join(f"{r:g}" for r in split["ratios"])
    held = f"; held out: {', '.join(split['holdout_styles'])}" if split["holdout_styles"] else ""
    names = [n for n in (*SPLITS, "holdout") if n in split]
    return ["", f"Split by take (ratios {ratios}, stratified by style x content, hash of the take id{held}):",
            *_table(["split", "takes", "frames", "minutes"],
                    [[n, split[n]["takes"], f"{split[n]['frames']:,}", f"{split[n]['minutes']:.1f}"] for n in names])]


def _problem_lines(problems: list[dict[str, Any]]) -> list[str]:
    """The skipped files by kind, then the first of them (``MAX_PROBLEMS_SHOWN``)."""
    if not problems:
        return ["", "Problems: none"]
    kinds = Counter(p["kind"] for p in problems)
    out = ["", f"Problems: {len(problems)} file(s) skipped ("
           + ", ".join(f"{k} {n}" for k, n in sorted(kinds.items())) + ")"]
    out += [f"  {Problem(**p)}" for p in problems[:MAX_PROBLEMS_SHOWN]]
    if len(problems) > MAX_PROBLEMS_SHOWN:
        out.append(f"  ... and {len(problems) - MAX_PROBLEMS_SHOWN} more (--json lists them all)")
    return out


def inspect_command(args: argparse.Namespace) -> int:
    report = inspect_data(args.folder, args.manifest, args.profile, args.ratios, args.holdout_style,
                          use_cache=args.cache, fps=args.fps, units=args.units)
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        print(format_report(report))
    if report["total"]["takes"] == 0:
        kinds = {p["kind"] for p in report["problems"]}
        hint = ""
        if "unlabelled" in kinds and args.manifest is None:
            hint = ": the file names carry no labels; write a CSV manifest (file,style,content) and pass --manifest"
        elif "rig" in kinds:
            hint = f": no profile fits the rig; rsmt profile guess {args.folder} --out my-rig.json, then --profile"
        elif "units" in kinds:
            hint = ": the units could not be told; pass --units"
        log.error("no usable takes under %s%s (docs/your-rig.md)", args.folder, hint)
        return 1
    return 0
