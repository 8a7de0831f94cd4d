"""The preprocessed motion cache: every take parsed, cut and resampled once, stored as one safetensors file plus a JSON index.

Layout of a cache folder ``<root>/<key>/``:

* ``motion.safetensors``: ``rotations`` ``[sum(T_i * J_i), 4]`` (take after take, each take's
  ``[T, J, 4]`` block flattened, so takes on rigs with different joint counts still share one
  tensor) and ``root_positions`` ``[sum(T_i), 3]``, both float32.
* ``index.json``: the settings, each take's labels, cut, frame and row ranges and skeleton number,
  the distinct skeletons as :meth:`Skeleton.to_dict` (offsets differ between performers), and the
  problems found (files skipped, and why).

``<root>`` is ``$RSMT_CACHE`` or ``~/.cache/rsmt/preprocessed``; ``<key>`` hashes the data (the data
folder's resolved path, and each file's path relative to it, size, modification time, labels and cut;
a copy of the data elsewhere gets its own cache, whose takes point into that copy) and the settings
(fps, skeleton profile, minimum length, :data:`CACHE_FORMAT_VERSION`), so a changed file or setting
gives a new cache and an unchanged one is reused. A build writes into a temporary folder that is
renamed into place at the end, so a killed build never leaves a half-written cache.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import asdict, replace
from functools import cached_property
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file
from tqdm import tqdm

from model.data.location import cache_root
from model.data.splits import DEFAULT_RATIOS, Split, split_takes
from model.data.takes import Problem, Take, TakeIndex, index_takes, relative_path
from model.motion.bvh import BvhError
from model.motion.bvh_clip import load_clip
from model.motion.clip import Clip
from model.motion.rig_facts import UnitsError, conform_clip, parse_units
from model.motion.skeleton import Skeleton, SkeletonError, SkeletonProfile

log = logging.getLogger(__name__)

# Bump when the reader, the cutting/resampling or the stored layout changes: old caches are then ignored.
CACHE_FORMAT_VERSION = 1
DATA_FILE = "motion.safetensors"
INDEX_FILE = "index.json"
DEFAULT_FPS = 30.0
DEFAULT_MIN_FRAMES = 2
DEFAULT_WORKERS = 2
# Below this many takes a process pool costs more (starting workers, importing torch) than it saves.
POOL_MIN_TAKES = 64
# Frame rates this close are the same rate written with few digits (Bandai-Namco's 0.0333333 s).
_SAME_FPS_REL_TOL = 1e-4

ProfileArg = SkeletonProfile | str | Path | None


def _resolve_profile(profile: ProfileArg) -> SkeletonProfile | None:
    if profile is None or isinstance(profile, SkeletonProfile):
        return profile
    return SkeletonProfile.load(profile)


def cache_key(index: TakeIndex, fps: float = DEFAULT_FPS, profile: ProfileArg = None,
              min_frames: int = DEFAULT_MIN_FRAMES, units: str | float = "auto") -> str:
    """The cache folder name for ``index`` under these settings (16 hex digits)."""
    prof = _resolve_profile(profile)
    files = []
    for take in index.takes:
        st = take.path.stat()
        files.append([take.take_id, relative_path(take.path, index.root), st.st_size, st.st_mtime_ns,
                      take.style, take.content, take.start, take.stop])
    description: dict[str, Any] = {
        "format": CACHE_FORMAT_VERSION,
        "fps": float(fps),
        # The profile's content, not its name, so an edited profile file gives a new cache.
        "profile": None if prof is None else prof.to_dict(),
        "min_frames": int(min_frames),
        "layout": index.layout,
        "data_root": str(index.root),
        "files": files,
    }
    if units != "auto":  # absent for the default, so caches built before units were read keep their key
        description["units"] = units
    if index.roots:  # several folders; a one-folder cache keeps its key
        description["data_roots"] = [str(r) for r in index.roots]
    text = json.dumps(description, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


# ---------------------------------------------------------------------------------- one take
def _worker_init() -> None:
    # Per-take tensors are small: intra-op threads only add overhead (with two OpenMP threads,
    # torch.cos on a strided float64 view ran 30x slower than with one), and two workers on two
    # cores would oversubscribe them.
    torch.set_num_threads(1)


@contextmanager
def _single_thread() -> Iterator[None]:
    """Run the serial build on one intra-op thread (see :func:`_worker_init`), then restore the setting."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _preprocess(job: tuple[str, str, int | None, int | None, float, SkeletonProfile | None, int, str | float]
                ) -> dict[str, Any]:
    """Load, check, cut and resample one take; a problem is returned, never raised (one bad file must not stop a build)."""
    path, rel, start, stop, fps, profile, min_frames, units = job
    try:
        # float64 until stored: the cut and resampling then lose nothing to rounding.
        clip = load_clip(path, profile=profile, dtype=torch.float64)
        clip, facts = conform_clip(clip, units)  # in cm, its facing joints apart
        source_frames, source_fps = clip.num_frames, float(clip.fps)
        if start is not None or stop is not None:
            lo = 0 if start is None else start
            hi = source_frames if stop is None else min(stop, source_frames)
            if lo >= hi:
                return _problem(rel, "bad-cut", f"cut [{start}, {stop}) leaves no frames of the {source_frames} in the file")
            if stop is not None and stop > source_frames:
                log.info("%s: cut stop %d is past the file's %d frames; cut there", rel, stop, source_frames)
            clip = clip.window(lo, hi)
        if math.isclose(clip.fps, fps, rel_tol=_SAME_FPS_REL_TOL):
            clip = replace(clip, fps=float(fps))
        else:
            clip = clip.resample(fps)
        if clip.num_frames < min_frames:
            return _problem(rel, "too-short", f"{clip.num_frames} frame(s) at {fps:g} fps, fewer than {min_frames}")
        return {
            "rotations": clip.rotations.to(torch.float32).contiguous().numpy(),
            "root_positions": clip.root_positions.to(torch.float32).contiguous().numpy(),
            "skeleton": clip.skeleton.to_dict(),
            "source_frames": source_frames,
            "source_fps": source_fps,
            "cm_per_unit": facts.cm_per_unit,
        }
    except UnitsError as exc:
        return _problem(rel, "units", str(exc))
    except BvhError as exc:
        return _problem(rel, "unreadable", str(exc))
    except SkeletonError as exc:
        return _problem(rel, "rig", str(exc))
    except Exception as exc:  # noqa: BLE001 - any failure on one file is that file's problem, reported below
        return _problem(rel, "unreadable", f"{type(exc).__name__}: {exc}")


