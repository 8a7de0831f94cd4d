"""The ``rsmt loadtest`` command: a bounded load test of a service, with the figures a capacity plan needs.

    rsmt loadtest --spawn --characters 64 --seconds 60
    rsmt loadtest --url http://127.0.0.1:8000 --characters 256 --seconds 30 --soak
    rsmt loadtest --spawn --transition 100 --frames 40
    rsmt loadtest --url http://127.0.0.1:8000 --slow-clients --partial-headers 20000 --half-bodies 5000

Streams ``--characters`` characters at the model's fps (realtime pacing) for ``--seconds``, each
starting a new transition when the last one ends (at most ``--max-transitions`` each), over
connections of ``--per-connection`` characters, binary frames, through the Python client's
:class:`rsmt_client.AsyncStreamClient`. Prints, as JSON on stdout:

* frame delivery latency: each frame's arrival minus its due time on a clock started by the first
  frame of its transition (``arrival(0) + seq / fps``), p50/p99/max, and frames later than one frame
  period ("late": a player with a one-frame buffer would have stalled; one stall makes every later
  frame of that transition late); the gap between consecutive frames of a character (smoothness);
  missing or out-of-order frames ("dropped", expected 0);
* start latency (``start`` sent to first frame), throughput (frames/s), and batch sizes;
* the server's cost per streamed frame: its CPU time, the engine step time (from /metrics), and
  the difference, i.e. what the service adds beyond the engine step;
* ``--soak``: the server's RSS every ``--sample-s`` seconds.

``--transition N``: instead, N ``POST /v1/transition`` requests of ``--frames`` frames at
concurrency 1 (stopping early after ``--seconds``), p50/p99 against the engine's own time for
the same transition (as the server reports it, and measured in this process with ``--bundle``).
Progress goes to stderr every ``--progress-s`` seconds.

``--slow-clients``: instead, hold connections that stall in their headers or body and time
``/v1/health/ready`` meanwhile (:mod:`rsmt_cli.slow_clients`).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import zlib
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rsmt_cli.load_figures import machine, metric_totals, percentiles

SERVER_METRICS = ("process_cpu_seconds_total", "rsmt_step_seconds_sum", "rsmt_step_seconds_count", "rsmt_frames_sent_total",
                  "rsmt_step_cpu_seconds_total", "rsmt_character_prepare_seconds_sum",
                  "rsmt_character_prepare_seconds_count", "rsmt_batch_size_sum", "rsmt_batch_size_count",
                  "rsmt_tick_overhead_seconds_sum")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "loadtest", help="load-test a running service (or one it starts) over the Python client",
        description="Stream many characters at a service (or time POST /v1/transition requests) and report\n"
                    "delivery latency, lateness, drops, throughput and the server's CPU and memory per frame,\n"
                    "as JSON on stdout (progress on stderr).",
        epilog="examples:\n  rsmt loadtest --spawn --characters 64 --seconds 60\n"
               "  rsmt loadtest --url http://127.0.0.1:8000 --characters 256 --seconds 30 --soak\n"
               "  rsmt loadtest --spawn --transition 100 --frames 40",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--url", help="a running service (or --spawn)")
    p.add_argument("--api-key", default=os.environ.get("RSMT_API_KEY"), help="API key (default $RSMT_API_KEY)")
    p.add_argument("--spawn", action="store_true",
                   help="start `rsmt serve` on a free port (random-weight bundle unless --bundle); stopped at the end")
    p.add_argument("--bundle", type=Path, help="bundle for --spawn and for the in-process engine timing")
    p.add_argument("--threads", type=int, default=1, help="torch threads of the spawned server (default 1)")
    p.add_argument("--characters", type=int, default=64, help="characters streamed at once (default 64)")
    p.add_argument("--seconds", type=float, default=60.0,
                   help="no transition starts after this many seconds (default 60); with --transition, stop then")
    p.add_argument("--max-transitions", type=int, metavar="N",
                   help="transitions per character at most (default: as many as --seconds allows)")
    p.add_argument("--per-connection", type=int, default=8, help="characters per WebSocket connection (default 8)")
    p.add_argument("--frames", type=int, default=60, help="frames per transition (streaming) or per request (default 60)")
    p.add_argument("--soak", action="store_true", help="also sample the server's RSS")
    p.add_argument("--sample-s", type=float, default=5.0, metavar="S", help="RSS sampling period with --soak (default 5)")
    p.add_argument("--transition", type=int, metavar="N", help="measure N POST /v1/transition requests instead")
    p.add_argument("--progress-s", type=float, default=5.0, metavar="S",
                   help="a progress line on stderr every S seconds (default 5; 0: none)")
    p.add_argument("--json", type=Path, metavar="FILE", help="also write the figures here")
    from rsmt_cli.slow_clients import add_arguments as add_slow_client_arguments

    add_slow_client_arguments(p)
    p.set_defaults(func=_run, parser=p)


def _run(args: argparse.Namespace) -> int:
    from rsmt_client import RsmtError

    if not args.url and not args.spawn:
        args.parser.error("give --url of a running service or --spawn")
    for flag, value in (("--characters", args.characters), ("--per-connection", args.per_connection),
                        ("--frames", args.frames), ("--max-transitions", args.max_transitions or 1)):
        if value < 1:
            args.parser.error(f"{flag} must be at least 1")
    progress = Progress(args.progress_s)
    try:
        with _service(args) as (url, bundle):
            if args.slow_clients:
                from rsmt_cli.slow_clients import slow_client_load

                result = slow_client_load(args, url)
            elif args.transition:
                result = transition_load(url, args.api_key, args.transition, args.frames, bundle, args.seconds, progress)
            else:
                result = stream_load(url, args.api_key, StreamPlan(args.characters, args.seconds, args.per_connection,
                                                                   args.frames, args.max_transitions),
                                     args.sample_s if args.soak else None, progress)
    except RsmtError as exc:
        print(f"rsmt loadtest: {exc}", file=sys.stderr)
        return 1
    result["machine"] = machine()
    text = json.dumps(result, indent=1)
    print(text, flush=True)
    if args.json:
        args.json.write_text(text)
    return 0


class Progress:
    """Lines on stderr at most every ``every_s`` seconds (0: none)."""

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s
        self.began = self.last = time.monotonic()

    def due(self) -> bool:
        now = time.monotonic()
        if self.every_s <= 0 or now - self.last < self.every_s:
            return False
        self.last = now
        return True

    def say(self, text: str) -> None:
        print(f"rsmt loadtest: {time.monotonic() - self.began:5.1f} s  {text}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------------- payloads from the served skeleton
def rest_motion(model: dict[str, Any], frames: int, yaw_deg: float = 0.0, shift: tuple[float, float] = (0.0, 0.0),
                speed: float = 100.0) -> dict[str, Any]:
    """JSON poses: the model's rest pose walking straight (``speed`` units/s) along ``yaw_deg``, shifted on the ground."""
    import numpy as np  # here, not at the top: `rsmt --help` need not load it

    joints = len(model["skeleton"]["joints"])
    yaw = np.radians(yaw_deg)
    heading = np.array([np.sin(yaw), 0.0, np.cos(yaw)])
    root = np.array([shift[0], 90.0, shift[1]]) + np.arange(frames)[:, None] * heading * (speed / model["fps"])
    rot = np.zeros((frames, joints, 4))
    rot[..., 3] = 1.0
    rot[:, 0] = [0.0, np.sin(yaw / 2), 0.0, np.cos(yaw / 2)]
    return {"root_positions": root.round(4).tolist(), "rotations": rot.round(6).tolist()}


