"""Evaluation and style classifier on the real Bandai-Namco takes (skipped with a reason when the data is absent).

Bounded: a subset of cases and a short classifier training, well under a minute together once the
motion cache exists.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from model.data.preprocessed import MotionCache, load_motion_cache
from model.evaluation import EvalSettings, evaluate, resolve_method
from model.nets.style_classifier import StyleClassifierConfig
from model.train.classifier_stage import TrainSettings, build_windows, check_classifier, train_classifier

pytestmark = [pytest.mark.real_data, pytest.mark.usefixtures("one_thread")]


@pytest.fixture(scope="module")
def cache(shared_data: Path) -> MotionCache:
    return load_motion_cache(shared_data, progress=False)


def test_interp_beats_zerovel_and_reaches_the_target(cache: MotionCache) -> None:
    methods = [resolve_method("interp"), resolve_method("zerovel")]
    run = evaluate(cache, methods, EvalSettings(limit=80, render_cases=0), progress=False)
    report = run.report
    assert report["cases"] == 80 and len(report["styles"]) == 7
    # Feet rest above the floor in this data (toes ~4.25 cm, ankles ~11.7 cm; data README).
    ankle_l, toe_l, ankle_r, toe_r = report["reference"]["ground_cm"]
    assert 10.0 < ankle_l < 13.5 and 10.0 < ankle_r < 13.5 and 3.0 < toe_l < 6.0 and 3.0 < toe_r < 6.0
    interp = report["methods"]["interp"]["variants"]
    zerovel = report["methods"]["zerovel"]["variants"]
    for gap in ("gap10", "gap20", "gap40"):
        assert interp[gap]["l2p"] < zerovel[gap]["l2p"], gap
        assert interp[gap]["npss"] < zerovel[gap]["npss"], gap
        assert 0.1 < report["ground_truth"][gap]["foot_skate"] < 0.6  # real feet barely slide
        assert interp[gap]["foot_skate"] > report["ground_truth"][gap]["foot_skate"]  # interpolation slides
    for v in ("gap40", "gap40-dt2", "gap40-dt0.5", "gap40-d2", "gap40-d-1"):
        assert interp[v]["last_frame_cm"] < 1e-3 and zerovel[v]["last_frame_cm"] < 1e-3
    # Errors grow with the gap.
    assert interp["gap10"]["l2p"] < interp["gap20"]["l2p"] < interp["gap40"]["l2p"]


def test_quick_classifier_recognises_real_styles(cache: MotionCache) -> None:
    train = build_windows(cache, cache.split.train[::5], window=40, step=10)
    cfg = StyleClassifierConfig(styles=cache.styles, channels=48, feature_dim=32)
    result = train_classifier(train, None, cfg, TrainSettings(epochs=3, iterations=40, batch=64), progress=False)
    check = check_classifier(result.model, cache, cache.split.test[::3])
    # A short training already separates the styles; the full recipe reaches 0.998
    # (docs/experiments/2026-11-evaluation-history.md).
    assert check["accuracy"] > 0.8, check["accuracy"]
    assert set(check["per_style"]) == set(cache.styles)
    assert "interpolation" in check and "zero_velocity" in check