def _problem(path: str, kind: str, message: str) -> dict[str, Any]:
    return {"problem": {"path": path, "kind": kind, "message": message}}


# ---------------------------------------------------------------------------------- building
def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_stale_temporaries(root: Path) -> None:
    """Remove the temporary folders (``.tmp-<pid>-*``, ``.old-<pid>-*``) of builds whose process is gone."""
    for tmp in [*root.glob(".tmp-*"), *root.glob(".old-*")]:
        try:
            pid = int(tmp.name.split("-")[1])
        except (IndexError, ValueError):
            continue
        if not _pid_alive(pid):
            shutil.rmtree(tmp, ignore_errors=True)


def _run_jobs(jobs: list[tuple], workers: int, progress: bool) -> list[dict[str, Any]]:
    bar = tqdm(total=len(jobs), desc="rsmt: preprocessing takes", unit="take", disable=not progress,
               file=sys.stderr, dynamic_ncols=True)
    results = []
    with bar:
        if workers > 1 and len(jobs) >= POOL_MIN_TAKES:
            # forkserver: forking a parent that has already run torch's thread pools can deadlock.
            # Its server imports this module (and torch, the BVH reader) once; workers fork from it.
            context = get_context("forkserver")
            context.set_forkserver_preload(["model.data.preprocessed", "model.motion.bvh_clip"])
            with ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_worker_init) as pool:
                for result in pool.map(_preprocess, jobs, chunksize=8):
                    results.append(result)
                    bar.update()
        else:
            with _single_thread():
                for job in jobs:
                    results.append(_preprocess(job))
                    bar.update()
    return results


