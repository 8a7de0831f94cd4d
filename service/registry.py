"""Loaded models: finding bundles on disk, one :class:`Engine` per bundle, and the threads that run it.

Each model gets three executors: ``work`` (``request_threads`` threads) for HTTP requests (parsing,
style encoding, ``prepare``, ``generate``) behind a bounded :class:`~service.work_queue.WorkQueue`;
``setup`` (as many threads) for stream setup (``start``, ``retarget`` and ``style`` payloads), a lane of
its own so that an HTTP burst never delays a stream, behind a queue of the same kind without a bound; and
``step``, a single thread that owns the scheduler's batches. Both queues serve each API key's jobs in turn
(:mod:`service.key_turns`). Engine calls never run on the event loop.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import torch

from model.export.backends import with_backend
from model.inference.bundle import Bundle, BundleError
from model.inference.engine import Engine
from model.inference.errors import EngineError
from service.caller import ANONYMOUS
from service.errors import ServiceError
from service.metrics import Metrics
from service.motion import MotionLimits
from service.settings import Settings
from service.streaming.scheduler import Scheduler
from service.streaming.step_shares import StepShares
from service.styles import StyleStore, builtin_list, style_store_factory
from service.work_queue import Continue, WorkQueue

log = logging.getLogger(__name__)
T = TypeVar("T")


class NoModelError(RuntimeError):
    """No bundle where the settings point; the message says how to get one."""


def find_bundles(path: Path) -> list[Path]:
    """``path`` itself when it is a bundle, else its subdirectories that are bundles (sorted)."""
    path = Path(path)
    hint = ("train one with `rsmt train all --data DIR --out BUNDLE_DIR` (or write a random-weight one for a smoke "
            "test), then serve it with `rsmt serve --models BUNDLE_DIR` or RSMT_MODELS=BUNDLE_DIR; a directory of "
            "bundle directories serves them all")
    if (path / "config.json").is_file():
        return [path]
    if not path.is_dir():
        raise NoModelError(f"no model bundle at {path}: the path does not exist. To get one, {hint}")
    found = sorted(p for p in path.iterdir() if (p / "config.json").is_file())
    if not found:
        raise NoModelError(f"no model bundle at {path}: it holds no config.json and no bundle subdirectories. To get one, {hint}")
    return found


@dataclass(eq=False)
class LoadedModel:
    """One served model: its engine, threads, scheduler, payload limits and style store (as the style functions
    see it, it is a :class:`service.styles.StyleHost`)."""

    name: str
    path: Path
    engine: Engine
    work: ThreadPoolExecutor
    step: ThreadPoolExecutor
    setup: ThreadPoolExecutor  # stream setup: its own lane, never behind HTTP work
    queue: WorkQueue  # HTTP work waits here for ``work``
    setup_queue: WorkQueue  # stream setup waits here for ``setup`` (no bound: each connection sends one at a time)
    limits: MotionLimits
    book: StyleStore  # the styles registered through this model, by owner (service.styles.store)
    scheduler: Scheduler | None = None
    warmup: dict[str, Any] = field(default_factory=dict)

    def info(self) -> dict[str, Any]:
        """The model description of ``GET /v1/model`` (:class:`service.schemas.ModelInfo`), also in ``hello``."""
        engine = self.engine
        c = engine.config
        sk = engine.skeleton
        return {
            "name": self.name,
            "version": engine.version,
            "fps": c.fps,
            "context_frames": c.context,
            "max_transition_frames": engine.max_frames,
            "target_velocity_flag": c.target_velocity_flag,
            "style_clip_frames": {"min": c.style_frames_min, "max": c.style_frames_max},
            "skeleton": {
                "joints": [{"name": n, "parent": p, "offset": list(o)} for n, p, o in zip(sk.names, sk.parents, sk.offsets)],
                "units": sk.units,
                "up_axis": sk.up_axis,
                "handedness": sk.handedness,
            },
            "training_data": engine.bundle.meta.training_data,
            "license": engine.bundle.meta.license,
            "builtin_styles": builtin_list(engine),
            "source": engine.source,
        }

    async def run(self, fn: Callable[..., T | Continue[T]], *args: Any, owner: str = ANONYMOUS,
                  gone: Callable[[], Awaitable[None]] | None = None) -> T:
        """Run ``fn(*args)`` for an HTTP request of ``owner`` (the caller's owner digest) on this model's work
        threads, through its bounded queue (``overloaded`` when ``owner``'s part is full, ``shutting_down`` once
        closed; ``gone``: see :meth:`WorkQueue.run`; a :class:`Continue` it returns runs on the key's next turn)."""
        return await self.queue.run(fn, *args, owner=owner, gone=gone)

    async def run_stream(self, fn: Callable[..., T | Continue[T]], *args: Any, owner: str = ANONYMOUS) -> T:
        """Run ``fn(*args)`` for a stream's message of ``owner`` on this model's stream-setup threads, in turn
        with the other keys' (``shutting_down`` once closed)."""
        return await self.setup_queue.run(fn, *args, owner=owner)


class Registry:
    """The models of this process, by name, with a default."""

    def __init__(self, models: list[LoadedModel], default: str | None = None) -> None:
        if not models:
            raise NoModelError("no models loaded")
        self.models = {m.name: m for m in models}
        if default is not None and default not in self.models:
            raise NoModelError(f"default model {default!r} is not among the loaded models: {', '.join(self.models)}")
        self.default = default or sorted(self.models)[0]

    def get(self, name: str | None = None) -> LoadedModel:
        if name is None:
            return self.models[self.default]
        model = self.models.get(name)
        if model is None:
            raise ServiceError("unknown_model", f"no model named {name!r}; loaded: {', '.join(sorted(self.models))} "
                                                "(GET /v1/models)")
        return model

    def __iter__(self) -> Iterator[LoadedModel]:
        return iter(self.models.values())

    def live_characters(self) -> int:
        return sum(m.scheduler.live for m in self if m.scheduler is not None)

    def start_schedulers(self, metrics: Metrics | None, asap_share: float = 0.1, step_shares: bool = False,
                         step_share_batch: int = 256) -> None:
        for m in self:
            m.queue.metrics = metrics
            m.scheduler = Scheduler(m.engine, m.step, metrics, m.name, asap_share=asap_share,
                                    shares=StepShares(step_shares, step_share_batch))
            m.scheduler.start()

    def close_queues(self) -> int:
        """Shutdown: HTTP work not yet started is answered ``shutting_down``; returns how much there was."""
        return sum(m.queue.close() for m in self)

    async def stop(self) -> None:
        for m in self:
            if m.scheduler is not None:
                await m.scheduler.stop()
        self.close_queues()
        for m in self:
            m.setup_queue.close()
            m.work.shutdown(wait=False, cancel_futures=True)
            m.setup.shutdown(wait=False, cancel_futures=True)
            m.step.shutdown(wait=False, cancel_futures=True)


def _threads(count: int, prefix: str, torch_threads: int) -> ThreadPoolExecutor:
    """``count`` worker threads; torch's thread count is per OS thread once that thread has run an op, so
    each worker sets it (when the settings fix one)."""
    if torch_threads:
        return ThreadPoolExecutor(count, thread_name_prefix=prefix, initializer=torch.set_num_threads,
                                  initargs=(torch_threads,))
    return ThreadPoolExecutor(count, thread_name_prefix=prefix)


def load_registry(settings: Settings) -> Registry:
    """Load every bundle the settings point at (blocking: call it from a thread)."""
    assert settings.models is not None
    paths = find_bundles(settings.models)
    models: list[LoadedModel] = []
    names: set[str] = set()
    new_book = style_store_factory(settings)
    for path in paths:
        try:
            bundle = Bundle.load(path)
        except BundleError as exc:
            raise NoModelError(f"cannot load the model bundle {path}: {exc}") from exc
        if settings.source != "network" and settings.backend != "torch":
            raise NoModelError(f"RSMT_SOURCE={settings.source} runs on the torch backend only (the ONNX graphs hold the "
                               "network alone); unset RSMT_BACKEND")
        try:
            engine = Engine(bundle, threads=settings.threads or None, cache_entries=settings.style_cache_entries,
                            cache_bytes=settings.style_cache_bytes, overrides=settings.overrides(),
                            compiled=not settings.eager, source=settings.source,
                            max_frames=settings.max_transition_frames)  # the engine checks frames
        except EngineError as exc:
            raise NoModelError(f"cannot serve {path} with RSMT_SOURCE={settings.source}: {exc}") from exc
        engine = with_backend(engine, settings.backend)
        name = engine.name if engine.name not in names else path.name
        if name in names:
            raise NoModelError(f"two bundles are named {name!r}; rename one directory")
        names.add(name)
        limits = MotionLimits(settings.max_clip_frames, settings.quaternion_tolerance, settings.max_abs_position)
        work = _threads(settings.request_threads, f"work-{name}", settings.threads)
        setup = _threads(settings.request_threads, f"setup-{name}", settings.threads)
        models.append(LoadedModel(
            name=name, path=path, engine=engine, limits=limits, work=work,
            queue=WorkQueue(work, settings.request_threads, settings.queue_limit, name=name),
            setup=setup, setup_queue=WorkQueue(setup, settings.request_threads, None, name=name),
            step=_threads(1, f"step-{name}", settings.threads),
            book=new_book(name, engine),
        ))
        log.info("loaded model", extra={"model": name, "path": str(path), "version": engine.version})
    return Registry(models, settings.default_model)
