"""A bounded load test of a running service on 127.0.0.1 (or one it starts), with figures a capacity plan needs.

Streams ``--characters`` characters at the model's fps (realtime pacing) for ``--seconds``, each
starting a new transition when the last one ends, over connections of ``--per-connection``
characters, binary frames. Reports:

* frame delivery latency: each frame's arrival minus its due time on a clock started by the first
  frame of its transition (``arrival(0) + seq / fps``), p50/p99/max, and frames later than one frame
  period ("late": a player with a one-frame buffer would have stalled; one stall makes every later
  frame of that transition late); the gap between consecutive frames of a character (smoothness);
  missing or out-of-order frames ("dropped", expected 0);
* start latency (``start`` sent to first frame), throughput (frames/s), and batch sizes;
* the server's cost per streamed frame: its CPU time, the engine step time (wall, from /metrics),
  and the difference, i.e. what the service adds beyond the engine step;
* ``--soak``: the server's RSS every ``--sample-s`` seconds.

``--transition N``: instead, N ``POST /v1/transition`` requests of ``--frames`` frames at
concurrency 1, p50/p99 against the engine's own time for the same transition (measured in this
process on the same bundle, and as the server reports it).

Examples::

    python -m service.loadtest --spawn --characters 64 --seconds 60
    python -m service.loadtest --url http://127.0.0.1:8000 --characters 256 --seconds 30 --soak
    python -m service.loadtest --spawn --transition 100 --frames 40
"""

from __future__ import annotations

import argparse
import asyncio
import atexit
import json
import os
import platform
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np


# ---------------------------------------------------------------------- payloads from the served skeleton
def rest_motion(model: dict, frames: int, yaw_deg: float = 0.0, shift: tuple[float, float] = (0.0, 0.0),
                speed: float = 100.0) -> dict:
    """JSON poses: the model's rest pose walking straight (``speed`` units/s) along ``yaw_deg``, shifted on the ground."""
    joints = len(model["skeleton"]["joints"])
    fps = model["fps"]
    yaw = np.radians(yaw_deg)
    heading = np.array([np.sin(yaw), 0.0, np.cos(yaw)])
    root = np.array([shift[0], 90.0, shift[1]]) + np.arange(frames)[:, None] * heading * (speed / fps)
    rot = np.zeros((frames, joints, 4))
    rot[..., 3] = 1.0
    rot[:, 0] = [0.0, np.sin(yaw / 2), 0.0, np.cos(yaw / 2)]
    return {"root_positions": root.round(4).tolist(), "rotations": rot.round(6).tolist()}


def _percentiles(values: list[float]) -> dict[str, float]:
    if not values:
        return {"p50": float("nan"), "p99": float("nan"), "max": float("nan"), "n": 0}
    a = np.asarray(values)
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max()), "n": len(a)}


def _metric(text: str, name: str, labels: str = "") -> float:
    total = 0.0
    for m in re.finditer(rf"^{re.escape(name)}(\{{[^}}]*\}})? (\S+)$", text, re.M):
        if labels and labels not in (m.group(1) or ""):
            continue
        total += float(m.group(2))
    return total


def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()} cores ({cpu}), {platform.system()} {platform.release()}, Python {platform.python_version()}"


# ---------------------------------------------------------------------- streaming load
@dataclass
class _Char:
    name: str
    slot: int = -1
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
    errors: list[str] = field(default_factory=list)


async def _connection(url: str, model: dict, style_id: str, names: list[str], frames: int, until: float,
                      stats: _Stats, stagger_s: float) -> None:
    import websockets

    fps = model["fps"]
    period = 1.0 / fps
    async with websockets.connect(url + "?encoding=binary", compression=None, proxy=None, max_queue=None,
                                  open_timeout=60, ping_interval=None) as ws:
        json.loads(await ws.recv())  # hello
        chars = {n: _Char(n) for n in names}
        by_slot: dict[int, _Char] = {}
        active: set[str] = set()  # characters in a transition
        rng = np.random.default_rng(abs(hash(names[0])) % 2**32)
        context = rest_motion(model, model["context_frames"])

        async def start(c: _Char) -> None:
            c.transitions += 1
            c.first, c.expect, c.started_at = None, 0, time.monotonic()
            target = rest_motion(model, 2, yaw_deg=float(rng.uniform(-90, 90)),
                                 shift=(float(rng.uniform(-200, 200)), float(rng.uniform(100, 300))))
            active.add(c.name)
            await ws.send(json.dumps({"type": "start", "character": c.name, "context": context, "target": target,
                                      "frames": frames, "style_id": style_id, "pace": "realtime",
                                      "seed": int(rng.integers(1 << 30))}))

        await asyncio.sleep(stagger_s * rng.random())  # connections start spread over the first second
        for c in chars.values():
            await start(c)
        while active:
            try:
                message = await asyncio.wait_for(ws.recv(), timeout=max(5.0, until - time.monotonic() + 10))
            except TimeoutError:
                stats.errors.append("timeout waiting for frames")
                return
            now = time.monotonic()
            if isinstance(message, bytes):
                slot, seq = struct.unpack_from("<ff", message)
                c = by_slot[int(slot)]
                seq = int(seq)
                if seq != c.expect:
                    stats.dropped += abs(seq - c.expect)
                c.expect = seq + 1
                if c.first is None:
                    c.first = now
                    stats.start_ms.append((now - c.started_at) * 1e3)
                else:
                    stats.gap_ms.append((now - c.last) * 1e3)
                c.last = now
                lateness = now - (c.first + seq * period)
                stats.latency_ms.append(lateness * 1e3)
                stats.late += lateness > period
                stats.frames += 1
                continue
            m = json.loads(message)
            if m["type"] == "started":
                chars[m["character"]].slot = m["slot"]
                by_slot[m["slot"]] = chars[m["character"]]
            elif m["type"] == "end":
                c = chars[m["character"]]
                active.discard(c.name)
                if c.expect != frames:
                    stats.dropped += frames - c.expect
                if now < until:
                    await start(c)
            elif m["type"] == "error":
                stats.errors.append(f"{m['code']}: {m['message']}")
                active.discard(m.get("character", ""))