def build_motion_cache(
    index: TakeIndex,
    destination: Path,
    fps: float = DEFAULT_FPS,
    profile: ProfileArg = None,
    min_frames: int = DEFAULT_MIN_FRAMES,
    workers: int = DEFAULT_WORKERS,
    progress: bool = True,
    key: str = "",
    units: str | float = "auto",
) -> Path:
    """Preprocess every take of ``index`` into the cache folder ``destination`` (replaced atomically).

    Files that fail are recorded in the index's problems (kind ``unreadable``, ``rig``,
    ``too-short``, ``bad-cut``) and skipped.
    """
    prof = _resolve_profile(profile)
    destination = Path(destination)
    destination.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_temporaries(destination.parent)
    began = time.perf_counter()
    jobs = [(str(t.path), relative_path(t.path, index.root), t.start, t.stop, float(fps), prof, int(min_frames), units)
            for t in index.takes]
    log.info("preprocessing %d takes from %s into %s", len(jobs), index.root, destination)
    results = _run_jobs(jobs, workers, progress)

    skeletons: list[dict[str, Any]] = []
    skeleton_ids: dict[str, int] = {}
    takes, rotations, roots = [], [], []
    problems = [asdict(p) for p in index.problems]
    frame, row = 0, 0
    for take, result in zip(index.takes, results):
        if "problem" in result:
            problems.append(result["problem"])
            log.warning("skipped %s", Problem(**result["problem"]))
            continue
        skel_text = json.dumps(result["skeleton"], sort_keys=True)
        sid = skeleton_ids.setdefault(skel_text, len(skeletons))
        if sid == len(skeletons):
            skeletons.append(result["skeleton"])
        rot, root = result["rotations"], result["root_positions"]
        frames, joints = rot.shape[0], rot.shape[1]
        takes.append({
            "take_id": take.take_id, "path": relative_path(take.path, index.root), "style": take.style,
            "content": take.content, "start": take.start, "stop": take.stop, "skeleton": sid,
            **({"source_style": take.source_style} if take.source_style else {}),
            "frames": frames, "joints": joints, "frame_offset": frame, "row_offset": row,
            "source_frames": result["source_frames"], "source_fps": result["source_fps"],
            "cm_per_unit": result["cm_per_unit"],
        })
        rotations.append(rot.reshape(-1, 4))
        roots.append(root)
        frame += frames
        row += frames * joints
    meta = {
        "format": CACHE_FORMAT_VERSION, "key": key, "fps": float(fps),
        "profile": None if prof is None else prof.to_dict(), "min_frames": int(min_frames), "units": units,
        "data_root": str(index.root), "layout": index.layout,
        **({"data_roots": [str(r) for r in index.roots]} if index.roots else {}),
        "manifest": None if index.manifest is None else str(index.manifest),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "build_seconds": round(time.perf_counter() - began, 2),
        "skeletons": skeletons, "takes": takes, "problems": problems,
    }
    tensors = {
        "rotations": torch.from_numpy(np.concatenate(rotations) if rotations else np.zeros((0, 4), np.float32)),
        "root_positions": torch.from_numpy(np.concatenate(roots) if roots else np.zeros((0, 3), np.float32)),
    }
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{os.getpid()}-", dir=destination.parent))
    tmp.chmod(0o755)  # mkdtemp makes it private; the finished cache is an ordinary folder
    try:
        save_file(tensors, str(tmp / DATA_FILE), metadata={"format": str(CACHE_FORMAT_VERSION)})
        (tmp / INDEX_FILE).write_text(json.dumps(meta, indent=1))
        _move_into_place(tmp, destination)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    log.info("cached %d takes (%d frames, %d problems) in %.1f s", len(takes), frame, len(problems),
             time.perf_counter() - began)
    return destination


