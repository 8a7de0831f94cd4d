"""Per-key shares of the step budget (service.streaming.step_shares) and the per-key batches (lanes) they step."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from model.inference.bundle import Bundle
from model.inference.engine import Engine
from service.streaming.lanes import Lanes
from service.streaming.step_shares import CREDIT_S, StepShares
from tests.service.conftest import context_clip, target_clip, walk


def test_with_shares_off_every_key_is_one_owner_and_nothing_adapts():
    shares = StepShares(enabled=False)
    assert shares.owner("key-a") == shares.owner("key-b") == ""
    assert shares.rows is None
    with pytest.raises(ValueError):
        StepShares(enabled=True, rows=0)
    with pytest.raises(ValueError):
        shares.charge("", -1.0)


def test_the_least_used_key_goes_first_and_a_new_key_joins_near_the_busiest():
    shares = StepShares(enabled=True)
    assert shares.owner("a") == "a"
    shares.charge("a", 1.0)
    assert shares.first(["a", "b"]) == "b"  # b has used nothing
    shares.charge("b", 2.0)
    assert shares.order(["a", "b"]) == ["a", "b"]
    # c, new, starts CREDIT_S behind the busiest key, never at zero: it cannot take the thread for a second.
    assert shares.order(["a", "b", "c"])[0] == "a"
    assert shares.used["c"] == pytest.approx(shares.used["b"] - CREDIT_S)
    shares.keep(["b"])
    assert set(shares.used) == {"b"}
    assert shares.first([]) is None


def _serve(sizes: dict[str, float], seconds: float) -> dict[str, float]:
    """Step time each key gets when each asap step goes to ``StepShares.first`` of the keys and a step of key
    ``k`` takes ``sizes[k]`` seconds, for ``seconds`` of steps."""
    shares, got, clock = StepShares(enabled=True), dict.fromkeys(sizes, 0.0), 0.0
    while clock < seconds:
        k = shares.first(sizes)
        assert k is not None
        shares.charge(k, sizes[k], asap=True)
        got[k] += sizes[k]
        clock += sizes[k]
    return got


@settings(max_examples=30, deadline=None)
@given(st.dictionaries(st.sampled_from("abcdef"), st.floats(0.002, 0.2), min_size=1, max_size=6))
def test_keys_of_any_step_lengths_get_about_equal_step_time(sizes: dict[str, float]):
    seconds = 20.0
    got = _serve(sizes, seconds)
    fair = seconds / len(sizes)
    for k, t in got.items():
        # Within one step of the longest (the order is decided step by step) and the credit of a new key.
        assert abs(t - fair) <= 2 * max(sizes.values()) + CREDIT_S, (k, t, fair, sizes)


@pytest.fixture(scope="module")
def engine(bundle_dir) -> Engine:
    return Engine(Bundle.load(bundle_dir))


def test_lanes_hold_each_keys_characters_apart_in_batches_of_at_most_rows(engine):
    style, _ = engine.encode_style(walk(30))
    lanes = Lanes(engine, rows=3)
    chars = {k: [engine.prepare(context_clip(), target_clip(), 10, style, seed=i) for i in range(n)]
             for k, n in (("a", 6), ("b", 1))}
    for k, cs in chars.items():
        for ch in cs:
            lanes.add(ch, "asap", k)
    assert lanes.owners("asap") == ["a", "b"] and lanes.owners("realtime") == []
    assert sorted(len(b) for b in lanes.of("asap", "a")) == [3, 3] and len(lanes.of("asap", "b")) == 1
    assert all(ch not in b.members and ch not in b._pending for b in lanes.of("asap", "a") for ch in chars["b"])
    # Round robin over a key's lanes.
    assert len({id(lanes.in_turn("asap", "a")[0]) for _ in range(2)}) == 2
    for b in lanes.of("asap", "a"):
        b.step()  # members join the batch
    ch = chars["a"][0]
    lane = lanes.lane_of(ch)
    assert lane is not None and lanes.detach(ch) is lane and lanes.lane_of(ch) is None
    assert sum(map(len, lanes.of("asap", "a"))) == 5
    lanes.add(ch, "asap", "a")  # resumed into the lane with room
    assert sorted(len(b) for b in lanes.of("asap", "a")) == [3, 3]
    # A lane whose step failed is emptied and dropped; its characters are handed back.
    failed = lanes.of("asap", "b")[0]
    failed.step()
    assert lanes.replace(failed) == chars["b"] and lanes.owners("asap") == ["a"]


def test_lanes_let_go_of_characters_that_will_never_step_again(engine):
    style, _ = engine.encode_style(walk(30))
    lanes = Lanes(engine, rows=4)
    a, b, c = (engine.prepare(context_clip(), target_clip(), 10, style, seed=i) for i in range(3))
    # Cancelled before its first step: taken out of its lane at once, the empty lane dropped.
    lanes.add(a, "asap", "k")
    assert lanes.withdraw(a) and lanes.lane_of(a) is None and lanes.owners("asap") == [] and len(lanes) == 2
    assert not lanes.withdraw(a)  # in no lane
    # A member is left for the scheduler's prune (a restack) while others in its lane live ...
    lanes.add(b, "asap", "k")
    lanes.add(c, "asap", "k")
    lanes.of("asap", "k")[0].step()
    assert not lanes.withdraw(b) and lanes.lane_of(b) is not None
    b.cancelled = True
    assert lanes.sweep() == [] and lanes.lane_of(b) is not None
    # ... and once none lives, the lane is emptied without any step.
    c.cancelled = True
    assert sorted(map(id, lanes.sweep())) == sorted(map(id, (b, c)))
    assert lanes.owners("asap") == [] and len(lanes) == 2 and lanes.lane_of(c) is None