async def _soak_sampler(url: str, until: float, every_s: float, out: list[tuple[float, float]]) -> None:
    t0 = time.monotonic()
    async with httpx.AsyncClient(base_url=url, timeout=10) as client:
        while time.monotonic() < until + 1:
            text = (await client.get("/metrics")).text
            out.append((time.monotonic() - t0, _metric(text, "process_resident_memory_bytes") / 2**20))
            await asyncio.sleep(every_s)


def stream_load(url: str, characters: int, seconds: float, per_connection: int, frames: int, soak: bool,
                sample_s: float) -> dict:
    ws_url = url.replace("http", "ws", 1) + "/v1/stream"
    model = httpx.get(url + "/v1/model", timeout=30).json()
    frames = min(frames, model["max_transition_frames"])
    style = httpx.post(url + "/v1/styles", json={"name": "load", "motion": rest_motion(model, 60)}, timeout=60).json()
    before = httpx.get(url + "/metrics", timeout=30).text
    stats = _Stats()
    rss: list[tuple[float, float]] = []

    async def main() -> None:
        until = time.monotonic() + seconds
        names = [f"L{i}" for i in range(characters)]
        groups = [names[i : i + per_connection] for i in range(0, len(names), per_connection)]
        tasks = [_connection(ws_url, model, style["style_id"], g, frames, until, stats, stagger_s=1.0) for g in groups]
        if soak:
            tasks.append(_soak_sampler(url, until, sample_s, rss))
        await asyncio.gather(*tasks)

    began = time.monotonic()
    asyncio.run(main())
    wall = time.monotonic() - began
    after = httpx.get(url + "/metrics", timeout=30).text
    d = {name: _metric(after, name) - _metric(before, name) for name in (
        "process_cpu_seconds_total", "rsmt_step_seconds_sum", "rsmt_step_seconds_count", "rsmt_frames_sent_total",
        "rsmt_step_cpu_seconds_total", "rsmt_character_prepare_seconds_sum", "rsmt_character_prepare_seconds_count",
        "rsmt_batch_size_sum", "rsmt_batch_size_count", "rsmt_tick_overhead_seconds_sum")}
    sent = max(1.0, d["rsmt_frames_sent_total"])
    out = {
        "characters": characters, "seconds": seconds, "per_connection": per_connection, "transition_frames": frames,
        "fps": model["fps"], "wall_s": round(wall, 1), "frames_received": stats.frames,
        "throughput_fps": round(stats.frames / wall, 1), "target_fps": characters * model["fps"],
        "latency_ms": {k: round(v, 2) if isinstance(v, float) else v for k, v in _percentiles(stats.latency_ms).items()},
        "gap_ms": {k: round(v, 2) if isinstance(v, float) else v for k, v in _percentiles(stats.gap_ms).items()},
        "late_frames": stats.late, "late_fraction": round(stats.late / max(1, stats.frames), 4),
        "dropped_frames": stats.dropped,
        "start_latency_ms": {k: round(v, 1) if isinstance(v, float) else v for k, v in _percentiles(stats.start_ms).items()},
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
        "errors": stats.errors[:5],
    }
    if soak:
        out["rss_mib"] = [(round(t, 1), round(m, 1)) for t, m in rss]
    return out