def _move_into_place(tmp: Path, destination: Path) -> None:
    """Rename the finished build onto ``destination``; an older cache there is swapped out first."""
    old = None
    if destination.exists():
        old = destination.parent / f".old-{os.getpid()}-{destination.name}"
        shutil.rmtree(old, ignore_errors=True)
        destination.rename(old)
    try:
        tmp.rename(destination)
    except OSError:
        # Another process finished the same cache first: its copy is as good as ours.
        if not destination.exists():
            raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


# ---------------------------------------------------------------------------------- reading
class MotionCache:
    """A built cache: takes (those that loaded), their motion as :class:`Clip`, problems and splits.

    Takes are addressed by their position ``i`` in :attr:`takes`, by ``take_id`` or by
    :class:`Take`. Tensors returned are views of the cache (do not modify them in place).
    """

    def __init__(self, folder: Path, meta: dict[str, Any], tensors: dict[str, torch.Tensor]) -> None:
        self.folder = Path(folder)
        self.meta = meta
        self.key: str = meta.get("key", self.folder.name)
        self.fps: float = float(meta["fps"])
        self.data_root = Path(meta["data_root"])
        self.layout: str = meta["layout"]
        self._rotations = tensors["rotations"]
        self._roots = tensors["root_positions"]
        self._entries: list[dict[str, Any]] = meta["takes"]
        self.takes: list[Take] = [
            Take(path=self.data_root / e["path"], style=e["style"], content=e["content"],
                 take_id=e["take_id"], start=e["start"], stop=e["stop"], source_style=e.get("source_style"))
            for e in self._entries
        ]
        self.problems: list[Problem] = [Problem(**p) for p in meta["problems"]]
        self._ids = {t.take_id: i for i, t in enumerate(self.takes)}
        self.styles: list[str] = sorted({t.style for t in self.takes})
        self.contents: list[str] = sorted({t.content for t in self.takes})
        self._style_ids = {s: i for i, s in enumerate(self.styles)}
        self._skeletons = [Skeleton.from_dict(s) for s in meta["skeletons"]]

    @classmethod
    def open(cls, folder: str | Path) -> MotionCache:
        """Open a cache folder; ``ValueError`` when it is not a complete cache of this format."""
        folder = Path(folder)
        try:
            meta = json.loads((folder / INDEX_FILE).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"{folder} is not a motion cache: {exc}") from exc
        if meta.get("format") != CACHE_FORMAT_VERSION:
            raise ValueError(f"{folder}: cache format {meta.get('format')}, expected {CACHE_FORMAT_VERSION}")
        try:
            tensors = load_file(str(folder / DATA_FILE))
        except Exception as exc:  # noqa: BLE001 - safetensors raises its own error type on a damaged file
            raise ValueError(f"{folder / DATA_FILE}: cannot read: {exc}") from exc
        return cls(folder, meta, tensors)

    def __len__(self) -> int:
        return len(self.takes)

    def __repr__(self) -> str:
        return (f"MotionCache({str(self.folder)!r}, {len(self)} takes, {self.total_frames} frames at {self.fps:g} fps, "
                f"{len(self.styles)} styles, {len(self.contents)} contents, {len(self.problems)} problems)")

    def indices_of(self, take_ids: Sequence[str], what: str = "") -> list[int]:
        """Positions of takes named by ``take_id``; a ValueError naming every unknown one (``what``: what they
        were asked for, said in the message)."""
        unknown = sorted({t for t in take_ids if t not in self._ids})
        if unknown:
            raise ValueError(f"no take {', '.join(unknown)} in the data" + (f" ({what} are named by take id)" if what else ""))
        return [self._ids[t] for t in take_ids]

    def index_of(self, take: int | str | Take) -> int:
        """Position of a take given by position, ``take_id`` or :class:`Take`."""
        if isinstance(take, Take):
            take = take.take_id
        if isinstance(take, str):
            try:
                return self._ids[take]
            except KeyError:
                raise KeyError(f"no take {take!r} in the cache") from None
        i = int(take)
        if not -len(self) <= i < len(self):
            raise IndexError(f"take index {i} out of range for {len(self)} takes")
        return i % len(self)

    @property
    def frame_counts(self) -> list[int]:
        """Frames of each take at :attr:`fps`."""
        return [e["frames"] for e in self._entries]

    @property
    def total_frames(self) -> int:
        return sum(self.frame_counts)

    def num_frames(self, take: int | str | Take) -> int:
        return self._entries[self.index_of(take)]["frames"]

    def rotations(self, take: int | str | Take) -> torch.Tensor:
        """``[T, J, 4]`` local rotations of a take (a view into the cache)."""
        e = self._entries[self.index_of(take)]
        rows = e["frames"] * e["joints"]
        return self._rotations[e["row_offset"]:e["row_offset"] + rows].view(e["frames"], e["joints"], 4)

    def root_positions(self, take: int | str | Take) -> torch.Tensor:
        """``[T, 3]`` root positions of a take (a view into the cache)."""
        e = self._entries[self.index_of(take)]
        return self._roots[e["frame_offset"]:e["frame_offset"] + e["frames"]]

    def skeleton(self, take: int | str | Take) -> Skeleton:
        return self._skeletons[self._entries[self.index_of(take)]["skeleton"]]

    def clip(self, take: int | str | Take) -> Clip:
        """The take as a :class:`Clip` at the cache's fps."""
        i = self.index_of(take)
        return Clip(skeleton=self.skeleton(i), rotations=self.rotations(i), root_positions=self.root_positions(i),
                    fps=self.fps, name=self.takes[i].take_id)

    def clips(self, takes: Sequence[int] | None = None) -> Iterator[Clip]:
        for i in range(len(self)) if takes is None else takes:
            yield self.clip(i)

    def style_id(self, take: int | str | Take) -> int:
        return self._style_ids[self.takes[self.index_of(take)].style]

    @cached_property
    def split(self) -> Split:
        """The default split (ratios 0.8/0.1/0.1, no held-out style); indices are take positions."""
        return split_takes(self.takes, DEFAULT_RATIOS, frames=self.frame_counts)

    def make_split(self, ratios: Sequence[float] = DEFAULT_RATIOS, holdout_styles: Sequence[str] = ()) -> Split:
        """A split with other ratios or held-out styles (see :func:`model.data.splits.split_takes`)."""
        return split_takes(self.takes, ratios, holdout_styles, frames=self.frame_counts)


