"""The evaluation report as Markdown tables, and writing it (JSON and Markdown) to a folder."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from model.evaluation.gait_report import gait_tables

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
    """The locomotion tables first (the acceptance figures), then all contents; see the sections below."""
    methods = report["methods"]
    lines = [f"## Evaluation on the {report['split']} split: {report['cases']} cases from {report['takes']} takes, "
             f"{report.get('locomotion_cases', 0)} of them locomotion", ""]
    if command:
        lines += [f"Command: `{command}`", ""]
    lines += [
        f"Data: `{report['data']}`; canonical frame: {report['protocol']['canonical_frame']}; "
        f"reference statistics from {report['reference']['windows']} training windows of "
        f"{report['reference']['takes']} takes; foot ground levels (cm) "
        + ", ".join(f"{n} {g:.2f}" for n, g in zip(report["reference"]["feet"], report["reference"]["ground_cm"]))
        + ".",
        "",
        f"Target sent to the models: {report['protocol'].get('target', 'the target frame and the frame before it')} "
        "(baselines use the target frame only). Bundles' sampling noise: "
        f"{report['protocol'].get('noise', 'none (deterministic)')}.",
        "",
    ]
    lines += _judge_line(report)
    if report.get("locomotion_cases"):
        lines += [f"# Locomotion cases ({', '.join(report['locomotion_contents'])}): the acceptance figures", ""]
        lines += _unchanged_controls(methods, report, "locomotion", "ground_truth_locomotion")
        lines += _changed_controls(methods, report, "locomotion", "ground_truth_locomotion")
        lines += gait_tables(report, "locomotion", "ground_truth_locomotion")
        lines += _judge_tables(methods, report, "locomotion", "ground_truth_locomotion")
    lines += ["# All contents", ""]
    lines += _unchanged_controls(methods, report, "variants", "ground_truth")
    lines += _changed_controls(methods, report, "variants", "ground_truth")
    lines += gait_tables(report, "variants", "ground_truth")
    lines += _judge_tables(methods, report, "variants", "ground_truth")
    lines += _style_tables(methods, report)
    lines += [f"Total time {report['seconds']:.1f} s: " + ", ".join(f"{n} {m['seconds']:.1f} s" for n, m in methods.items()), ""]
    return "\n".join(lines)


def _judge_line(report: dict[str, Any]) -> list[str]:
    judge = report.get("judge")
    if not judge:
        return ["No style judge given (`--judge DIR`, from `rsmt train judge`): no acceptance style figures.", ""]
    return [f"Style scored by the judge `{judge['path']}`: {judge['kind']}; {judge['features']} features of "
            f"{judge['window']}-pose windows; {len(judge['styles'])} styles, chance {1 / len(judge['styles']):.3f}. "
            "No training critic shares its inputs or its architecture.", ""]


def _unchanged_controls(methods: dict[str, Any], report: dict[str, Any], key: str, gt_key: str) -> list[str]:
    """Per gap: the figures that need ground truth."""
    header = ["gap", "method", "L2P", "L2Q", "NPSS", "100×NPSS", "MPJPE cm", "foot skate", "GT foot skate",
              "below floor cm", "last frame cm", "max root speed cm/s", "style (judge)", "style (judge), other-style clip",
              "diversity cm"]
    rows = []
    gts = report.get(gt_key, {})
    for v in _variants(report, True):
        gt = gts.get(v["name"], {})
        rows.append([str(v["gap"]), GT_NAME, "–", "–", "–", "–", "–", _fmt(gt.get("foot_skate")), "–",
                     _fmt(gt.get("floor_depth_cm"), 2), "–",
                     _fmt(gt.get("max_root_speed_cm_s"), 1), _fmt(gt.get("judge_accuracy")), "–", "–"])
        for name, m in methods.items():
            r = m.get(key, {}).get(v["name"], {})
            if "unavailable" in r:
                rows.append([str(v["gap"]), name] + ["n/a"] * (len(header) - 2))
                continue
            rows.append([str(v["gap"]), name, _fmt(r.get("l2p")), _fmt(r.get("l2q")), _fmt(r.get("npss"), 5),
                         _fmt(r.get("npss_x100")), _fmt(r.get("mpjpe_cm"), 2), _fmt(r.get("foot_skate")),
                         _fmt(gt.get("foot_skate")), _fmt(r.get("floor_depth_cm"), 2), _fmt(r.get("last_frame_cm"), 2),
                         _fmt(r.get("max_root_speed_cm_s"), 1), _fmt(r.get("judge_accuracy")),
                         _fmt(r.get("judge_accuracy_cross")), _fmt(r.get("diversity_cm"), 2)])
    where = "locomotion cases" if key == "locomotion" else "all contents"
    return [f"### Unchanged controls, {where} (ground truth exists)", "", *_table(header, rows), "",
            "Max root speed: per case the largest root speed between consecutive frames (the last context "
            "frame first), averaged over cases; below floor: per case the deepest a foot joint goes under its ground "
            "level, averaged over cases; style (judge): the judge's accuracy on the requested style, 40-frame "
            "gap, with a clip of the case's own style and with a clip of another style (baselines ignore the clip).",
            ""]


def _changed_controls(methods: dict[str, Any], report: dict[str, Any], key: str, gt_key: str) -> list[str]:
    """The 40-frame gap with the target moved, turned or the duration scaled (no ground truth)."""
    header = ["variant", "method", "frames", "arrival cm", "last-frame L2P", "foot skate", "below floor cm",
              "max root speed cm/s",
              "worst root speed cm/s", "style (judge)"]
    clf = report.get("classifier") if key == "variants" else None
    if clf:
        header.append("style (classifier)")
    rows = []
    for v in _variants(report, False):
        if v.get("locomotion_only") and key != "locomotion":
            continue
        for name, m in methods.items():
            r = m.get(key, {}).get(v["name"], {})
            if "unavailable" in r:
                rows.append([v["label"], name, str(v["frames"])] + ["n/a"] * (len(header) - 3))
                continue
            cells = [v["label"], name, str(v["frames"]), _fmt(r.get("last_frame_cm"), 2), _fmt(r.get("last_frame_l2p")),
                     _fmt(r.get("foot_skate")), _fmt(r.get("floor_depth_cm"), 2), _fmt(r.get("max_root_speed_cm_s"), 1),
                     _fmt(r.get("max_root_speed_cm_s_worst"), 1), _fmt(r.get("judge_accuracy"))]
            if clf:
                cells.append(_fmt(r.get("style_accuracy")))
            rows.append(cells)
    where = "locomotion cases" if key == "locomotion" else "all contents"
    lines = [f"### Changed controls on the 40-frame gap, {where} (no ground truth)", "", *_table(header, rows), ""]
    gt = report.get(gt_key, {}).get("gap40", {})
    if "context_max_root_speed_cm_s" in gt:
        lines += [f"For scale, largest root speed of the ground truth's 40-frame transitions "
                  f"{_fmt(gt.get('max_root_speed_cm_s'), 1)} cm/s (mean), {_fmt(gt.get('max_root_speed_cm_s_worst'), 1)} "
                  f"(worst); of the contexts {_fmt(gt.get('context_max_root_speed_cm_s'), 1)} (mean), "
                  f"{_fmt(gt.get('context_max_root_speed_cm_s_worst'), 1)} (worst). Arrival: mean joint distance "
                  "of the last generated frame to the (changed) target. Style (judge): 40 frames or more only.", ""]
    unavailable = sorted({f"{name} {vn}: {r['unavailable']}" for name, m in methods.items()
                          for vn, r in m.get(key, {}).items() if "unavailable" in r})
    if unavailable:
        lines += ["Not produced: " + "; ".join(unavailable) + ".", ""]
    return lines


def _judge_tables(methods: dict[str, Any], report: dict[str, Any], key: str, gt_key: str) -> list[str]:
    """The judge's accuracy per requested style, a row per method (and the ground truth): on the locomotion
    cases one table per variant of 40 frames or more, on all contents the 40-frame gap's."""
    if not report.get("judge"):
        return []
    where = "locomotion cases" if key == "locomotion" else "all contents"
    lines: list[str] = []
    for v in report["variants"]:
        if v["frames"] < 40 or (key != "locomotion" and v["name"] != "gap40"):
            continue
        per: dict[str, dict[str, float] | None] = {}
        if v["ground_truth"]:
            per[GT_NAME] = report.get(gt_key, {}).get(v["name"], {}).get("judge_accuracy_by_style")
        per.update({name: m.get(key, {}).get(v["name"], {}).get("judge_accuracy_by_style") for name, m in methods.items()})
        lines += _per_style_table(f"Style (judge) per requested style, {v['label']}, {where}:", per)
        if v["name"] == "gap40":
            lines += _judge_gap40_tables(methods, report.get(gt_key, {}).get("gap40", {}), key, v["label"], where)
    return lines


