"""Warm-up before readiness: run every code path and batch shape a model serves once, on the threads that serve it.

Shapes warmed (per model):

* style encoding at the shortest and longest accepted style clip (the encoder's convolutions);
* ``prepare`` (context warm-up of the recurrent core, batch 1), seeded and deterministic;
* ``generate`` of a short transition (the ``POST /v1/transition`` path, batch 1), JSON and BVH output;
* the scheduler's batched ``step`` at 1, 2, 4, ... up to ``warmup_max_batch`` characters, on the step thread,
  and at 1 on each style adapter's weights (their own traced steps);
* a stream ``start`` (style encoding and ``prepare``) on every stream-setup thread (``LoadedModel.setup``, the
  streams' own lane), so that the first ``start`` neither creates its thread nor pays that thread's first
  torch calls; every work thread is started the same way.

CPU PyTorch in eager mode compiles nothing per shape; what the first calls pay is one-off
allocation and kernel selection (tens of ms). Measured first-versus-second step at batch sizes
never seen before are equal within noise, so powers of two cover the shapes in between.
"""

from __future__ import annotations

import asyncio
import threading
import time
from concurrent.futures import Executor
from dataclasses import replace
from typing import Any

import torch

from model.inference.engine import Character, CharacterBatch, Engine
from model.inference.style_codes import CacheStats
from model.motion.clip import Clip
from service.motion import dumps, frames_bvh, frames_json
from service.registry import LoadedModel


def rest_clip(engine: Engine, frames: int) -> Clip:
    """The rest pose walking forward along +Z at 1 m/s (in cm; any plausible motion will do)."""
    sk = engine.skeleton
    rot = torch.zeros(frames, sk.num_joints, 4)
    rot[..., 3] = 1.0
    root = torch.zeros(frames, 3)
    root[:, 1] = 90.0
    root[:, 2] = torch.arange(frames) * (100.0 / engine.config.fps)
    return Clip(sk, rot, root, engine.config.fps, "warm-up")


def _warm_requests(model: LoadedModel) -> tuple[dict[str, float], Character]:
    engine = model.engine
    c = engine.config
    out: dict[str, float] = {}
    started = time.perf_counter()
    ids = []
    for frames in sorted({c.style_frames_min, c.style_frames_max}):
        style, _ = engine.encode_style(rest_clip(engine, frames), "warm-up")
        ids.append(style.style_id)
    out["encode_style_ms"] = (time.perf_counter() - started) * 1e3
    context = rest_clip(engine, c.context)
    target = rest_clip(engine, 2)
    started = time.perf_counter()
    ch = engine.prepare(context, target, min(10, engine.max_frames), style, deterministic=True)
    engine.prepare(context, target, min(10, engine.max_frames), style, seed=1)
    out["prepare_ms"] = (time.perf_counter() - started) * 1e3 / 2
    started = time.perf_counter()
    rot, root = engine.generate([engine.prepare(context, target, min(10, engine.max_frames), style, seed=2)])[0]
    dumps({"frames": frames_json(rot, root)})
    frames_bvh(rot, root, engine.skeleton, c.fps)
    out["generate_ms"] = (time.perf_counter() - started) * 1e3
    for sid in ids:
        engine.styles.delete(sid)
    engine.styles.stats = CacheStats()
    return out, ch


def _warm_steps(model: LoadedModel, template: Character, max_batch: int) -> dict[str, float]:
    engine = model.engine
    out: dict[str, float] = {}
    n = 1
    while True:
        batch = CharacterBatch(engine)
        for i in range(n):
            batch.add(template.replica(f"warm{i}"))
        started = time.perf_counter()
        batch.step()
        first = time.perf_counter() - started
        started = time.perf_counter()
        batch.step()
        out[f"step_{n}_ms"] = round((time.perf_counter() - started) * 1e3, 3)
        out[f"first_step_{n}_ms"] = round(first * 1e3, 3)
        if n >= max_batch:
            break
        n = min(2 * n, max_batch)
    for name in (w for w in engine.weight_sets if w):  # each style adapter's own traced step, at batch 1
        batch = CharacterBatch(engine)
        batch.add(template.replica("warm-adapter", replace(template.style, weights=name)))
        started = time.perf_counter()
        batch.step()
        out[f"first_step_1_{name}_ms"] = round((time.perf_counter() - started) * 1e3, 3)
    return out


def _warm_start(model: LoadedModel, arrived: threading.Barrier) -> tuple[float, str]:
    """What a stream ``start`` runs on its setup thread (an inline style, ``prepare``), once every thread of the
    lane holds one of these jobs (so that each thread of the pool is created and warmed); returns ms and the
    style id to forget."""
    arrived.wait(timeout=60)
    engine = model.engine
    c = engine.config
    started = time.perf_counter()
    style, _ = engine.encode_style(rest_clip(engine, c.style_frames_min), "warm-up")
    engine.prepare(rest_clip(engine, c.context), rest_clip(engine, 2), min(10, engine.max_frames), style, seed=3)
    return (time.perf_counter() - started) * 1e3, style.style_id


async def _on_every_thread(pool: Executor, threads: int, model: LoadedModel) -> float:
    """Run :func:`_warm_start` on each of the ``threads`` threads of ``pool`` at once; the slowest one's ms."""
    loop = asyncio.get_running_loop()
    arrived = threading.Barrier(threads)
    done = await asyncio.gather(*(loop.run_in_executor(pool, _warm_start, model, arrived) for _ in range(threads)))
    for _, style_id in done:
        model.engine.styles.delete(style_id)
    model.engine.styles.stats = CacheStats()
    return round(max(ms for ms, _ in done), 3)


async def warm_up(model: LoadedModel, max_batch: int) -> dict[str, Any]:
    """Warm one model on its own threads; returns the timings (also kept on ``model.warmup``)."""
    loop = asyncio.get_running_loop()
    started = time.perf_counter()
    threads = model.queue.threads  # RSMT_REQUEST_THREADS: the work threads, and as many stream-setup threads
    timings, template = await loop.run_in_executor(model.work, _warm_requests, model)
    timings["stream_start_ms"] = await _on_every_thread(model.setup, threads, model)
    if threads > 1:
        timings["work_threads_ms"] = await _on_every_thread(model.work, threads, model)
    timings.update(await loop.run_in_executor(model.step, _warm_steps, model, template, max_batch))
    timings["total_ms"] = round((time.perf_counter() - started) * 1e3, 1)
    model.warmup = timings
    return timings