def load_motion_cache(
    folder: str | Path,
    fps: float = DEFAULT_FPS,
    profile: ProfileArg = None,
    manifest: str | Path | None = None,
    rebuild: bool = False,
    *,
    min_frames: int = DEFAULT_MIN_FRAMES,
    workers: int = DEFAULT_WORKERS,
    progress: bool = True,
    root: str | Path | None = None,
    units: str | float = "auto",
) -> MotionCache:
    """The cache of the takes under ``folder``, built first when missing, stale or ``rebuild`` is set.

    Args:
        folder: the data folder (see :func:`model.data.takes.index_takes`).
        fps: frame rate to resample to.
        profile: skeleton profile (built-in name, JSON path or object); ``None`` picks a built-in per file.
        manifest: optional CSV manifest of the takes.
        rebuild: build even when a cache with this key exists.
        min_frames: takes shorter than this after resampling are skipped as ``too-short``.
        workers: processes used to parse files (1 parses in this process).
        progress: show a progress bar on stderr while building.
        root: cache root; default :func:`cache_root`.
        units: the takes' units (:func:`model.motion.rig_facts.parse_units`); ``auto`` reads them
            from each take's head height. Every take is stored in centimetres.
    """
    index = index_takes(folder, manifest)
    units = parse_units(units)
    key = cache_key(index, fps, profile, min_frames, units)
    destination = (Path(root).expanduser() if root is not None else cache_root()) / key
    if not rebuild and destination.is_dir():
        try:
            cache = MotionCache.open(destination)
            log.info("reusing motion cache %s", destination)
            return cache
        except ValueError as exc:
            log.warning("rebuilding unusable cache: %s", exc)
    build_motion_cache(index, destination, fps, profile, min_frames, workers, progress, key=key, units=units)
    return MotionCache.open(destination)
