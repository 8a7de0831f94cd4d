"""The stream yardstick (model/evaluation/stream_retarget.py): a stream retargeted mid-motion is
scored against the moved target, and a stream never retargeted equals the transition sent whole."""

from __future__ import annotations

import pytest
import torch

from model.data.preprocessed import load_motion_cache
from model.data.synthetic import synthetic_skeleton, write_synthetic_dataset
from model.evaluation import CaseSet, build_cases
from model.evaluation.cases import variant
from model.evaluation.methods import BundleMethod, Request
from model.evaluation.stream_retarget import RetargetSettings, retarget_report, stream
from model.inference.bundle import Bundle

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory) -> tuple[CaseSet, BundleMethod]:
    root = tmp_path_factory.mktemp("retarget")
    write_synthetic_dataset(root / "data", takes_per_pair=2, frames=150)
    cache = load_motion_cache(root / "data", root=root / "cache", workers=1, progress=False)
    cases = CaseSet.load(cache, build_cases(cache, cache.split.train, limit=6))
    bundle = Bundle.create(synthetic_skeleton()).save(root / "bundle")
    return cases, BundleMethod(bundle)


def test_a_stream_sent_to_the_moved_target_from_the_start_is_the_whole_transition(setup) -> None:
    cases, method = setup
    rot, root = stream(method, cases, RetargetSettings(), retarget=False)
    whole_rot, whole_root = method.generate(cases, Request(variant("gap40-side1m")))
    assert torch.allclose(rot, whole_rot, atol=1e-5) and torch.allclose(root, whole_root, atol=1e-4)


def test_the_report_scores_the_moved_target_and_checks_the_frame(setup) -> None:
    cases, method = setup
    r = retarget_report(method, cases)
    assert r["cases"] == len(cases) and r["retarget_at"] == 20 and r["moved_cm"] == 100.0
    for name in ("retargeted", "from_start"):
        assert r[name]["arrival_cm"] >= 0 and r[name]["arrival_cm_p90"] >= r[name]["arrival_cm_median"] - 1e-6
    # The retarget changes what is generated from frame 20 on, so its arrival differs from the stream's.
    assert r["retargeted"]["arrival_cm"] != r["from_start"]["arrival_cm"]
    with pytest.raises(ValueError, match="retarget frame"):
        retarget_report(method, cases, RetargetSettings(at=40))


def test_a_method_with_exact_arrival_streams_with_it(setup) -> None:
    cases, method = setup
    exact = BundleMethod(method.path, exact_arrival=True)
    r = retarget_report(exact, cases)
    assert r["exact_arrival"] is True and retarget_report(method, cases)["exact_arrival"] is False
    # Bent onto the moved target, retargeted mid-stream or sent there from the start.
    assert r["retargeted"]["arrival_cm"] < 0.05 and r["from_start"]["arrival_cm"] < 0.05


def test_each_case_can_be_retargeted_at_its_own_frame(setup) -> None:
    cases, method = setup
    settings = RetargetSettings()
    at_20 = stream(method, cases, settings, retarget=True)
    same = stream(method, cases, settings, retarget=True, at=[20] * len(cases))
    assert torch.equal(at_20[0], same[0]) and torch.equal(at_20[1], same[1])
    staggered = [20 + 3 * b for b in range(len(cases))]
    rot, _ = stream(method, cases, settings, retarget=True, at=staggered)
    late, _ = stream(method, cases, settings, retarget=True, at=[39] * len(cases))  # the first target until frame 39
    for b, at in enumerate(staggered):  # each case as the late one until its own retarget, then elsewhere
        assert torch.allclose(rot[b, :at], late[b, :at], atol=1e-5)
        assert not torch.allclose(rot[b, -1], late[b, -1], atol=1e-4)
    with pytest.raises(ValueError, match="one retarget frame per case"):
        stream(method, cases, settings, retarget=True, at=[20])
    with pytest.raises(ValueError, match="one retarget frame per case"):
        stream(method, cases, settings, retarget=True, at=[0] * len(cases))
