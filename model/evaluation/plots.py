"""Pictures of an evaluation: metrics over gap length, changed controls, and a contact sheet of transitions.

Drawn with matplotlib's Agg backend (files only, no display). The contact sheet shows a few
40-frame transitions as side views (the canonical frame's forward axis Z to the right, Y up): one
row per case, one column per method with the ground truth first; every 5th frame is drawn, later
frames in warmer colours and each pose moved a fixed step to the right of the previous one (on
top of its own travel) so the poses do not overlap; the dashed grey figure is the target pose.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import torch

from model.motion.skeleton import Skeleton

if TYPE_CHECKING:
    from matplotlib.axes import Axes

GT_NAME = "ground truth"
GAP_METRICS = (
    ("l2p", "L2P (standardised)"),
    ("l2q", "L2Q"),
    ("npss_x100", "100 × NPSS"),
    ("mpjpe_cm", "mean joint error (cm)"),
    ("foot_skate", "foot skate (cm/frame)"),
    ("diversity_cm", "diversity (cm)"),
)


def _plt() -> ModuleType:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def plot_gap_metrics(report: dict[str, Any], path: str | Path) -> Path:
    """A panel per metric, value against gap length (10/20/40), a line per method; GT foot skate dashed."""
    plt = _plt()
    variants = [v for v in report["variants"] if v["ground_truth"]]
    gaps = [v["gap"] for v in variants]
    fig, axes = plt.subplots(2, 3, figsize=(13, 7.5))
    for ax, (key, title) in zip(axes.flat, GAP_METRICS):
        for name, m in report["methods"].items():
            ys = [m["variants"].get(v["name"], {}).get(key) for v in variants]
            if all(y is None for y in ys):
                continue
            ax.plot(gaps, [float("nan") if y is None else y for y in ys], marker="o", label=name)
        if key == "foot_skate":
            ys = [report["ground_truth"].get(v["name"], {}).get("foot_skate") for v in variants]
            ax.plot(gaps, ys, "k--", marker="x", label=GT_NAME)
        ax.set_title(title)
        ax.set_xlabel("gap (frames)")
        ax.set_xticks(gaps)
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=8)
        else:
            ax.text(0.5, 0.5, "no method samples", ha="center", va="center", transform=ax.transAxes, color="grey")
    fig.suptitle(f"{report['split']} split, {report['cases']} cases: metrics over gap length")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_controls(report: dict[str, Any], path: str | Path) -> Path:
    """Grouped bars per changed control: last-frame error, foot skate (and style accuracy with a classifier)."""
    plt = _plt()
    variants = [v for v in report["variants"] if not v["ground_truth"]]
    keys = [("last_frame_cm", "last-frame error (cm)"), ("foot_skate", "foot skate (cm/frame)")]
    if report.get("classifier"):
        keys.append(("style_accuracy", "style accuracy (same-style clip)"))
    names = list(report["methods"])
    fig, axes = plt.subplots(1, len(keys), figsize=(5.2 * len(keys), 4.2))
    width = 0.8 / max(1, len(names))
    for ax, (key, title) in zip(axes, keys):
        for k, name in enumerate(names):
            ys = [report["methods"][name]["variants"].get(v["name"], {}).get(key) for v in variants]
            xs = [i + (k - (len(names) - 1) / 2) * width for i in range(len(variants))]
            ax.bar(xs, [0.0 if y is None else y for y in ys], width, label=name)
            for x, y in zip(xs, ys):
                if y is None:
                    ax.text(x, 0, "n/a", ha="center", va="bottom", fontsize=7, rotation=90)
        if key == "style_accuracy":
            ax.axhline(1.0 / max(1, len(report["classifier"]["styles"])), color="k", ls="--", lw=1, label="chance")
        ax.set_xticks(range(len(variants)))
        ax.set_xticklabels([v["label"].replace("gap 40, ", "") for v in variants])
        ax.set_title(title)
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=8)
    fig.suptitle("changed controls on the 40-frame gap")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _draw_pose(ax: Axes, pose: torch.Tensor, parents: tuple[int, ...], x_shift: float, **style: Any) -> None:
    for j, p in enumerate(parents):
        if p < 0:
            continue
        ax.plot([pose[p, 2] + x_shift, pose[j, 2] + x_shift], [pose[p, 1], pose[j, 1]], **style)


def contact_sheet(
    render: dict[str, dict[str, torch.Tensor]],
    targets: torch.Tensor,
    labels: list[str],
    skeleton: Skeleton,
    path: str | Path,
    variant: str = "gap40",
    every: int = 5,
    spacing: float = 45.0,
) -> Path | None:
    """Side views of ``render[method][variant]`` (``[R, N+1, J, 3]`` canonical positions).

    Args:
        targets: ``[R, J, 3]`` canonical target pose of each rendered case.
        labels: a caption per rendered case.
    """
    plt = _plt()
    from matplotlib import cm

    methods = [m for m in render if variant in render[m]]
    if not methods or targets.shape[0] == 0:
        return None
    rows = targets.shape[0]
    fig, axes = plt.subplots(rows, len(methods), figsize=(4.6 * len(methods), 2.6 * rows), squeeze=False)
    parents = skeleton.parents
    for r in range(rows):
        lo, hi = float("inf"), float("-inf")
        for c, name in enumerate(methods):
            ax = axes[r][c]
            pos = render[name][variant][r]
            n = pos.shape[0] - 1
            frames = list(range(0, n + 1, every))
            if frames[-1] != n:
                frames.append(n)
            for k, f in enumerate(frames):
                colour = cm.plasma(0.1 + 0.8 * f / max(1, n))
                _draw_pose(ax, pos[f], parents, k * spacing, color=colour, lw=1.4)
            _draw_pose(ax, targets[r], parents, (len(frames) - 1) * spacing, color="0.55", lw=1.0, ls="--")
            ax.axhline(0.0, color="0.8", lw=0.8)
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(name, fontsize=11)
            if c == 0:
                ax.text(0.01, 0.98, labels[r], transform=ax.transAxes, ha="left", va="top", fontsize=7,
                        bbox={"facecolor": "white", "alpha": 0.7, "lw": 0})
            x0, x1 = ax.get_xlim()
            lo, hi = min(lo, x0), max(hi, x1)
        for c in range(len(methods)):
            axes[r][c].set_xlim(lo, hi)
            axes[r][c].set_ylim(-10, 200)
    fig.suptitle(f"{variant}: every {every}th frame, side view (forward to the right); dashed: target", fontsize=11)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