# ---------------------------------------------------------------------- streaming load
@dataclass(frozen=True)
class StreamPlan:
    characters: int
    seconds: float
    per_connection: int
    frames: int
    max_transitions: int | None = None


@dataclass
class _Character:
    name: str
    started_at: float = 0.0  # when `start` was sent
    first: float | None = None  # arrival of frame 0 of the current transition
    last: float = 0.0  # arrival of the previous frame
    expect: int = 0  # next seq expected
    transitions: int = 0


@dataclass
class _Stats:
    latency_ms: list[float] = field(default_factory=list)
    gap_ms: list[float] = field(default_factory=list)
    start_ms: list[float] = field(default_factory=list)
    frames: int = 0
    late: int = 0
    dropped: int = 0
    transitions: int = 0
    errors: list[str] = field(default_factory=list)

    def frame(self, c: _Character, seq: int, now: float, period: float) -> None:
        if seq != c.expect:
            self.dropped += abs(seq - c.expect)
        c.expect = seq + 1
        if c.first is None:
            c.first = now
            self.start_ms.append((now - c.started_at) * 1e3)
        else:
            self.gap_ms.append((now - c.last) * 1e3)
        c.last = now
        lateness = now - (c.first + seq * period)
        self.latency_ms.append(lateness * 1e3)
        self.late += lateness > period
        self.frames += 1