def _judge_gap40_tables(methods: dict[str, Any], gt: dict[str, Any], key: str, label: str, where: str) -> list[str]:
    """The judge's other figures on the 40-frame gap, per style: with another style's clip, the mean
    probability of the requested style, and FMD in the judge's feature space."""

    def per(field: str) -> dict[str, dict[str, float] | None]:
        return {name: m.get(key, {}).get("gap40", {}).get(field) for name, m in methods.items()}

    lines = _per_style_table(f"Style (judge) with another style's clip, per requested (clip) style, {label}, {where}:",
                             per("judge_accuracy_cross_by_style"))
    lines += _per_style_table(f"With another style's clip, the share the judge reads as the context's own style, per "
                              f"context style, {label}, {where}:", per("judge_cross_as_context_by_style"))
    lines += _per_style_table(f"Mean probability the judge gives the requested style (same-style clip), {label}, "
                              f"{where}:", {GT_NAME: gt.get("judge_accuracy_prob_by_style"),
                                            **per("judge_accuracy_prob_by_style")})
    if key == "locomotion":
        for name, m in methods.items():
            read_as: dict[str, dict[str, float]] | None = m.get(key, {}).get("gap40", {}).get(
                "judge_accuracy_read_as_by_style")
            if read_as:
                lines += _per_style_table(f"What the judge reads {name}'s transitions as (a row per requested style, "
                                          f"shares of its cases), {label}, {where}:",
                                          {f"asked {s}": row for s, row in read_as.items()})
    fmd = {GT_NAME + " (split halves)": gt.get("judge_fmd_split_half_by_style"), **per("judge_fmd_by_style")}
    if any(fmd.values()):
        overall = {name: m.get(key, {}).get("gap40", {}).get("judge_fmd") for name, m in methods.items()}
        lines += _per_style_table(
            f"FMD in the judge's feature space (its standardised window statistics; no training network sees them) "
            f"to the real transitions of the same cases, per case style, {label}, {where}; overall: "
            + ", ".join(f"{n} {_fmt(x, 2)}" for n, x in overall.items())
            + f"; the ground-truth row is two halves of the real transitions, the floor at this number of cases "
              f"(overall {_fmt(gt.get('judge_fmd_split_half'), 2)}):", fmd, digits=2)
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


def _per_style_table(title: str, per_method: dict[str, dict[str, float] | None], digits: int = 3) -> list[str]:
    """A titled table of per-style figures, a row per method that has them (none: no lines)."""
    names = sorted({s for d in per_method.values() if d for s in d})
    if not names:
        return []
    rows = [[name] + [_fmt(d.get(s), digits) if s in d else "–" for s in names] for name, d in per_method.items() if d]
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
