"""The capture's gait limits: measured per style on a data set's train split, saved beside a bundle's config and
loaded with it; a style the capture does not hold takes the largest built-in maximum."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from model.data.gait_capture import measure_gait_limits
from model.data.preprocessed import load_motion_cache
from model.data.synthetic import SYNTHETIC_STYLES, synthetic_skeleton, write_synthetic_dataset
from model.inference.bundle import Bundle, BundleError
from model.motion.gait_limits import GAIT_LIMITS_FILE, GaitLimits, StyleGait, gait_of
from tests.model.tiny_bundles import tiny_bundle


@pytest.fixture(scope="module")
def limits(tmp_path_factory: pytest.TempPathFactory) -> GaitLimits:
    root = tmp_path_factory.mktemp("gait")
    write_synthetic_dataset(root / "data", takes_per_pair=3, frames=90)
    cache = load_motion_cache(root / "data", workers=1, progress=False, root=root / "cache")
    return measure_gait_limits(cache)


def test_each_style_s_top_speed_is_its_fastest_train_take_s(limits: GaitLimits) -> None:
    assert set(limits.styles) == set(SYNTHETIC_STYLES)
    for style, (speed, _, _) in SYNTHETIC_STYLES.items():
        got = limits.styles[style]
        # The synthetic takes of a style walk at speed x 1.00, 1.05 or 1.10 (one speed a take): the top is one of them.
        assert any(got.max_speed_cm_s == pytest.approx(speed * (1 + 0.05 * n), rel=1e-3) for n in range(3))
        assert speed * 0.999 <= got.p99_speed_cm_s <= got.max_speed_cm_s
        lo, hi = got.hips_cm["walk"]
        assert 92.0 - 1.5 - 1e-3 <= lo < hi <= 92.0 + 1.5 + 1e-3  # the synthetic hips bob 1.5 cm about 92
        assert got.takes > 0 and 0.0 < got.foot_lift_cm < 30.0  # the synthetic feet swing, never all leave the floor
        assert 0.0 <= got.planted_rise_cm < 100.0  # measured (the synthetic swing slows high up: no bound of a real walk)
    assert limits.max_speed("slow") == limits.styles["slow"].max_speed_cm_s
    assert limits.max_speed("a-clip-style") == max(s.max_speed_cm_s for s in limits.styles.values())
    assert limits.max_speed(None) == limits.max_speed("a-clip-style")
    assert limits.foot_lift("a-clip-style") == max(s.foot_lift_cm for s in limits.styles.values())
    assert limits.planted_rise("a-clip-style") == max(s.planted_rise_cm for s in limits.styles.values())


def test_gaits_of_content_labels() -> None:
    assert [gait_of(c) for c in ("walk", "walk-turn-left", "walk-back", "run", "dash", "wave-both-hands")] == [
        "walk", "walk", "walk", "run", "run", "stand"]


def test_the_limits_travel_with_the_bundle(limits: GaitLimits, tmp_path: Path) -> None:
    bundle = tiny_bundle(1)
    bundle.gait_limits = limits
    bundle.save(tmp_path / "b")
    assert (tmp_path / "b" / GAIT_LIMITS_FILE).stat().st_size < 4096
    loaded = Bundle.load(tmp_path / "b")
    assert loaded.gait_limits is not None and set(loaded.gait_limits.styles) == set(limits.styles)
    for name, style in limits.styles.items():
        assert loaded.gait_limits.styles[name].max_speed_cm_s == pytest.approx(style.max_speed_cm_s, abs=0.05)
        assert loaded.gait_limits.styles[name].planted_rise_cm == pytest.approx(style.planted_rise_cm, abs=0.05)
    (tmp_path / "b" / GAIT_LIMITS_FILE).write_text(json.dumps({"format": "rsmt-gait-limits/0", "styles": {}}))
    with pytest.raises(BundleError, match="gait limits format"):
        Bundle.load(tmp_path / "b")
    (tmp_path / "b" / GAIT_LIMITS_FILE).unlink()
    assert Bundle.load(tmp_path / "b").gait_limits is None  # an older bundle: not capped


def test_bad_limits_are_refused() -> None:
    with pytest.raises(ValueError, match="positive"):
        StyleGait(0.0, 0.0)
    with pytest.raises(ValueError, match="hips height"):
        StyleGait(100.0, 90.0, {"walk": (95.0, 80.0)})
    with pytest.raises(ValueError, match="at least one style"):
        GaitLimits({})
    assert synthetic_skeleton().roles.root == 0  # the hips are the rig's root, whose positions the cache holds
