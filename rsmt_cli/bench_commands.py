"""The ``rsmt bench`` command: speed of a bundle beside the paper-size network, as a table and JSON."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from rsmt_cli.output_arguments import add_output_arguments, output_overrides


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("bench", help="per-frame latency, throughput, style encoding time, memory",
                              description="Benchmark a bundle and the paper-size network (random weights) on this machine.")
    p.add_argument("--model", type=Path, help="bundle folder (default: the bundled default model)")
    p.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's choice)")
    p.add_argument("--batch-sizes", default="1,8,32,128,512", help="concurrent characters to measure (comma-separated)")
    p.add_argument("--budget", type=float, default=8.0, metavar="S", help="seconds of throughput runs per model (default 8)")
    add_output_arguments(p, "the bundle")
    p.add_argument("--no-paper", action="store_true", help="skip the paper-size network")
    p.add_argument("--json", type=Path, metavar="FILE", help="also write the figures as JSON here")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    import torch

    from model.bench import (
        bench_engine,
        format_table,
        machine_description,
        machine_probe,
        paired_latency,
        paper_size_engine,
    )
    from model.inference.bundle import DEFAULT_BUNDLE, Bundle
    from model.inference.engine import Engine

    if args.threads:
        torch.set_num_threads(args.threads)
    began = time.monotonic()
    sizes = tuple(int(x) for x in args.batch_sizes.split(",") if x.strip())
    path = args.model or DEFAULT_BUNDLE
    bundle = Bundle.load(path)
    probe = machine_probe()
    engine = Engine(bundle, overrides=output_overrides(args))
    label = engine_label(engine, path)
    results = [bench_engine(engine, label, sizes, budget_s=args.budget)]
    paired = None
    if not args.no_paper:
        paper = paper_size_engine(bundle)
        results.append(bench_engine(paper, "paper-size, random weights", sizes, budget_s=args.budget))
        paired = paired_latency(engine, paper)
    print(format_table(results, probe))
    if paired is not None:
        print(f"Batch 1, the two taking turns ({paired.blocks} blocks of {paired.frames} frames each): "
              f"{paired.first_ms:.3f} ms against {paired.second_ms:.3f} ms, {paired.ratio:.3f}x the paper-size network's time.")
    report = {"machine": machine_description(), "probe": probe, "results": [r.to_dict() for r in results],
              "paired_batch1": paired.to_dict() if paired is not None else None,
              "seconds": round(time.monotonic() - began, 1)}
    print(f"\nfinished in {report['seconds']} s")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


def engine_label(engine: Any, path: Path) -> str:
    """The bench table's name for ``engine`` (loaded from ``path``): its model and the settings it runs with."""
    return f"{engine.name} ({path.name}; {engine.output.in_words()}{', int8 LSTM' if engine.inference.int8_lstm else ''})"
