"""Deterministic, stratified train/val/test split of takes by a hash of each take's stable key.

The rule (no random state, so every machine and every run agrees):

1. Takes of a held-out style are set aside entirely (``Split.holdout``), for the few-shot experiment.
2. The other takes are grouped by ``(source, style, content)``: the data set a take comes from
   (:attr:`Take.source`, so adding a second data set moves no take of the first), the style as the
   data names it (a label merge moves no take) and the content. Inside a group, each take gets the number
   ``sha256(salt + take.key)`` and the group is sorted by it.
3. The group's ``n`` takes are shared out by the largest-remainder rule on ``n * ratio``; when the
   group has at least as many takes as there are splits with a non-zero ratio, every such split
   gets at least one take (taken from the largest share). Smaller groups go by the rule alone,
   so a group of one take is all train.
4. In hash order, the first takes go to test, the next to val, the rest to train.

A data set recorded with a take or two per style and content (Bandai-Namco dataset 1, 100STYLE)
would put every take in train by that rule. When every group of a source (:attr:`Take.source`) has
fewer takes than there are splits with a non-zero ratio, its takes are grouped by content alone
instead (**pooled** groups); a source with larger groups (dataset 2) is split as before. A
pooled group is ordered by style in turn (every style's first take before any style's second): the
source's styles are ranked by hash, and the k-th pooled group (by content name) starts at the style
after the last one the previous pooled groups sent to test and val, so test and val takes go to
every style in turn rather than to the same few (ties by take hash). When the takes' frame counts
are given, a pooled take shorter than :data:`POOLED_MIN_FRAMES` (too short for an evaluation case)
comes last, so val and test get takes that can be scored.

Adding a take to a group inserts it at its hash rank: at most the takes next to a split boundary
(one or two per group) change split, and other groups do not change at all.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from model.data.takes import Take

SPLITS = ("train", "val", "test")
DEFAULT_RATIOS = (0.8, 0.1, 0.1)
DEFAULT_SALT = "rsmt-split-v1"
POOLED_MIN_FRAMES = 50  # the evaluation's case span (model.evaluation.cases.SPAN)


@dataclass(frozen=True)
class Split:
    """Take indices (into the sequence given to :func:`split_takes`) per split, each sorted.

    Attributes:
        train / val / test: the three splits.
        holdout: every take of the held-out styles.
        ratios: the ratios used.
        holdout_styles: the styles held out.
    """

    train: tuple[int, ...]
    val: tuple[int, ...]
    test: tuple[int, ...]
    holdout: tuple[int, ...] = ()
    ratios: tuple[float, float, float] = DEFAULT_RATIOS
    holdout_styles: tuple[str, ...] = ()

    def __getitem__(self, name: str) -> tuple[int, ...]:
        if name not in (*SPLITS, "holdout"):
            raise KeyError(f"no split {name!r}: use one of {', '.join(SPLITS)}, holdout")
        return getattr(self, name)

    def sizes(self) -> dict[str, int]:
        return {name: len(self[name]) for name in (*SPLITS, "holdout")}


def parse_ratios(text: str) -> tuple[float, float, float]:
    """``"0.8,0.1,0.1"`` (or ``"8/1/1"``) as checked ratios."""
    parts = text.replace("/", ",").split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"ratios must be three numbers such as 0.8,0.1,0.1, got {text!r}") from None
    return check_ratios(values)


def check_ratios(ratios: Iterable[float]) -> tuple[float, float, float]:
    """Three non-negative ratios with a positive train share, normalised to sum to 1."""
    values = tuple(float(r) for r in ratios)
    if len(values) != 3 or any(not math.isfinite(v) or v < 0 for v in values):
        raise ValueError(f"ratios must be three non-negative numbers (train, val, test), got {values}")
    total = sum(values)
    if total <= 0 or values[0] <= 0:
        raise ValueError(f"the train ratio must be positive, got {values}")
    return values[0] / total, values[1] / total, values[2] / total


def hash_fraction(key: str, salt: str = DEFAULT_SALT) -> float:
    """A number in ``[0, 1)`` fixed by ``key``: the same on every machine and Python version."""
    digest = hashlib.sha256(f"{salt}\0{key}".encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2**64


def group_shares(n: int, ratios: Sequence[float]) -> list[int]:
    """How many of a group's ``n`` takes each split gets (see the module docstring, step 3)."""
    raw = [n * r for r in ratios]
    shares = [math.floor(x) for x in raw]
    # Largest remainder; ties go to the earlier split (train first) so the result is deterministic.
    order = sorted(range(len(raw)), key=lambda i: (-(raw[i] - shares[i]), i))
    for i in order[: n - sum(shares)]:
        shares[i] += 1
    wanted = [i for i, r in enumerate(ratios) if r > 0]
    if n >= len(wanted):
        for i in wanted:
            if shares[i] == 0:
                donor = max(wanted, key=lambda k: (shares[k], -k))
                shares[donor] -= 1
                shares[i] += 1
    return shares


