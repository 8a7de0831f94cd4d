"""Fixed-length training windows over cached takes, and a style-balanced batch sampler.

Windowing rule: a take of ``n`` frames gives windows of ``length`` frames starting at
``0, step, 2*step, ...`` with ``step = length - overlap``, keeping **every** window that fits,
i.e. every start with ``start + length <= n``. The last window that fits exactly (ending on the
take's last frame) is kept; the reference code's ``start + length < n`` drops it, which we do not
reproduce. Frames after the last full window are not used; a take shorter than ``length`` gives none.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, Any

import torch
from torch.utils.data import Dataset, Sampler

if TYPE_CHECKING:
    from model.motion_cache import MotionCache


def window_starts(num_frames: int, length: int, overlap: int = 0) -> range:
    """Start frames of the windows of one take (see the module docstring)."""
    if length <= 0:
        raise ValueError(f"window length must be positive, got {length}")
    if not 0 <= overlap < length:
        raise ValueError(f"overlap must be in [0, length), got {overlap} for length {length}")
    return range(0, num_frames - length + 1, length - overlap)


def make_windows(
    frame_counts: Sequence[int],
    length: int,
    overlap: int = 0,
    takes: Sequence[int] | None = None,
) -> list[tuple[int, int]]:
    """``(take index, start)`` of every window, take by take.

    Args:
        frame_counts: frames of each take, indexed by take.
        length / overlap: window size and the frames two neighbouring windows share.
        takes: the take indices to cut (a split, say); all takes when ``None``.
    """
    chosen = range(len(frame_counts)) if takes is None else takes
    return [(t, s) for t in chosen for s in window_starts(int(frame_counts[t]), length, overlap)]


class WindowDataset(Dataset):
    """Windows of cached takes as training samples.

    Each item is a dict: ``rotations`` ``[W, J, 4]`` local x,y,z,w quaternions, ``root_positions``
    ``[W, 3]``, ``offsets`` ``[J, 3]`` (the take's rest offsets: they differ between performers),
    and the ints ``take``, ``style``, ``content`` (ids into ``cache.styles`` / ``cache.contents``),
    ``start``. All takes used must share one rig (joint names and parents) so that windows batch.
    """

    def __init__(self, cache: MotionCache, length: int, overlap: int = 0, takes: Sequence[int] | None = None) -> None:
        self.cache = cache
        self.length = length
        self.overlap = overlap
        self.takes = tuple(range(len(cache)) if takes is None else takes)
        if self.takes:
            first = cache.skeleton(self.takes[0])
            others = [t for t in self.takes if not cache.skeleton(t).same_rig(first)]
            if others:
                raise ValueError(
                    f"takes {cache.takes[self.takes[0]].take_id} and {cache.takes[others[0]].take_id} have "
                    "different rigs; windows of one dataset must share joint names and parents")
        self.windows = make_windows(cache.frame_counts, length, overlap, self.takes)

    def __len__(self) -> int:
        return len(self.windows)

    def __getitem__(self, index: int) -> dict[str, Any]:
        take, start = self.windows[index]
        stop = start + self.length
        return {
            "rotations": self.cache.rotations(take)[start:stop],
            "root_positions": self.cache.root_positions(take)[start:stop],
            "offsets": self.cache.skeleton(take).offsets_tensor(),
            "take": take,
            "style": self.cache.style_id(take),
            "content": self.cache.content_id(take),
            "start": start,
        }

    @property
    def window_styles(self) -> list[int]:
        """Style id of each window, for :class:`StyleBalancedBatchSampler`."""
        ids = {t: self.cache.style_id(t) for t in self.takes}
        return [ids[t] for t, _ in self.windows]


def _seed(*numbers: int) -> int:
    """A generator seed from integers, the same in every process (``hash`` of a str is not)."""
    digest = hashlib.sha256(",".join(map(str, numbers)).encode()).digest()
    return int.from_bytes(digest[:8], "big") >> 1


class StyleBalancedBatchSampler(Sampler[list[int]]):
    """Batches of one style each, with every style contributing the same number of batches per epoch.

    Approach: each style has an endless stream of its window indices, made of successive random
    permutations (seeded by ``seed``, the style and the permutation's number). Epoch ``e`` takes the
    next ``batches_per_style * batch_size`` indices of every style's stream and shuffles the batches
    of all styles together. ``batches_per_style`` defaults to the number that keeps an epoch as long
    as one pass over all windows, ``ceil(windows / (batch_size * styles))``. So a large style is
    sampled without replacement and walks through all of its windows over a few epochs (nothing is
    discarded, unlike capping every style at the smallest one), while a small style's windows repeat
    more often. A style with fewer windows than ``batch_size`` repeats windows inside a batch.

    Call :meth:`set_epoch` before each epoch (as with ``DistributedSampler``); the batches are a
    pure function of ``(seed, epoch)``.
    """

    def __init__(
        self,
        styles: Sequence[int],
        batch_size: int,
        batches_per_style: int | None = None,
        seed: int = 0,
    ) -> None:
        if batch_size <= 0:
            raise ValueError(f"batch_size must be positive, got {batch_size}")
        self.batch_size = batch_size
        self.seed = seed
        self.epoch = 0
        by_style: dict[int, list[int]] = {}
        for index, style in enumerate(styles):
            by_style.setdefault(int(style), []).append(index)
        self.members = {s: torch.tensor(v) for s, v in sorted(by_style.items())}
        if batches_per_style is None:
            batches_per_style = -(-len(styles) // (batch_size * max(1, len(self.members)))) if styles else 0
        if batches_per_style < 0:
            raise ValueError("batches_per_style must be non-negative")
        self.batches_per_style = batches_per_style

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.batches_per_style * len(self.members)

    def _stream(self, style: int, begin: int, count: int) -> torch.Tensor:
        """Items ``[begin, begin + count)`` of the style's stream of permutations."""
        members = self.members[style]
        n = len(members)
        out = []
        first, last = begin // n, (begin + count - 1) // n
        for cycle in range(first, last + 1):
            g = torch.Generator().manual_seed(_seed(self.seed, style, cycle))
            perm = members[torch.randperm(n, generator=g)]
            lo = begin - cycle * n if cycle == first else 0
            hi = begin + count - cycle * n if cycle == last else n
            out.append(perm[lo:hi])
        return torch.cat(out)

    def __iter__(self) -> Iterator[list[int]]:
        per_style = self.batches_per_style * self.batch_size
        if per_style == 0:
            return iter(())
        batches = []
        for style in self.members:
            items = self._stream(style, self.epoch * per_style, per_style)
            batches += [items[i:i + self.batch_size].tolist() for i in range(0, per_style, self.batch_size)]
        g = torch.Generator().manual_seed(_seed(self.seed, -1, self.epoch))
        order = torch.randperm(len(batches), generator=g).tolist()
        return iter([batches[i] for i in order])
