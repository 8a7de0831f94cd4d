"""Speed bench: per-frame latency at batch 1, throughput across many characters, style encoding
time and memory, for a bundle and for the paper-size network at random weights, with a machine
probe so figures from different machines compare as ratios.
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from model.data.synthetic import synthetic_walk
from model.inference.bundle import Bundle
from model.inference.engine import CharacterBatch, EncodedStyle, Engine
from model.motion.clip import Clip
from model.nets.manifold import ManifoldConfig
from model.nets.sampler import SamplerConfig
from model.retrieval.database import MotionDatabase

PAPER_SAMPLER: dict[str, int] = {"width": 512, "rnn": 1024, "head": 1024, "style_channels": 512, "phases": 10, "latent": 32}
# What the bench times with: the wall clock (what a caller waits), or this process's CPU time (every thread of
# it), which leaves out the time a loaded machine keeps it waiting for a core (--clock cpu).
CLOCKS: dict[str, Callable[[], float]] = {"wall": time.perf_counter, "cpu": time.process_time}
PAPER_MANIFOLD = {"experts": 8, "hidden": 512, "gate_hidden": 128, "encoder_hidden": 512, "phases": 10, "latent": 32}


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:  # not Linux
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def machine_probe(seconds: float = 1.0, clock: Callable[[], float] = time.perf_counter) -> dict[str, float]:
    """A fixed fp32 matrix product (GFLOP/s) and a 64 MiB memory copy (GB/s) on this machine, timed by ``clock``."""
    a = torch.randn(512, 512)
    b = torch.randn(512, 512)
    n, t0 = 0, clock()
    while clock() - t0 < seconds / 2:
        a @ b
        n += 1
    gflops = n * 2 * 512**3 / (clock() - t0) / 1e9
    src = torch.empty(16 * 2**20)  # 64 MiB of float32
    dst = torch.empty_like(src)
    n, t0 = 0, clock()
    while clock() - t0 < seconds / 2:
        dst.copy_(src)
        n += 1
    gbps = n * 2 * src.numel() * 4 / (clock() - t0) / 1e9
    return {"matmul_gflops": round(gflops, 1), "memcpy_gbps": round(gbps, 1)}


@dataclass
class BenchResult:
    name: str
    parameters_per_frame: int
    latency_ms: dict[str, float] = field(default_factory=dict)
    throughput: dict[int, float] = field(default_factory=dict)
    style_encode_ms: float = 0.0
    rss_mb: float = 0.0
    bytes_per_frame: int = 0  # weight bytes a frame reads (:func:`weight_bytes_per_frame`)

    def floor_ms(self, probe: dict[str, float]) -> float:
        """The memory floor of a frame: its weight bytes at the probe's copy bandwidth (ms)."""
        return self.bytes_per_frame / (probe["memcpy_gbps"] * 1e9) * 1e3

    def to_dict(self) -> dict:
        return {"name": self.name, "parameters_per_frame": self.parameters_per_frame,
                "bytes_per_frame": self.bytes_per_frame, "latency_ms": self.latency_ms,
                "throughput_char_frames_per_s": {str(k): v for k, v in self.throughput.items()},
                "style_encode_ms": self.style_encode_ms, "rss_mb": self.rss_mb}


# The sampler's layers that run once per style or transition, not every frame.
_ONCE = ("style_encoder.", "phase_estimator.", "target_encoder.", "film1.", "film2.", "attn1.key", "attn1.value",
         "attn2.key", "attn2.value")


def per_frame_parameters(bundle: Bundle) -> int:
    """Weights read for every generated frame (the style encoder and target encoder run once)."""
    return sum(p.numel() for n, p in bundle.net.named_parameters() if not n.startswith(_ONCE))


def weight_bytes_per_frame(engine: Engine) -> int:
    """Bytes of the weights a frame reads at batch 1: :func:`per_frame_parameters` at their runtime width
    (float32; the LSTM cell's weight matrices at one byte where the engine runs them in int8)."""
    if engine.source == "matching":  # it plays the database: no network runs
        return 0
    int8 = engine.inference.int8_lstm
    return sum(p.numel() * (1 if int8 and n.startswith("lstm.weight") else p.element_size())
               for n, p in engine.bundle.net.named_parameters() if not n.startswith(_ONCE))