def split_takes(
    takes: Sequence[Take],
    ratios: Sequence[float] = DEFAULT_RATIOS,
    holdout_styles: Iterable[str] = (),
    salt: str = DEFAULT_SALT,
    frames: Sequence[int] | None = None,
) -> Split:
    """Split ``takes`` by take into train/val/test, stratified by ``(source, style, content)``.

    Args:
        takes: the takes; the result holds indices into this sequence.
        ratios: train, val, test shares (normalised to sum to 1; train must be positive).
        holdout_styles: styles put aside entirely (``Split.holdout``); each must occur in ``takes``.
        salt: changes every assignment at once (a different but equally deterministic split).
        frames: each take's frame count, or ``None``; only pooled groups use it (see the module docstring).

    Raises:
        ValueError: bad ratios, or a held-out style that no take has.
    """
    ratios_t = check_ratios(ratios)
    held = tuple(sorted(set(holdout_styles)))
    styles = {t.style for t in takes}
    unknown = [s for s in held if s not in styles]
    if unknown:
        raise ValueError(f"held-out style(s) {', '.join(unknown)} not in the data; styles are: {', '.join(sorted(styles))}")
    groups: dict[tuple[str, str, str], list[int]] = {}
    holdout: list[int] = []
    for i, take in enumerate(takes):
        if take.style in held:
            holdout.append(i)
        else:
            groups.setdefault((take.source, take.data_style, take.content), []).append(i)
    out: dict[str, list[int]] = {name: [] for name in SPLITS}
    wanted = sum(1 for r in ratios_t if r > 0)
    pooled: dict[tuple[str, str], list[int]] = {}
    largest: dict[str, int] = {}
    for (source, _, _), members in groups.items():
        largest[source] = max(largest.get(source, 0), len(members))
    for (source, style, content) in list(groups):
        if largest[source] < wanted:
            pooled.setdefault((source, content), []).extend(groups.pop((source, style, content)))
    for members in groups.values():
        members.sort(key=lambda i: (hash_fraction(takes[i].key, salt), takes[i].key))
        _deal(members, group_shares(len(members), ratios_t), out)
    _deal_pooled(takes, pooled, ratios_t, salt, out, frames)
    return Split(
        train=tuple(sorted(out["train"])), val=tuple(sorted(out["val"])), test=tuple(sorted(out["test"])),
        holdout=tuple(sorted(holdout)), ratios=ratios_t, holdout_styles=held,
    )


def _deal(members: list[int], shares: list[int], out: dict[str, list[int]]) -> None:
    """The first ``shares[2]`` of ``members`` to test, the next ``shares[1]`` to val, the rest to train."""
    _, n_val, n_test = shares
    out["test"] += members[:n_test]
    out["val"] += members[n_test:n_test + n_val]
    out["train"] += members[n_test + n_val:]


def _deal_pooled(takes: Sequence[Take], pooled: dict[tuple[str, str], list[int]],
                 ratios: Sequence[float], salt: str, out: dict[str, list[int]],
                 frames: Sequence[int] | None) -> None:
    """Share out the pooled groups, style by style in turn (see the module docstring)."""
    offsets: dict[str, int] = {}
    for source, content in sorted(pooled):
        members = pooled[(source, content)]
        styles = sorted({takes[i].data_style for t in pooled for i in pooled[t] if t[0] == source},
                        key=lambda st: (hash_fraction(f"style/{source}/{st}", salt), st))
        rank = {st: r for r, st in enumerate(styles)}
        start = offsets.get(source, 0)
        members.sort(key=lambda i: (hash_fraction(takes[i].key, salt), takes[i].key))
        seen: dict[str, int] = {}
        turn = {}  # a style's second take comes after every style's first
        for i in members:
            turn[i] = seen.get(takes[i].data_style, 0)
            seen[takes[i].data_style] = turn[i] + 1
        members.sort(key=lambda i: (frames is not None and frames[i] < POOLED_MIN_FRAMES, turn[i],
                                    (rank[takes[i].data_style] - start) % len(styles),
                                    hash_fraction(takes[i].key, salt), takes[i].key))
        shares = group_shares(len(members), ratios)
        _deal(members, shares, out)
        offsets[source] = start + len({takes[i].data_style for i in members[:shares[1] + shares[2]]})
