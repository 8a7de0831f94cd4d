"""What the hardening tests measure of a real server while it is attacked: the CPU time its process spent
(from ``/proc``), and the gaps between the frames of a real-time stream read in a background thread."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from tests.service.conftest import bvh, walk
from tests.service.wsclient import Ws, start_message

_TICK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """User plus system CPU time of process ``pid`` so far (every thread), in seconds."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _TICK


class GapProbe:
    """``characters`` real-time characters on one WebSocket, restarted as each ends, read in a thread:
    the arrival time of every frame. Gaps are taken per character between :meth:`mark` calls."""

    def __init__(self, ws_url: str, characters: int = 4, query: str = "", frames: int | None = None) -> None:
        self.ws = Ws(ws_url, encoding="binary", query=query)
        self.frames = frames or int(self.ws.hello["model"]["max_transition_frames"])
        self.characters = characters
        self.arrivals: dict[str, list[float]] = {}
        self.errors: list[dict[str, Any]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._runs = 0

    def __enter__(self) -> GapProbe:
        for i in range(self.characters):
            self._start(f"probe{i}")
        self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        self._thread.join(10)
        self.ws.conn.close()

    def _start(self, base: str) -> None:
        self._runs += 1
        name = f"{base}.{self._runs}"
        self.arrivals[name] = []
        self.ws.send(start_message(name, self.frames, seed=self._runs, pace="realtime", style=bvh(walk(30))))

    def _read(self) -> None:
        for m in self.ws.messages_until(self._stop):
            name = m.get("character")
            if m["type"] == "frame" and name in self.arrivals:
                self.arrivals[name].append(time.monotonic())
            elif m["type"] == "end" and name in self.arrivals:
                self._start(name.rsplit(".", 1)[0])
            elif m["type"] == "error":
                self.errors.append(m)

    def gaps_ms(self, since: float, until: float) -> np.ndarray:
        """Every gap between consecutive frames of one character that arrived within ``[since, until]``."""
        out: list[np.ndarray] = []
        for times in self.arrivals.values():
            t = np.asarray([x for x in times if since <= x <= until])
            if len(t) > 1:
                out.append(np.diff(t) * 1e3)
        return np.concatenate(out) if out else np.zeros(0)

    def frames_in(self, since: float, until: float) -> int:
        return sum(sum(1 for x in times if since <= x <= until) for times in self.arrivals.values())


def quiet_cpu_rate(pid: int, seconds: float) -> tuple[float, float, float]:
    """Process ``pid``'s CPU seconds a second over the next ``seconds``, after 1 s for a stream to settle: the window's
    start and end (monotonic) and the rate."""
    time.sleep(1.0)
    start, cpu = time.monotonic(), cpu_seconds(pid)
    time.sleep(seconds)
    end = time.monotonic()
    return start, end, (cpu_seconds(pid) - cpu) / (end - start)


@dataclass
class FloodRun:
    """A flood process's run beside a :class:`GapProbe` stream: what it printed at its end, how long it ran, the
    server CPU it cost beyond the quiet rate, and the stream's frames a second before and during it."""

    out: dict[str, Any]
    seconds: float
    extra_cpu_s: float
    quiet_fps: float
    flood_fps: float
    gaps: np.ndarray  # the stream's frame gaps (ms) while the flood sent


def run_flood(pid: int, probe: GapProbe, module: str, args: list[str], flood_s: float) -> FloodRun:
    """``python -m module *args`` (a flood of ``flood_s`` seconds that prints ``ready`` when it starts and a JSON line
    when it ends) against the server process ``pid``, after a 3 s quiet window, while ``probe`` reads its stream."""
    quiet_from, quiet_until, quiet_rate = quiet_cpu_rate(pid, 3.0)
    flood = subprocess.Popen([sys.executable, "-m", module, *args], stdout=subprocess.PIPE, text=True,
                             cwd=Path(__file__).resolve().parents[2])
    assert flood.stdout is not None and flood.stdout.readline().strip() == "ready"
    since, flood_cpu = time.monotonic(), cpu_seconds(pid)  # from the flood's start
    out = json.loads(flood.stdout.readline())
    flood.wait(10)
    until = time.monotonic()
    return FloodRun(out=out, seconds=until - since,
                    extra_cpu_s=cpu_seconds(pid) - flood_cpu - quiet_rate * (until - since),
                    quiet_fps=probe.frames_in(quiet_from, quiet_until) / (quiet_until - quiet_from),
                    flood_fps=probe.frames_in(since, since + flood_s) / flood_s,  # while it sent (not while it drained)
                    gaps=probe.gaps_ms(since, since + flood_s))


def p99(values: np.ndarray) -> float:
    return float(np.percentile(values, 99)) if len(values) else float("inf")


def live(url: str, timeout_s: float = 10.0) -> float:
    """Seconds ``GET /v1/health/live`` took (inf when it failed)."""
    started = time.monotonic()
    try:
        httpx.get(url + "/v1/health/live", timeout=timeout_s).raise_for_status()
    except httpx.HTTPError:
        return float("inf")
    return time.monotonic() - started
