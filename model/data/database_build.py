"""A bundle's motion database (:class:`model.retrieval.database.MotionDatabase`) built from a data set's train split.

Every locomotion take of the split (walks, turns, runs, walks backwards or at an angle: any content whose gait is
not ``stand``) is a candidate, without its first and last ``trim`` frames. Takes are taken one group at a time in
turn, a group being a (data set, style, content), so every style and every kind of walk gets its share before any
gets more (every style of one content first), until the next take would pass the byte budget (10 MB: what the
data's licence lets a bundle carry).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from model.data.preprocessed import MotionCache, ProfileArg, load_motion_cache
from model.motion.gait_limits import gait_of
from model.retrieval.database import MotionDatabase, bytes_per_frame

TRIM = 15
MIN_SEGMENT = 45  # a 40-frame window and the frame before it, with room to move
BUDGET_BYTES = 10_000_000


def locomotion_groups(cache: MotionCache, takes: Sequence[int]) -> dict[tuple[str, str, str], list[int]]:
    """The locomotion takes among ``takes`` by (data set, style, content), each group in take order."""
    groups: dict[tuple[str, str, str], list[int]] = {}
    for i in sorted(takes):
        take = cache.takes[i]
        if gait_of(take.content) != "stand":
            groups.setdefault((take.source, take.style, take.content), []).append(i)
    return groups


def build_database(cache: MotionCache, takes: Sequence[int] | None = None, budget_bytes: int = BUDGET_BYTES,
                   trim: int = TRIM) -> MotionDatabase:
    """The database of ``cache``'s locomotion takes among ``takes`` (default: its train split) within
    ``budget_bytes`` (see the module's notes)."""
    chosen = list(cache.split.train if takes is None else takes)
    groups = locomotion_groups(cache, chosen)
    if not groups:
        raise ValueError(f"{cache.folder}: none of its {len(chosen)} takes is locomotion (a walk, run or dash)")
    first = next(iter(groups.values()))[0]
    skeleton = cache.skeleton(first)
    budget = budget_bytes // bytes_per_frame(skeleton.num_joints)
    # One pass visits every style of a content before the next content, so a budget cut mid-pass costs contents, not styles.
    queues = {k: list(v) for k, v in sorted(groups.items(), key=lambda kv: (kv[0][2], kv[0][0], kv[0][1]))}
    segments, used = [], 0
    kept: dict[str, int] = {}
    while any(queues.values()):
        for queue in queues.values():
            if not queue:
                continue
            i = queue.pop(0)
            frames = cache.num_frames(i) - 2 * trim
            if frames < MIN_SEGMENT or used + frames > budget:
                continue
            take = cache.takes[i]
            rot, root = cache.rotations(i).float(), cache.root_positions(i).float()
            segments.append((rot[trim:trim + frames], root[trim:trim + frames], take.style, take.content))
            used += frames
            kept[take.source or cache.data_root.name] = kept.get(take.source or cache.data_root.name, 0) + 1
    offered: dict[str, int] = {}
    for (source, _, _), members in groups.items():
        offered[source or cache.data_root.name] = offered.get(source or cache.data_root.name, 0) + len(members)
    counts = ", ".join(f"{name} {kept.get(name, 0)} of {n}" for name, n in sorted(offered.items()))
    source = f"train split locomotion takes ({counts}) at {cache.fps:g} fps, {trim} frames trimmed from each end"
    return MotionDatabase.from_segments(skeleton, cache.fps, segments, source)


def database_from_data(data: Path, fps: float, budget_bytes: int = BUDGET_BYTES, workers: int = 1, *,
                       profile: ProfileArg = None, units: str | float = "auto") -> MotionDatabase:
    """:func:`build_database` of the data folder(s) ``data`` (its preprocessed cache, built when missing)."""
    cache = load_motion_cache(data, fps=fps, profile=profile, workers=workers, progress=True, units=units)
    return build_database(cache, budget_bytes=budget_bytes)