@dataclass
class _Run:
    """What every connection of one streaming load shares."""

    url: str
    api_key: str | None
    model: dict[str, Any]
    style_id: str
    plan: StreamPlan
    until: float
    stats: _Stats = field(default_factory=_Stats)

    def may_start(self, c: _Character) -> bool:
        limit = self.plan.max_transitions
        return time.monotonic() < self.until and (limit is None or c.transitions < limit)


async def _connection(run: _Run, names: list[str], stagger_s: float) -> None:
    import numpy as np
    from rsmt_client import AsyncStreamClient, Frame, RetryPolicy, RsmtError

    period = 1.0 / float(run.model["fps"])
    stats = run.stats
    rng = np.random.default_rng(zlib.crc32(names[0].encode()))
    context = rest_motion(run.model, run.model["context_frames"])
    chars = {n: _Character(n) for n in names}
    active: set[str] = set()
    await asyncio.sleep(stagger_s * rng.random())  # connections start spread over the first second
    async with await AsyncStreamClient.connect(run.url, api_key=run.api_key, encoding="binary", open_timeout=60,
                                               retry=RetryPolicy(attempts=3), max_queue=None) as client:

        async def start(c: _Character) -> None:
            c.transitions += 1
            stats.transitions += 1
            c.first, c.expect, c.started_at = None, 0, time.monotonic()
            target = rest_motion(run.model, 2, yaw_deg=float(rng.uniform(-90, 90)),
                                 shift=(float(rng.uniform(-200, 200)), float(rng.uniform(100, 300))))
            active.add(c.name)
            await client.start(context, target, run.plan.frames, style_id=run.style_id, pace="realtime",
                               seed=int(rng.integers(1 << 30)), character=c.name)

        for c in chars.values():
            await start(c)
        while active:
            try:
                item = await client.recv(timeout=max(5.0, run.until - time.monotonic() + 10))
            except RsmtError as exc:
                stats.errors.append(str(exc))
                return
            now = time.monotonic()
            if isinstance(item, Frame):
                if item.character in chars:
                    stats.frame(chars[item.character], item.seq, now, period)
                else:
                    stats.errors.append(f"a frame of unknown slot {item.slot}")
            elif item.get("type") == "end" and item.get("character") in chars:
                c = chars[item["character"]]
                active.discard(c.name)
                stats.dropped += max(0, run.plan.frames - c.expect)
                if run.may_start(c):
                    await start(c)
            elif item.get("type") == "error":
                stats.errors.append(f"{item.get('code')}: {item.get('message')}")
                active.discard(str(item.get("character", "")))


async def _soak_sampler(run: _Run, every_s: float, out: list[tuple[float, float]]) -> None:
    from rsmt_client import AsyncClient

    t0 = time.monotonic()
    async with AsyncClient(run.url, api_key=run.api_key, timeout=10) as client:
        while True:
            text = (await client.request("GET", "/metrics")).text
            out.append((time.monotonic() - t0, metric_totals(text)["process_resident_memory_bytes"] / 2**20))
            await asyncio.sleep(every_s)


async def _reporter(run: _Run, progress: Progress) -> None:
    began = time.monotonic()
    while True:
        await asyncio.sleep(min(1.0, progress.every_s))
        if progress.due():
            s = run.stats
            rate = s.frames / max(1e-9, time.monotonic() - began)
            progress.say(f"{s.frames} frames ({rate:.0f}/s), {s.transitions} transitions, {s.late} late, "
                         f"{s.dropped} dropped, {len(s.errors)} errors")


async def _stream(run: _Run, soak_s: float | None, rss: list[tuple[float, float]], progress: Progress) -> None:
    names = [f"L{i}" for i in range(run.plan.characters)]
    step = run.plan.per_connection
    loads = [_connection(run, names[i:i + step], stagger_s=1.0) for i in range(0, len(names), step)]
    helpers = [asyncio.create_task(_soak_sampler(run, soak_s, rss))] if soak_s else []
    if progress.every_s > 0:
        helpers.append(asyncio.create_task(_reporter(run, progress)))
    try:
        await asyncio.gather(*loads)
    finally:
        for task in helpers:
            task.cancel()
        await asyncio.gather(*helpers, return_exceptions=True)


