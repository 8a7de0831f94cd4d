"""The style-code probe: nearest centroids with each take left out of its own, and separation."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.evaluation.style_code_probe import probe_codes, probe_table


def _clusters(offset: float, per: int, seed: int) -> tuple[torch.Tensor, list[str]]:
    gen = torch.Generator().manual_seed(seed)
    centres = {"a": torch.zeros(6), "b": torch.zeros(6), "c": torch.zeros(6)}
    centres["b"][0] = offset
    centres["c"][1] = offset
    codes = torch.cat([c + torch.randn(per, 6, generator=gen) for c in centres.values()])
    return codes, [s for s in centres for _ in range(per)]


@settings(max_examples=25, deadline=None)
@given(st.floats(20.0, 100.0), st.integers(3, 8), st.integers(0, 1000), st.floats(0.1, 10.0), st.floats(-5.0, 5.0))
def test_apart_styles_are_found_and_a_change_of_units_changes_nothing(offset, per, seed, scale, shift) -> None:
    codes, labels = _clusters(offset, per, seed)
    probe = probe_codes(codes, labels)
    assert all(a == 1.0 for a in probe.accuracy.values())
    assert all(s > 1.0 for s in probe.separation.values())
    for style, row in probe.read_as.items():
        assert sum(row.values()) == pytest.approx(1.0) and row[style] == probe.accuracy[style]
    # Centred and scaled in float64 (the probe computes in it): units and origin do not matter, and float32 rounding
    # of the moved codes themselves (1e-6 relative after standardising) is not what is tested.
    moved = probe_codes(codes.double() * scale + shift, labels)
    assert moved.accuracy == probe.accuracy and moved.nearest == probe.nearest
    assert moved.separation == pytest.approx(probe.separation)


def test_one_distribution_under_two_names_is_not_separated() -> None:
    codes = torch.randn(200, 4, generator=torch.Generator().manual_seed(0))
    probe = probe_codes(codes, ["a", "b"] * 100)
    assert all(s < 0.5 for s in probe.separation.values())
    assert all(0.2 < a < 0.8 for a in probe.accuracy.values())


def test_clips_of_one_take_do_not_vouch_for_each_other() -> None:
    # Style a: take a1 (four clips at 0), take a2 (four at -6); style b: four clips at 4, four at 5.
    x = torch.tensor([0.0] * 4 + [-6.0] * 4 + [4.0] * 4 + [5.0] * 4).unsqueeze(1)
    labels = ["a"] * 8 + ["b"] * 8
    # Clip by clip, a1's clips find their style (its centroid, their twins included, 3.4 away; b's 4.5) ...
    assert probe_codes(x, labels).read_as["a"]["a"] == 1.0
    # ... but without their take, a's centroid is a2's, 6 away: they are read as b.
    groups = ["a1"] * 4 + ["a2"] * 4 + ["b1"] * 4 + ["b2"] * 4
    probe = probe_codes(x, labels, groups=groups)
    assert probe.read_as["a"] == {"a": 0.5, "b": 0.5} and probe.accuracy["b"] == 1.0
    assert "| a | 8 | 0.500 | b 0.500 |" in "\n".join(probe_table("m", probe))


def test_bad_inputs_are_refused() -> None:
    with pytest.raises(ValueError, match="two groups"):
        probe_codes(torch.zeros(4, 2), ["a", "a", "b", "b"], groups=["1", "1", "2", "3"])
    with pytest.raises(ValueError, match="share one style"):
        probe_codes(torch.zeros(4, 2), ["a", "a", "b", "b"], groups=["1", "2", "2", "3"])
    with pytest.raises(ValueError, match="a style per row"):
        probe_codes(torch.zeros(4, 2), ["a", "b"])
