"""Tests of the deterministic, stratified, hash-based split of takes."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from model.data.splits import (
    DEFAULT_RATIOS,
    SPLITS,
    Split,
    check_ratios,
    group_shares,
    hash_fraction,
    parse_ratios,
    split_takes,
)
from model.data.takes import Take


def make_takes(groups: dict[tuple[str, str], int], prefix: str = "") -> list[Take]:
    return [
        Take(path=Path(f"/data/{style}_{content}_{n}.bvh"), style=style, content=content,
             take_id=f"{prefix}dataset-2_{content}_{style}_{n:03d}")
        for (style, content), count in groups.items() for n in range(count)
    ]


STYLES = ("active", "elderly", "exhausted", "feminine", "masculine", "normal", "youthful")
CONTENTS = ("walk", "run", "wave-left-hand", "raise-up-both-hands")


def realistic_takes() -> list[Take]:
    rng = random.Random(7)
    return make_takes({(s, c): rng.randint(15, 90) for s in STYLES for c in CONTENTS})


def split_of_each(split: Split) -> dict[int, str]:
    """The split name of each take index (holdout included)."""
    return {i: name for name in (*SPLITS, "holdout") for i in split[name]}


def assignment_by_key(takes: list[Take], **kwargs) -> dict[str, str]:
    split = split_takes(takes, **kwargs)
    return {takes[i].key: name for i, name in split_of_each(split).items()}


def test_split_is_a_partition_with_the_ratios() -> None:
    takes = realistic_takes()
    split = split_takes(takes)
    everything = split.train + split.val + split.test
    assert sorted(everything) == list(range(len(takes)))
    n = len(takes)
    assert abs(len(split.train) / n - 0.8) < 0.02
    assert abs(len(split.val) / n - 0.1) < 0.02
    assert abs(len(split.test) / n - 0.1) < 0.02
    assert split.holdout == () and split.ratios == DEFAULT_RATIOS


def test_split_is_deterministic_and_independent_of_order() -> None:
    takes = realistic_takes()
    first = assignment_by_key(takes)
    shuffled = takes[:]
    random.Random(1).shuffle(shuffled)
    assert assignment_by_key(shuffled) == first
    assert assignment_by_key(takes) == first


def test_hash_is_fixed_across_machines_and_versions() -> None:
    # A changed value would silently move takes between splits (test data leaking into training).
    assert hash_fraction("active/walk/data/dataset-2_walk_active_001") == pytest.approx(0.2495811, abs=1e-7)
    assert hash_fraction("a", salt="x") != hash_fraction("a", salt="y")


def test_every_group_reaches_every_split() -> None:
    takes = make_takes({("a", "walk"): 3, ("a", "run"): 5, ("b", "walk"): 12, ("b", "run"): 2, ("c", "run"): 1})
    split = split_takes(takes)
    for name in ("train", "val", "test"):
        groups = {(takes[i].style, takes[i].content) for i in split[name]}
        assert {("a", "walk"), ("a", "run"), ("b", "walk")} <= groups, name
    # Too small for three splits: all train.
    assert {takes[i].style for i in split.train if takes[i].content == "run" and takes[i].style in "bc"} == {"b", "c"}


def test_adding_a_take_moves_few_others() -> None:
    takes = realistic_takes()
    before = assignment_by_key(takes)
    extra = make_takes({("normal", "walk"): 1}, prefix="new-")
    after = assignment_by_key(takes + extra)
    moved = [k for k in before if before[k] != after[k]]
    assert len(moved) <= 2
    assert all(k.startswith("normal/walk/") for k in moved)


def test_holdout_styles() -> None:
    takes = realistic_takes()
    split = split_takes(takes, (0.8, 0.1, 0.1), holdout_styles=["elderly", "youthful"])
    assert {takes[i].style for i in split.holdout} == {"elderly", "youthful"}
    assert len(split.holdout) == sum(t.style in ("elderly", "youthful") for t in takes)
    for name in ("train", "val", "test"):
        assert not {takes[i].style for i in split[name]} & {"elderly", "youthful"}
    # The other styles keep exactly the assignment they have without the hold-out.
    plain = assignment_by_key(takes)
    held = {takes[i].key: name for i, name in split_of_each(split).items()}
    assert all(held[k] == plain[k] for k in plain if not k.startswith(("elderly/", "youthful/")))
    with pytest.raises(ValueError, match="zombie"):
        split_takes(takes, holdout_styles=["zombie"])


def test_other_ratios_and_salt() -> None:
    takes = realistic_takes()
    split = split_takes(takes, (0.6, 0.2, 0.2))
    assert abs(len(split.val) / len(takes) - 0.2) < 0.03
    no_val = split_takes(takes, (0.9, 0, 0.1))
    assert no_val.val == ()
    assert assignment_by_key(takes, salt="other") != assignment_by_key(takes)


@pytest.mark.parametrize("bad", [(1, 0), (0.0, 0.5, 0.5), (0.8, -0.1, 0.3), (float("nan"), 0, 0)])
def test_bad_ratios(bad: tuple[float, ...]) -> None:
    with pytest.raises(ValueError):
        check_ratios(bad)


def test_parse_ratios() -> None:
    assert parse_ratios("8/1/1") == pytest.approx((0.8, 0.1, 0.1))
    assert parse_ratios("0.7,0.2,0.1") == pytest.approx((0.7, 0.2, 0.1))
    with pytest.raises(ValueError):
        parse_ratios("a,b,c")


@given(n=st.integers(0, 400), ratios=st.tuples(st.floats(0.05, 1), st.floats(0, 1), st.floats(0, 1)))
def test_group_shares_properties(n: int, ratios: tuple[float, float, float]) -> None:
    r = check_ratios(ratios)
    shares = group_shares(n, r)
    assert sum(shares) == n and min(shares) >= 0
    wanted = [i for i, x in enumerate(r) if x > 0]
    if n >= len(wanted):
        assert all(shares[i] >= 1 for i in wanted)
    for i, x in enumerate(r):
        if x == 0:
            assert shares[i] == 0
        # Never more than one take (plus the minimum-one top-ups) away from the exact share.
        assert abs(shares[i] - n * x) <= 1 + len(wanted)