def stream_load(url: str, api_key: str | None, plan: StreamPlan, soak_s: float | None, progress: Progress) -> dict[str, Any]:
    """Run ``plan`` against the service at ``url``; the figures as a dict (``soak_s``: sample the RSS that often)."""
    from rsmt_client import Client

    with Client(url, api_key=api_key) as http:
        model = http.model()
        plan = StreamPlan(plan.characters, plan.seconds, plan.per_connection, min(plan.frames, model["max_transition_frames"]),
                          plan.max_transitions)
        style_id = http.register_style(rest_motion(model, 60), name="load")["style_id"]
        before = metric_totals(http.request("GET", "/metrics").text)
        rss: list[tuple[float, float]] = []
        began = time.monotonic()
        run = _Run(url, api_key, model, style_id, plan, until=began + plan.seconds)
        asyncio.run(_stream(run, soak_s, rss, progress))
        wall = time.monotonic() - began
        after = metric_totals(http.request("GET", "/metrics").text)
    out = _stream_figures(run, wall, {name: after[name] - before[name] for name in SERVER_METRICS})
    if soak_s:
        out["rss_mib"] = [(round(t, 1), round(m, 1)) for t, m in rss]
    return out


def _stream_figures(run: _Run, wall: float, d: dict[str, float]) -> dict[str, Any]:
    stats, plan, fps = run.stats, run.plan, run.model["fps"]
    sent = max(1.0, d["rsmt_frames_sent_total"])
    return {
        "url": run.url, "characters": plan.characters, "seconds": plan.seconds, "per_connection": plan.per_connection,
        "max_transitions": plan.max_transitions, "transition_frames": plan.frames, "fps": fps, "wall_s": round(wall, 1),
        "transitions": stats.transitions, "frames_received": stats.frames, "throughput_fps": round(stats.frames / wall, 1),
        "target_fps": plan.characters * fps, "latency_ms": percentiles(stats.latency_ms, 2),
        "gap_ms": percentiles(stats.gap_ms, 2), "late_frames": stats.late,
        "late_fraction": round(stats.late / max(1, stats.frames), 4), "dropped_frames": stats.dropped,
        "start_latency_ms": percentiles(stats.start_ms, 1),
        "mean_batch": round(d["rsmt_batch_size_sum"] / max(1, d["rsmt_batch_size_count"]), 1),
        "server_cpu_ms_per_frame": round(d["process_cpu_seconds_total"] * 1e3 / sent, 3),
        "engine_step_cpu_ms_per_frame": round(d["rsmt_step_cpu_seconds_total"] * 1e3 / sent, 3),
        "engine_step_wall_ms_per_frame": round(d["rsmt_step_seconds_sum"] * 1e3 / sent, 3),
        "service_overhead_cpu_ms_per_frame": round(
            (d["process_cpu_seconds_total"] - d["rsmt_step_cpu_seconds_total"]) * 1e3 / sent, 3),
        "prepare_ms_per_start": round(d["rsmt_character_prepare_seconds_sum"] * 1e3
                                      / max(1, d["rsmt_character_prepare_seconds_count"]), 2),
        "tick_overhead_ms_per_frame": round(d["rsmt_tick_overhead_seconds_sum"] * 1e3 / sent, 3),
        "server_cpu_utilisation": round(d["process_cpu_seconds_total"] / wall, 2),
        "error_count": len(stats.errors), "errors": stats.errors[:5],
    }


