"""The ``rsmt bench`` command: speed of a bundle beside the paper-size network, as a table and JSON."""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rsmt_cli.output_arguments import add_output_arguments, output_overrides

if TYPE_CHECKING:
    from model.bench import BenchResult, PairedLatency
    from model.inference.bundle import Bundle


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("bench", help="per-frame latency, throughput, style encoding time, memory",
                              description="Benchmark a bundle and the paper-size network (random weights) on this machine.")
    p.add_argument("--model", type=Path, help="bundle folder (default: the bundled default model)")
    p.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's choice)")
    p.add_argument("--batch-sizes", default="1,8,32,128,512", help="concurrent characters to measure (comma-separated)")
    p.add_argument("--budget", type=float, default=8.0, metavar="S", help="seconds of throughput runs per model (default 8)")
    add_output_arguments(p, "the bundle")
    p.add_argument("--backend", choices=["torch", "onnxruntime", "both"], default="torch",
                   help="what runs the bundle's per-frame graphs (default torch); both: each, side by side, with "
                        "their batch-1 times measured taking turns")
    p.add_argument("--source", choices=["network", "matching", "hybrid", "all"], default="network",
                   help="what makes the motion (as the service's RSMT_SOURCE; default network); all: each, side by side "
                        "(matching and hybrid need a bundle with a motion database, and run on torch)")
    p.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                   help="time by the wall clock (default) or by this process's CPU time, which leaves out the "
                        "time a loaded machine keeps it waiting for a core")
    p.add_argument("--no-paper", action="store_true", help="skip the paper-size network")
    p.add_argument("--json", type=Path, metavar="FILE", help="also write the figures as JSON here")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    import torch

    from model.bench import CLOCKS, machine_description, machine_probe
    from model.inference.bundle import DEFAULT_BUNDLE, Bundle

    if args.threads:
        torch.set_num_threads(args.threads)
    began = time.monotonic()
    sizes = tuple(int(x) for x in args.batch_sizes.split(",") if x.strip())
    path = args.model or DEFAULT_BUNDLE
    bundle = Bundle.load(path)
    clock = CLOCKS[args.clock]
    probe = machine_probe(clock=clock)
    results, paired, engines = _measure(args, bundle, path, sizes, clock)
    _print_figures(args, results, probe, paired, engines)
    search = _database_search(bundle, clock)
    report = {"machine": machine_description(), "clock": args.clock, "probe": probe, "results": [r.to_dict() for r in results],
              "paired_batch1": {k: v.to_dict() for k, v in paired.items()} or None,
              "database_search": search, "seconds": round(time.monotonic() - began, 1)}
    print(f"\nfinished in {report['seconds']} s")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


def _measure(args: argparse.Namespace, bundle: Bundle, path: Path, sizes: tuple[int, ...],
             clock: Callable[[], float]) -> tuple[list[BenchResult], dict[str, PairedLatency], int]:
    """The bundle's figures on each backend asked for (then the paper-size network's, unless skipped), the
    batch-1 times measured taking turns, and how many of the figures are the bundle's."""
    from model.bench import bench_engine, paired_latency, paper_size_engine
    from model.export.backends import with_backend
    from model.inference.engine import Engine

    backends = ["torch", "onnxruntime"] if args.backend == "both" else [args.backend]
    sources = ["network", "matching", "hybrid"] if args.source == "all" else [args.source]
    engines = [with_backend(Engine(bundle, overrides=output_overrides(args), source=s), b)
               for s in sources for b in (backends if s == "network" else ["torch"])]
    results = [bench_engine(engine, engine_label(engine, path), sizes, budget_s=args.budget, clock=clock)
               for engine in engines]
    paired: dict[str, PairedLatency] = {}
    if not args.no_paper:
        paper = paper_size_engine(bundle)
        results.append(bench_engine(paper, "paper-size, random weights", sizes, budget_s=args.budget, clock=clock))
        for engine in engines:
            name = engine.source if engine.source != "network" else ("onnxruntime" if _on_onnxruntime(engine) else "torch")
            paired[f"{name}_vs_paper"] = paired_latency(engine, paper, clock=clock)
    if len(backends) == 2 and "network" in sources:
        paired["torch_vs_onnxruntime"] = paired_latency(engines[0], engines[1], clock=clock)
    return results, paired, len(engines)


def _print_figures(args: argparse.Namespace, results: list[BenchResult], probe: dict[str, float],
                   paired: dict[str, PairedLatency], engines: int) -> None:
    """The table, each pair's turn-taking batch-1 times and how the first ``engines`` results scale with characters."""
    from model.bench import format_table

    if args.clock == "cpu":
        print("Times are this process's CPU time (--clock cpu), not the wall clock.")
    print(format_table(results, probe))
    for key, pair in paired.items():
        first, second = key.split("_vs_")
        print(f"Batch 1, {first} and {second} taking turns ({pair.blocks} blocks of {pair.frames} frames each): "
              f"{pair.first_ms:.3f} ms against {pair.second_ms:.3f} ms, {pair.ratio:.3f}x {second}'s time.")
    for r in results[:engines]:
        one = r.throughput.get(1)
        if one:
            rates = ", ".join(f"{n} characters {v / one:.1f}x" for n, v in sorted(r.throughput.items()) if n > 1)
            print(f"{r.name}: {rates} one character's rate.")


def _database_search(bundle: Bundle, clock: Callable[[], float]) -> dict[str, float] | None:
    """The bundle's database search times at batch 1, printed (None where it has no database)."""
    from model.bench import database_search_ms

    if bundle.database is None:
        return None
    search = database_search_ms(bundle.database, clock=clock)
    print(f"Database search at batch 1 over {int(search['rows']):,} rows: the window a 40-frame transition starts from "
          f"{search['window_search_ms']:.3f} ms (once per transition and retarget), the nearest pose and trajectory "
          f"{search['pose_search_ms']:.3f} ms.")
    return search


def engine_label(engine: Any, path: Path) -> str:
    """The bench table's name for ``engine`` (loaded from ``path``): its model and the settings it runs with."""
    strength = engine.inference.style_strength
    source = f"{engine.source} source; " if engine.source != "network" else ""
    return (f"{engine.name} ({path.name}; {source}{engine.output.in_words()}"
            f"{', int8 LSTM' if engine.inference.int8_lstm and engine.source != 'matching' else ''}"
            f"{f', style strength {strength:g}' if strength != 1.0 else ''}{', onnxruntime' if _on_onnxruntime(engine) else ''})")


def _on_onnxruntime(engine: Any) -> bool:
    from model.export.backends import backend_of

    return backend_of(engine) == "onnxruntime"