# ---------------------------------------------------------------------- POST /v1/transition
def transition_load(url: str, requests: int, frames: int, bundle: Path | None) -> dict:
    """Requests at concurrency 1, each followed by the same transition on an in-process engine (when
    ``bundle`` is given), so both see the same machine load."""
    model = httpx.get(url + "/v1/model", timeout=30).json()
    body = {"context": rest_motion(model, model["context_frames"]), "target": rest_motion(model, 2, 30.0, (80.0, 200.0)),
            "frames": frames, "seed": 5}
    style = rest_motion(model, 60)
    body["style_id"] = httpx.post(url + "/v1/styles", json={"name": "t", "motion": style}, timeout=60).json()["style_id"]
    local = _local_engine(bundle, body, style) if bundle is not None else None
    client_ms, engine_ms, total_ms, parse_ms, local_ms = [], [], [], [], []
    with httpx.Client(base_url=url, timeout=60) as client:
        client.post("/v1/transition", json=body)
        for _ in range(requests):
            t = time.perf_counter()
            r = client.post("/v1/transition", json=body)
            client_ms.append((time.perf_counter() - t) * 1e3)
            timing = r.json()["timing_ms"]
            engine_ms.append(timing["engine"])
            total_ms.append(timing["total"])
            parse_ms.append(timing["parse"])
            if local is not None:
                local_ms.append(local())
    out = {"requests": requests, "frames": frames, "client_ms": _percentiles(client_ms),
           "server_total_ms": _percentiles(total_ms), "server_engine_ms": _percentiles(engine_ms),
           "server_parse_ms": _percentiles(parse_ms)}
    if local_ms:
        out["in_process_engine_ms"] = _percentiles(local_ms)
    return out


def _local_engine(bundle: Path, body: dict, style_motion: dict):
    """A callable timing ``prepare`` + ``generate`` of the same request in this process (1 torch thread,
    like the server's default); returns milliseconds."""
    import torch

    from model.inference.bundle import Bundle
    from model.inference.engine import Engine
    from model.motion.clip import Clip

    torch.set_num_threads(1)
    engine = Engine(Bundle.load(bundle), threads=1)

    def clip(m: dict) -> Clip:
        return Clip(engine.skeleton, torch.tensor(m["rotations"], dtype=torch.float32),
                    torch.tensor(m["root_positions"], dtype=torch.float32), engine.config.fps)

    style, _ = engine.encode_style(clip(style_motion))
    ctx, tgt = clip(body["context"]), clip(body["target"])

    def run() -> float:
        t = time.perf_counter()
        engine.generate([engine.prepare(ctx, tgt, body["frames"], style, seed=5)])
        return (time.perf_counter() - t) * 1e3

    run()
    return run


# ---------------------------------------------------------------------- a server to test
def spawn(bundle: Path | None, threads: int, env: dict[str, str]) -> tuple[subprocess.Popen, str, Path]:
    if bundle is None:
        from model.data.synthetic import synthetic_skeleton
        from model.inference.bundle import Bundle

        folder = tempfile.mkdtemp(prefix="rsmt-load-")
        atexit.register(shutil.rmtree, folder, ignore_errors=True)
        bundle = Bundle.create(synthetic_skeleton(), seed=0).save(Path(folder) / "rsmt")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(
        ["rsmt", "serve", "--host", "127.0.0.1", "--port", str(port), "--models", str(bundle), "--threads", str(threads)],
        env={**os.environ, "RSMT_MAX_CHARACTERS_PER_CONNECTION": "256", **env},
    )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            if httpx.get(url + "/v1/health/ready", timeout=1).status_code == 200:
                return proc, url, bundle
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    proc.kill()
    raise SystemExit("the spawned server did not become ready")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m service.loadtest", description=__doc__.split("\n\n")[0])
    p.add_argument("--url", help="a running service (default: start one with --spawn)")
    p.add_argument("--spawn", action="store_true",
                   help="start `rsmt serve` on a free port (random-weight bundle unless --bundle)")
    p.add_argument("--bundle", type=Path, help="bundle for --spawn and for the in-process engine timing")
    p.add_argument("--threads", type=int, default=1, help="torch threads of the spawned server (default 1)")
    p.add_argument("--characters", type=int, default=64)
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--per-connection", type=int, default=8)
    p.add_argument("--frames", type=int, default=60, help="frames per transition (streaming) or per request")
    p.add_argument("--soak", action="store_true", help="also sample the server's RSS")
    p.add_argument("--sample-s", type=float, default=5.0)
    p.add_argument("--transition", type=int, metavar="N", help="measure N POST /v1/transition requests instead")
    p.add_argument("--json", type=Path, help="also write the figures here")
    args = p.parse_args(argv)
    if not args.url and not args.spawn:
        p.error("give --url of a running service or --spawn")
    proc = None
    bundle = args.bundle
    try:
        if args.spawn:
            proc, url, bundle = spawn(args.bundle, args.threads, {})
        else:
            url = args.url.rstrip("/")
        if args.transition:
            result = transition_load(url, args.transition, args.frames, bundle)
        else:
            result = stream_load(url, args.characters, args.seconds, args.per_connection, args.frames, args.soak,
                                 args.sample_s)
        result["machine"] = machine()
        print(json.dumps(result, indent=1))
        if args.json:
            args.json.write_text(json.dumps(result, indent=1))
    finally:
        if proc is not None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
    return 0


if __name__ == "__main__":
    sys.exit(main())
