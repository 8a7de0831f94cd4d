"""Figures every load command reports: percentiles of a sample, Prometheus totals, and the machine they ran on."""

from __future__ import annotations

import os
import platform
from collections import defaultdict
from pathlib import Path


def percentiles(values: list[float], digits: int | None = None) -> dict[str, float]:
    if not values:
        return {"p50": float("nan"), "p99": float("nan"), "max": float("nan"), "n": 0}
    import numpy as np

    a = np.asarray(values)
    out = {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}
    return {**({k: round(v, digits) for k, v in out.items()} if digits is not None else out), "n": len(a)}


def metric_totals(text: str) -> dict[str, float]:
    """Every sample of a Prometheus text exposition, summed over its labels, by sample name."""
    from prometheus_client.parser import text_string_to_metric_families

    totals: dict[str, float] = defaultdict(float)
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            totals[sample.name] += float(sample.value)
    return totals


def machine() -> str:
    cpu = "unknown CPU"
    try:
        cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                    if line.startswith("model name")), cpu)
    except OSError:
        pass
    return f"{os.cpu_count()} cores ({cpu}), {platform.system()} {platform.release()}, Python {platform.python_version()}"