# ---------------------------------------------------------------------- POST /v1/transition
def transition_load(url: str, api_key: str | None, requests: int, frames: int, bundle: Path | None, seconds: float,
                    progress: Progress) -> dict[str, Any]:
    """Requests at concurrency 1, each followed by the same transition on an in-process engine (when ``bundle``
    is given), so both see the same machine load; stops after ``requests`` or ``seconds``."""
    import numpy as np
    from rsmt_client import Client

    with Client(url, api_key=api_key) as http:
        model = http.model()
        context, target = rest_motion(model, model["context_frames"]), rest_motion(model, 2, 30.0, (80.0, 200.0))
        style = rest_motion(model, 60)
        style_id = http.register_style(style, name="t")["style_id"]
        local = _local_engine(bundle, context, target, frames, style) if bundle is not None else None
        http.transition(context, target, frames, style_id=style_id, seed=5)  # the first request warms caches
        timings: dict[str, list[float]] = defaultdict(list)
        deadline = time.monotonic() + seconds
        while len(timings["client_ms"]) < requests and time.monotonic() < deadline:
            t = time.perf_counter()
            poses = http.transition(context, target, frames, style_id=style_id, seed=5)
            timings["client_ms"].append((time.perf_counter() - t) * 1e3)
            for key in ("total", "engine", "parse"):
                timings[f"server_{key}_ms"].append(poses.timing_ms[key])
            if local is not None:
                timings["in_process_engine_ms"].append(local())
            if progress.due():
                progress.say(f"{len(timings['client_ms'])}/{requests} requests, client p50 "
                             f"{np.median(timings['client_ms']):.2f} ms")
    out: dict[str, Any] = {"url": url, "requests": len(timings["client_ms"]), "frames": frames}
    for key in ("client_ms", "server_total_ms", "server_engine_ms", "server_parse_ms", "in_process_engine_ms"):
        if key in timings:
            out[key] = percentiles(timings[key])
    return out


def _local_engine(bundle: Path, context: dict[str, Any], target: dict[str, Any], frames: int,
                  style_motion: dict[str, Any]) -> Callable[[], float]:
    """A callable timing ``prepare`` + ``generate`` of the same request in this process (1 torch thread,
    like the server's default); returns milliseconds."""
    import torch

    from model.inference.bundle import Bundle
    from model.inference.engine import Engine
    from model.motion.clip import Clip

    torch.set_num_threads(1)
    engine = Engine(Bundle.load(bundle), threads=1)

    def clip(m: dict[str, Any]) -> Clip:
        return Clip(engine.skeleton, torch.tensor(m["rotations"], dtype=torch.float32),
                    torch.tensor(m["root_positions"], dtype=torch.float32), engine.config.fps)

    style, _ = engine.encode_style(clip(style_motion))
    ctx, tgt = clip(context), clip(target)

    def run() -> float:
        t = time.perf_counter()
        engine.generate([engine.prepare(ctx, tgt, frames, style, seed=5)])
        return (time.perf_counter() - t) * 1e3

    run()
    return run


# ---------------------------------------------------------------------- a server to test
@contextmanager
def _service(args: argparse.Namespace) -> Iterator[tuple[str, Path | None]]:
    """The service to load: ``--url``, or one spawned for the run (and stopped after it)."""
    if not args.spawn:
        yield args.url.rstrip("/"), args.bundle
        return
    with tempfile.TemporaryDirectory(prefix="rsmt-load-") as folder, spawned(args.bundle, args.threads, Path(folder)) as (
            url, bundle):
        yield url, bundle


@contextmanager
def spawned(bundle: Path | None, threads: int, folder: Path, ready_s: float = 120.0) -> Iterator[tuple[str, Path]]:
    """``rsmt serve`` on a free 127.0.0.1 port (a random-weight bundle in ``folder`` unless ``bundle``), its log in
    ``folder/server.log``; SIGTERM (then kill) on the way out."""
    from rsmt_client import NO_RETRY, Client, RsmtError

    if bundle is None:
        from model.data.synthetic import synthetic_skeleton
        from model.inference.bundle import Bundle

        bundle = Bundle.create(synthetic_skeleton(), seed=0).save(folder / "rsmt")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"http://127.0.0.1:{port}"
    log_path = folder / "server.log"
    with log_path.open("w") as log:
        proc = subprocess.Popen([sys.executable, "-m", "rsmt_cli.main", "serve", "--host", "127.0.0.1", "--port", str(port),
                                 "--models", str(bundle), "--threads", str(threads)],
                                env={**os.environ, "RSMT_MAX_CHARACTERS_PER_CONNECTION": "256"}, stdout=log,
                                stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + ready_s
        with Client(url, retry=NO_RETRY, timeout=2) as probe:
            while not probe.ready():
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RsmtError("connection", f"the spawned server at {url} did not become ready "
                                                  f"(exit code {proc.poll()}): {log_path.read_text()[-2000:]}")
                time.sleep(0.2)
        yield url, bundle
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