def bench_engine(engine: Engine, name: str, batch_sizes: tuple[int, ...] = (1, 8, 32, 128, 512),
                 latency_frames: int = 300, budget_s: float = 6.0,
                 clock: Callable[[], float] = time.perf_counter) -> BenchResult:
    """Measure one engine, timed by ``clock`` (:data:`CLOCKS`); each throughput point runs for at most
    ``budget_s / len(batch_sizes)`` of it."""
    request = WalkRequest.of(engine)
    res = BenchResult(name, 0 if engine.source == "matching" else per_frame_parameters(engine.bundle),
                      bytes_per_frame=weight_bytes_per_frame(engine))
    times = []
    for _ in range(5):
        engine.styles.delete(engine.style_id(request.style_clip))
        t0 = clock()
        style, _ = engine.encode_style(request.style_clip)
        times.append((clock() - t0) * 1000)
    res.style_encode_ms = round(statistics.median(times), 3)

    # Latency: one character, each step timed; new transitions start when one ends.
    timer = frame_timer(engine, style, request, clock)
    timer()  # warm
    step_ms = sorted(timer() for _ in range(latency_frames))
    res.latency_ms = {"median": round(statistics.median(step_ms), 3), "p99": round(step_ms[int(0.99 * (len(step_ms) - 1))], 3),
                      "mean": round(statistics.fmean(step_ms), 3)}
    per_point = budget_s / len(batch_sizes)
    for n in batch_sizes:
        res.throughput[n] = _throughput(engine, style, request, n, per_point, clock)
    res.rss_mb = round(_rss_mb(), 1)
    return res


def database_search_ms(database: MotionDatabase, runs: int = 200, frames: int = 40,
                       clock: Callable[[], float] = time.perf_counter) -> dict[str, float]:
    """Median times (ms) of one search at batch 1 over ``database``: the window a ``frames``-frame transition
    starts from (what the matching source does once per transition and per retarget) and the nearest row by pose
    and trajectory (:class:`model.retrieval.matching.MatchIndex`)."""
    from model.retrieval.matching import MatchIndex
    from model.retrieval.windows import WindowSearch

    index = MatchIndex(database)
    row = torch.nonzero(index.valid).flatten()[len(index.db.starts)]  # some row inside a segment
    query = index.row_groups(row.view(1))
    p = index.positions
    index.search(query)
    index_windows = WindowSearch(p, database.segment_of_rows(), database.skeleton, database.fps)
    window = (p[row].unsqueeze(0), p[row - 1].unsqueeze(0), p[row + frames].unsqueeze(0))
    index_windows.search(*window, frames)  # builds the windows of that length once, as the first request does

    def median(fn: Callable[[], object]) -> float:
        times = []
        for _ in range(runs):
            t0 = clock()
            fn()
            times.append((clock() - t0) * 1000)
        return round(statistics.median(times), 3)

    return {"rows": float(database.frames), "window_search_ms": median(lambda: index_windows.search(*window, frames)),
            "pose_search_ms": median(lambda: index.search(query))}


def _throughput(engine: Engine, style: EncodedStyle, request: WalkRequest, n: int, budget_s: float,
                clock: Callable[[], float]) -> float:
    """Character-frames a second of ``n`` characters stepped together: whole transitions one after another
    until ``budget_s`` of timed steps (or twice that of wall time, preparing included) has passed. Each
    transition's first step, which also warms every character on its context, is not timed."""
    frames, timed, began = 0, 0.0, clock()
    while timed < budget_s and clock() - began < 2 * budget_s:
        batch = request.batch(engine, style, n)
        batch.step()
        steps, t0 = 0, clock()
        while steps < request.frames - 1 and timed + clock() - t0 < budget_s:
            batch.step()
            steps += 1
        timed += clock() - t0
        frames += n * steps
    return round(frames / timed, 1) if frames and timed > 0 else 0.0


@dataclass(frozen=True)
class WalkRequest:
    """The bench's transition, on a procedural walk: a style clip, the context, a two-frame target and the
    longest trained length."""

    style_clip: Clip
    context: Clip
    target: Clip
    frames: int

    @classmethod
    def of(cls, engine: Engine) -> WalkRequest:
        c = engine.config
        walk = synthetic_walk(frames=160, turn_deg_s=15.0)
        frames = c.max_transition
        return cls(walk.window(20, 20 + min(120, c.style_frames_max)), walk.window(0, c.context),
                   walk.window(c.context + frames - 2, c.context + frames), frames)

    def batch(self, engine: Engine, style: EncodedStyle, n: int) -> CharacterBatch:
        """``n`` characters of this transition, prepared (seeds 0 to n - 1), not begun."""
        batch = CharacterBatch(engine)
        for i in range(n):
            batch.add(engine.prepare(self.context, self.target, self.frames, style, seed=i))
        return batch


