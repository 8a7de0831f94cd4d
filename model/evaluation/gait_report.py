"""The yardstick's gait and second-judge table (Markdown), printed beside the main tables of :mod:`model.evaluation.report`.

Per variant, a row per method (and the ground truth where it exists): toe foot skate (and the capture's
on the same cases), the backward share, the longest airborne run, the largest root speed, and the second
judge's style accuracy with a same-style and another style's clip.
"""

from __future__ import annotations

import math
from typing import Any

GT_NAME = "ground truth"


def _fmt(x: Any, digits: int = 3) -> str:
    if x is None:
        return "–"
    if isinstance(x, float):
        return "nan" if math.isnan(x) else f"{x:.{digits}f}"
    return str(x)


def gait_tables(report: dict[str, Any], key: str, gt_key: str) -> list[str]:
    """The table for ``key`` (``locomotion`` or ``variants``), ground truth rows from ``report[gt_key]``."""
    methods = report["methods"]
    judge2 = bool(report.get("judge2"))
    header = ["variant", "method", "toe skate cm/frame", "GT toe skate", "backward share", "longest airborne frames",
              "max root speed cm/s (mean / worst)"]
    if judge2:
        header += ["style (judge 2)", "style (judge 2), other-style clip"]
    rows: list[list[str]] = []
    for v in report["variants"]:
        if v.get("locomotion_only") and key != "locomotion":
            continue
        gt = report.get(gt_key, {}).get(v["name"]) if v["ground_truth"] else None
        entries = ([(GT_NAME, gt)] if gt else []) + [(n, m.get(key, {}).get(v["name"], {})) for n, m in methods.items()]
        for name, r in entries:
            if "unavailable" in r:
                rows.append([v["label"], name] + ["n/a"] * (len(header) - 2))
                continue
            cells = [v["label"], name, _fmt(r.get("toe_skate")), _fmt(r.get("toe_skate_gt", gt and gt.get("toe_skate"))),
                     _fmt(r.get("backward_share")),
                     f"{_fmt(r.get('longest_airborne_frames'))} (mean {_fmt(r.get('longest_airborne_frames_mean'), 1)})",
                     f"{_fmt(r.get('max_root_speed_cm_s'), 1)} / {_fmt(r.get('max_root_speed_cm_s_worst'), 1)}"]
            if judge2:
                cells += [_fmt(r.get("judge2_accuracy")), _fmt(r.get("judge2_accuracy_cross"))]
            rows.append(cells)
    where = "locomotion cases" if key == "locomotion" else "all contents"
    lines = [f"### Feet, direction and speed{' and the second judge' if judge2 else ''}, {where}", "",
             "| " + " | ".join(header) + " |", "| " + " | ".join(["---"] * len(header)) + " |",
             *("| " + " | ".join(r) + " |" for r in rows), "",
             "Toe skate: the two toe joints against their rest height 4.25 cm above y = 0, contact weight "
             "clamp(2 - 2^(h/2.5), 0, 1), horizontal cm/frame from the last context frame on. Backward share: of the "
             "frame steps whose hips move faster than 30 cm/s, the share against the body's facing (mean over cases). "
             "Longest airborne: the worst case's longest run of frames with both toes 15 cm above rest."]
    if judge2:
        j = report["judge2"]
        lines.append(f"Judge 2 (`{j['path']}`): {j['kind']}; 40 frames or more only.")
    return [*lines, ""]
