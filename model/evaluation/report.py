"""The evaluation report as Markdown tables, and writing it (JSON and Markdown) to a folder."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

GT_NAME = "ground truth"


def _fmt(x: Any, digits: int = 3) -> str:
    if x is None:
        return "–"
    if isinstance(x, float):
        if math.isnan(x):
            return "nan"
        return f"{x:.{digits}f}"
    return str(x)


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return [_row(header), _row(["---"] * len(header)), *(_row(r) for r in rows)]


def _variants(report: dict[str, Any], ground_truth: bool) -> list[dict[str, Any]]:
    return [v for v in report["variants"] if v["ground_truth"] == ground_truth]


def markdown(report: dict[str, Any], command: str | None = None) -> str:
    """Three tables: unchanged controls (per gap), changed controls (40-frame gap), style (40-frame gap)."""
    methods = report["methods"]
    lines = [f"## Evaluation on the {report['split']} split: {report['cases']} cases from {report['takes']} takes", ""]
    if command:
        lines += [f"Command: `{command}`", ""]
    lines += [
        f"Data: `{report['data']}`; canonical frame: {report['protocol']['canonical_frame']}; "
        f"reference statistics from {report['reference']['windows']} training windows of "
        f"{report['reference']['takes']} takes; foot ground levels (cm) "
        + ", ".join(f"{n} {g:.2f}" for n, g in zip(report["reference"]["feet"], report["reference"]["ground_cm"]))
        + ".",
        "",
    ]

    lines += _unchanged_controls(methods, report)
    lines += _changed_controls(methods, report)
    lines += _style_tables(methods, report)
    lines += [f"Total time {report['seconds']:.1f} s: " + ", ".join(f"{n} {m['seconds']:.1f} s" for n, m in methods.items()), ""]
    return "\n".join(lines)


def _unchanged_controls(methods: dict[str, Any], report: dict[str, Any]) -> list[str]:
    """Per gap: the figures that need ground truth."""
    header = ["gap", "method", "L2P", "L2Q", "NPSS", "100×NPSS", "MPJPE cm", "foot skate", "GT foot skate",
              "last frame cm", "diversity cm"]
    rows = []
    for v in _variants(report, True):
        gt = report["ground_truth"].get(v["name"], {})
        for name, m in methods.items():
            r = m["variants"].get(v["name"], {})
            if "unavailable" in r:
                rows.append([str(v["gap"]), name] + ["n/a"] * (len(header) - 2))
                continue
            rows.append([str(v["gap"]), name, _fmt(r.get("l2p")), _fmt(r.get("l2q")), _fmt(r.get("npss"), 5),
                         _fmt(r.get("npss_x100")), _fmt(r.get("mpjpe_cm"), 2), _fmt(r.get("foot_skate")),
                         _fmt(gt.get("foot_skate")), _fmt(r.get("last_frame_cm"), 2),
                         _fmt(r.get("diversity_cm"), 2)])
    return ["### Unchanged controls (ground truth exists)", "", *_table(header, rows), ""]


def _changed_controls(methods: dict[str, Any], report: dict[str, Any]) -> list[str]:
    """The 40-frame gap with the target moved or the duration scaled (no ground truth)."""
    header = ["variant", "method", "frames", "last frame cm", "last-frame L2P", "foot skate"]
    clf = report.get("classifier")
    if clf:
        header.append("style acc")
    rows = []
    for v in _variants(report, False):
        for name, m in methods.items():
            r = m["variants"].get(v["name"], {})
            if "unavailable" in r:
                rows.append([v["label"], name, str(v["frames"]), "n/a", "n/a", "n/a"] + (["n/a"] if clf else []))
                continue
            cells = [v["label"], name, str(v["frames"]), _fmt(r.get("last_frame_cm"), 2), _fmt(r.get("last_frame_l2p")),
                     _fmt(r.get("foot_skate"))]
            if clf:
                cells.append(_fmt(r.get("style_accuracy")))
            rows.append(cells)
    lines = ["### Changed controls on the 40-frame gap (no ground truth)", "", *_table(header, rows), ""]
    unavailable = sorted({f"{name} {vn}: {r['unavailable']}" for name, m in methods.items()
                          for vn, r in m["variants"].items() if "unavailable" in r})
    if unavailable:
        lines += ["Not produced: " + "; ".join(unavailable) + ".", ""]
    return lines


def _style_tables(methods: dict[str, Any], report: dict[str, Any]) -> list[str]:
    """Style accuracy and FMD on the 40-frame gap, overall and per style."""
    clf = report.get("classifier")
    if not clf:
        return ["No style classifier given (`--classifier DIR`): no style accuracy or FMD.", ""]
    chance = 1.0 / max(1, len(clf["styles"]))
    header = ["method", "style acc (same-style clip)", "style acc (other-style clip)",
              "other-style clip read as the context's style", "FMD", "FMD (other style)"]
    gt = report["ground_truth"].get("gap40", {})
    floor = gt.get("fmd_split_half")
    rows = [[GT_NAME, _fmt(gt.get("style_accuracy")), "–", "–", "0" if floor is None else f"0 (split halves {floor:.2f})",
             "–"]]
    for name, m in methods.items():
        r = m["variants"].get("gap40", {})
        rows.append([name, _fmt(r.get("style_accuracy")), _fmt(r.get("style_accuracy_cross")),
                     _fmt(r.get("style_cross_as_context")), _fmt(r.get("fmd"), 2), _fmt(r.get("fmd_cross"), 2)])
    lines = [f"### Style on the 40-frame gap (classifier `{clf['path']}`, inputs `{clf['inputs']}`, "
             f"chance {chance:.3f})", "", *_table(header, rows), "",
             "Style accuracy: share of transitions classified as the requested style (the style clip's). "
             "Baselines ignore the style clip. With an other-style clip, the next column is the share of "
             "transitions classified as the context's own style instead (the clip not followed). "
             "FMD: Fréchet distance of the classifier's pooled features to the "
             "ground truth of the same cases (other style: to ground truth of cases in the requested style); "
             "the ground-truth row gives the distance between two halves of the ground truth, the floor at "
             "this number of cases.", ""]

    def gap40(key: str) -> dict[str, Any]:
        return {name: m["variants"].get("gap40", {}).get(key) for name, m in methods.items()}

    lines += _per_style_table("Same-style accuracy per requested style (40-frame gap):",
                              {GT_NAME: gt.get("style_accuracy_by_style"), **gap40("style_accuracy_by_style")})
    lines += _per_style_table("Other-style accuracy per requested style (the clip's; 40-frame gap):",
                              gap40("style_accuracy_cross_by_style"))
    lines += _per_style_table("Other-style accuracy per context style (scored on the clip's style; 40-frame gap):",
                              gap40("style_accuracy_cross_by_context"))
    return lines


def _per_style_table(title: str, per_method: dict[str, dict[str, float] | None]) -> list[str]:
    """A titled table of per-style figures, a row per method that has them (none: no lines)."""
    names = sorted({s for d in per_method.values() if d for s in d})
    if not names:
        return []
    rows = [[name] + [_fmt(d.get(s)) if s in d else "–" for s in names] for name, d in per_method.items() if d]
    return [title, "", *_table(["method", *names], rows), ""]


def write_report(folder: str | Path, report: dict[str, Any], text: str) -> list[Path]:
    """``report.json`` and ``report.md`` in ``folder``; returns their paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    js = folder / "report.json"
    md = folder / "report.md"
    js.write_text(json.dumps(report, indent=1))
    md.write_text(text)
    return [js, md]