def frame_timer(engine: Engine, style: EncodedStyle | None = None, request: WalkRequest | None = None,
                clock: Callable[[], float] = time.perf_counter) -> Callable[[], float]:
    """A function that steps one character by one frame and returns the milliseconds it took (by ``clock``); a new
    transition (of the longest trained length, on a procedural walk) is prepared, untimed, when one
    ends, and its first frame, which also warms the recurrent core on the context, is timed."""
    request = request or WalkRequest.of(engine)
    if style is None:
        style, _ = engine.encode_style(request.style_clip)
    batch = CharacterBatch(engine)

    def step() -> float:
        nonlocal batch
        if not len(batch):
            batch = request.batch(engine, style, 1)
        t0 = clock()
        batch.step()
        elapsed = (clock() - t0) * 1000
        batch.drop_finished()
        return elapsed

    return step


@dataclass
class PairedLatency:
    """Batch-1 frame times of two engines measured in alternating blocks (medians, ms), and their ratio."""

    first_ms: float
    second_ms: float
    blocks: int
    frames: int

    @property
    def ratio(self) -> float:
        return self.first_ms / self.second_ms

    def to_dict(self) -> dict:
        return {"first_ms": self.first_ms, "second_ms": self.second_ms, "ratio": round(self.ratio, 3),
                "blocks": self.blocks, "frames_per_block": self.frames}


def paired_latency(first: Engine, second: Engine, blocks: int = 8, frames: int = 40, warm: int = 5,
                   clock: Callable[[], float] = time.perf_counter) -> PairedLatency:
    """Batch-1 frame times of two engines, ``blocks`` blocks of ``frames`` timed frames each, the engines
    taking turns (which goes first alternates), each block after ``warm`` untimed frames.

    Measured one after the other, two engines see different moments of a shared machine: on a noisy
    2-core container the ratio of separate runs moved from 0.20 to 0.51 in an hour. Taking turns puts the drift on
    both; the warm frames let each refill the caches the other emptied, as in a run of its own."""
    timers = (frame_timer(first, clock=clock), frame_timer(second, clock=clock))
    times: tuple[list[float], list[float]] = ([], [])
    for block in range(blocks):
        for i in ((0, 1) if block % 2 == 0 else (1, 0)):
            for _ in range(warm):
                timers[i]()
            times[i].extend(timers[i]() for _ in range(frames))
    return PairedLatency(round(statistics.median(times[0]), 3), round(statistics.median(times[1]), 3), blocks, frames)


def paper_size_engine(reference: Bundle) -> Engine:
    """The paper's network sizes on the reference bundle's skeleton, random weights."""
    j = reference.skeleton.num_joints
    sampler = SamplerConfig(joints=j, root=reference.skeleton.roles.root,
                            target_velocity_flag=reference.config.target_velocity_flag, **PAPER_SAMPLER)
    manifold = ManifoldConfig(joints=j, root=reference.skeleton.roles.root, **PAPER_MANIFOLD)
    return Engine(Bundle.create(reference.skeleton, sampler, manifold))


def machine_description() -> dict[str, str | int]:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count() or 0, "torch": torch.__version__, "threads": torch.get_num_threads(),
            "python": platform.python_version()}


def format_table(results: list[BenchResult], probe: dict[str, float]) -> str:
    sizes = sorted({n for r in results for n in r.throughput})
    head = (["model", "params/frame", "batch-1 median ms", "memory floor ms", "x floor", "p99 ms", "style encode ms",
             "RSS MB"] + [f"{n} chars (char-frames/s)" for n in sizes])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in results:
        floor = r.floor_ms(probe)
        row = [r.name, f"{r.parameters_per_frame / 1e6:.2f} M", f"{r.latency_ms['median']:.3f}", f"{floor:.3f}",
               f"{r.latency_ms['median'] / floor:.1f}x" if floor else "-", f"{r.latency_ms['p99']:.3f}",
               f"{r.style_encode_ms:.2f}", f"{r.rss_mb:.0f}"] + [f"{r.throughput.get(n, 0):,.0f}" for n in sizes]
        lines.append("| " + " | ".join(row) + " |")
    lines.append("")
    lines.append(f"Machine probe: {probe['matmul_gflops']} GFLOP/s (512x512 fp32 matmul), "
                 f"{probe['memcpy_gbps']} GB/s (64 MiB copy). Memory floor: the weight bytes a frame reads at batch 1 "
                 f"({', '.join(f'{r.bytes_per_frame / 1e6:.1f} MB' for r in results)}) at that bandwidth.")
    return "\n".join(lines)
