"""The evaluation (model/evaluation, rsmt eval) on a tiny synthetic dataset: cases, scores, report, pictures."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from model.data.preprocessed import MotionCache
from model.data.synthetic import synthetic_skeleton
from model.evaluation import VARIANTS, CaseSet, EvalSettings, build_cases, evaluate, resolve_method
from model.evaluation.cases import CONTEXT, LAST_CONTEXT, SPAN, variant
from model.evaluation.methods import BundleMethod, Request
from model.evaluation.reference import reference_stats
from model.evaluation.report import markdown
from model.evaluation.runner import eval_split as runner_split
from model.evaluation.style_scores import matched_reference
from model.inference.bundle import Bundle
from model.inference.overrides import Overrides
from model.nets.style_classifier import StyleClassifierConfig
from model.train.classifier_stage import TrainSettings, build_windows, train_classifier
from rsmt_cli.main import main

GAPS = ("gap10", "gap20", "gap40")
CONTROLS = ("gap40-dt2", "gap40-dt0.5", "gap40-d2", "gap40-d-1")
LOCOMOTION_CONTROLS = ("gap40-turn+90", "gap40-turn-90", "gap40-side1m")  # asked of locomotion cases only

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def stats(cache: MotionCache):
    return reference_stats(cache, cache.split.train)


@pytest.fixture(scope="module")
def bundle_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return Bundle.create(synthetic_skeleton()).save(tmp_path_factory.mktemp("bundle") / "random")


@pytest.fixture(scope="module")
def classifier_dir(cache: MotionCache, tmp_path_factory: pytest.TempPathFactory) -> Path:
    train = build_windows(cache, cache.split.train, 40, 20)
    cfg = StyleClassifierConfig(styles=cache.styles, joints=21, channels=16, feature_dim=8, layers=2)
    result = train_classifier(train, None, cfg, TrainSettings(epochs=1, iterations=2, batch=8, normalisation_windows=32),
                              progress=False)
    return result.model.save(tmp_path_factory.mktemp("clf") / "clf")


@pytest.fixture(scope="module")
def judge_dir(cache: MotionCache, tmp_path_factory: pytest.TempPathFactory) -> Path:
    from model.evaluation.style_judge import fit_judge, take_windows

    feats, styles, _ = take_windows(cache, cache.split.train, step=20)
    labels = torch.tensor([cache.styles.index(s) for s in styles])
    judge = fit_judge(feats, labels, cache.styles, list(synthetic_skeleton().names), cache.fps)
    return judge.save(tmp_path_factory.mktemp("judge") / "judge")


# ------------------------------------------------------------------ cases
def test_cases_are_deterministic_and_paired(cache: MotionCache) -> None:
    takes = cache.split.test
    cases = build_cases(cache, takes)
    assert cases == build_cases(cache, list(reversed(takes)))
    assert len(cases) == len(takes) * 3  # 150-frame takes: windows at 0, 40, 80
    for c in cases:
        assert c.style == cache.takes[c.take].style
        assert c.style_take != c.take and cache.takes[c.style_take].style == c.style
        assert c.cross_style != c.style and cache.takes[c.cross_take].style == c.cross_style
        assert c.style_frames == 120 == c.cross_frames
        assert c.start + SPAN <= cache.num_frames(c.take)
    limited = build_cases(cache, takes, limit=5)
    assert len(limited) == 5 and limited[0] == cases[0] and set(limited) <= set(cases)
    assert len({c.style for c in limited}) == len(cache.styles)
    # A style filter keeps exactly that style's cases, unchanged (their clips still come from all takes).
    one = cache.styles[0]
    only = build_cases(cache, takes, only_styles=[one])
    assert only and only == [c for c in cases if c.style == one]


def test_clips_only_takes_give_no_case_but_stay_style_clips(cache: MotionCache) -> None:
    one = cache.styles[0]
    split = cache.make_split(holdout_styles=[one])
    held = split.holdout
    assert held and all(cache.takes[i].style == one for i in held)
    cases = build_cases(cache, held, clip_fallback=split.train)
    skipped = cache.takes[cases[0].style_take].take_id  # a take that serves another case as its style clip
    kept = build_cases(cache, held, clip_fallback=split.train, clips_only=[skipped])
    assert kept == [c for c in cases if cache.takes[c.take].take_id != skipped]
    assert any(cache.takes[c.style_take].take_id == skipped for c in kept)


def test_holdout_split_and_its_errors(cache: MotionCache) -> None:
    one = cache.styles[0]
    settings = EvalSettings(split="holdout", holdout_styles=(one,))
    assert set(runner_split(cache, settings).holdout) == {i for i, t in enumerate(cache.takes) if t.style == one}
    with pytest.raises(ValueError, match="needs the held-out styles"):
        runner_split(cache, EvalSettings(split="holdout"))
    with pytest.raises(ValueError, match="held-out style.*not in the data"):
        runner_split(cache, EvalSettings(holdout_styles=("nosuch",)))
    with pytest.raises(ValueError, match="no take nosuch"):
        evaluate(cache, [], EvalSettings(clips_only=("nosuch",)), progress=False)


def test_variants_and_targets(cache: MotionCache) -> None:
    cs = CaseSet.load(cache, build_cases(cache, cache.split.test, limit=4))
    assert [v.frames for v in VARIANTS] == [10, 20, 40, 80, 20, 40, 40, 40, 40, 40]
    assert [v.has_ground_truth for v in VARIANTS] == [True] * 3 + [False] * 7
    assert [v.name for v in VARIANTS if v.locomotion_only] == list(LOCOMOTION_CONTROLS)
    base = variant("gap40")
    assert base.target_frame == LAST_CONTEXT + 40 == SPAN - 1
    torch.testing.assert_close(cs.target_positions(base), cs.positions[:, -1])
    for name, d in (("gap40-d2", 2.0), ("gap40-d-1", -1.0)):
        v = variant(name)
        shift = cs.target_positions(v)[:, 0] - cs.positions[:, LAST_CONTEXT, 0]  # root relative to frame 9
        travel = cs.positions[:, -1, 0] - cs.positions[:, LAST_CONTEXT, 0]
        torch.testing.assert_close(shift[:, [0, 2]], d * travel[:, [0, 2]])
        torch.testing.assert_close(shift[:, 1], travel[:, 1])  # heights unchanged
        rot, root = cs.targets(v, 2)
        assert rot.shape[1] == 2 and torch.equal(rot, cs.rotations[:, -2:])
        torch.testing.assert_close(root[:, 1] - root[:, 0], cs.roots[:, -1] - cs.roots[:, -2], atol=1e-3, rtol=0)
    with pytest.raises(ValueError):
        cs.ground_truth(variant("gap40-dt2"))
    pos, _ = cs.ground_truth(variant("gap10"))
    assert pos.shape[1] == 10 and torch.equal(pos, cs.positions[:, CONTEXT:CONTEXT + 10])
    # The canonical frame is frame 9's: its root sits over the origin, facing +Z.
    canon = cs.canonical_positions[:, LAST_CONTEXT, 0]
    torch.testing.assert_close(canon[:, [0, 2]], torch.zeros(len(cs), 2), atol=1e-4, rtol=0)


def test_reference_stats(stats, cache: MotionCache) -> None:
    assert stats.positions.num_joints == 21 and stats.windows == len(cache.split.train) * 3
    assert stats.ground.shape == (4,) and bool((stats.positions.std >= 0).all())


def test_matched_reference_round_robin() -> None:
    feats = torch.arange(4.0).unsqueeze(1)
    ref, kept = matched_reference(feats, ["a", "b", "a", "b"], ["b", "b", "b", "c", "a"])
    assert ref.flatten().tolist() == [1.0, 3.0, 1.0, 0.0] and kept.tolist() == [0, 1, 2, 4]


# ------------------------------------------------------------------ whole runs
def _check_baseline_rows(report: dict) -> None:
    """interp and zerovel arrive exactly, score every gap and control, and interp beats zerovel on each gap."""
    for name in ("interp", "zerovel"):
        rows = report["methods"][name]["variants"]
        for v in GAPS + CONTROLS:
            assert rows[v]["last_frame_cm"] < 1e-3, (name, v)
            assert rows[v]["last_frame_l2p"] < 1e-3
            assert rows[v]["foot_skate"] >= 0
        for v in GAPS:
            assert {"l2p", "l2q", "npss", "npss_x100", "mpjpe_cm", "foot_skate_gt"} <= set(rows[v])
        for v in CONTROLS:
            assert "l2p" not in rows[v]
    for v in GAPS:
        interp, zerovel = (report["methods"][m]["variants"][v] for m in ("interp", "zerovel"))
        assert interp["l2p"] < zerovel["l2p"] and interp["mpjpe_cm"] < zerovel["mpjpe_cm"]


def _check_ground_truth_rows(report: dict) -> None:
    """gt scores zero on every gap, matches the ground truth's foot skate, and is unavailable for the controls."""
    for v in GAPS:
        gt = report["methods"]["gt"]["variants"][v]
        for key in ("l2p", "l2q", "npss", "mpjpe_cm", "last_frame_cm"):
            assert gt[key] < 1e-4, (v, key)
        assert gt["foot_skate"] == pytest.approx(gt["foot_skate_gt"]) == pytest.approx(report["ground_truth"][v]["foot_skate"])
    for v in CONTROLS:
        assert "no ground truth" in report["methods"]["gt"]["variants"][v]["unavailable"]
    for v in LOCOMOTION_CONTROLS:  # the synthetic contents are all locomotion
        assert "no ground truth" in report["methods"]["gt"]["locomotion"][v]["unavailable"]
        assert report["methods"]["interp"]["locomotion"][v]["last_frame_cm"] < 1e-3


def test_baselines_and_ground_truth(cache: MotionCache, stats) -> None:
    methods = [resolve_method(m) for m in ("interp", "zerovel", "gt")]
    run = evaluate(cache, methods, EvalSettings(limit=9, render_cases=2), progress=False, stats=stats)
    report = run.report
    assert report["format"] == "rsmt-eval/2" and report["cases"] == 9 and report["classifier"] is None
    assert [v["name"] for v in report["variants"]] == list(GAPS + CONTROLS + LOCOMOTION_CONTROLS)
    assert set(report["methods"]) == {"interp", "zerovel", "gt"}
    json.dumps(report)  # JSON-ready
    _check_baseline_rows(report)
    _check_ground_truth_rows(report)
    assert len(run.render_index) == 2 and run.render["interp"]["gap40"].shape == (2, 41, 21, 3)
    text = markdown(report, "rsmt eval ...")
    assert "| 40 | interp |" in text and "gap 40, d=-1" in text and "n/a" in text


def _check_style_scores(model: dict, stdout: str) -> None:
    """The 40-frame gap's classifier and judge scores are shares, per style too, and the report prints them."""
    gap40 = model["variants"]["gap40"]
    for key in ("style_accuracy", "style_accuracy_cross", "style_cross_as_context"):
        assert 0.0 <= gap40[key] <= 1.0
    # The clip and the context are of different styles, so a transition is read as at most one of them.
    assert gap40["style_accuracy_cross"] + gap40["style_cross_as_context"] <= 1.0 + 1e-6
    assert "read as the context's style" in stdout
    for key, heading in (("style_accuracy_by_style", "Same-style accuracy per requested style"),
                         ("style_accuracy_cross_by_style", "Other-style accuracy per requested style"),
                         ("style_accuracy_cross_by_context", "Other-style accuracy per context style")):
        assert set(gap40[key]) <= {"bouncy", "brisk", "slow"} and all(0.0 <= a <= 1.0 for a in gap40[key].values()), key
        assert heading in stdout
    assert gap40["fmd"] >= 0 and gap40["fmd_cross"] >= 0
    for group in (model["variants"], model["locomotion"]):  # the judge, with the same-style and the other-style clip
        g40 = group["gap40"]
        assert 0.0 <= g40["judge_accuracy"] <= 1.0 and 0.0 <= g40["judge_accuracy_cross"] <= 1.0
        assert g40["judge_accuracy_cross"] + g40["judge_cross_as_context"] <= 1.0 + 1e-9
    assert "judge_accuracy" in model["locomotion"]["gap40-side1m"]


@pytest.mark.slow  # trains a classifier and runs rsmt eval
def test_eval_command_with_bundle_and_classifier(dataset: tuple[Path, Path], bundle_dir: Path, classifier_dir: Path,
                                                 judge_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    data, root = dataset
    monkeypatch.setenv("RSMT_CACHE", str(root))
    out = tmp_path / "out"
    code = main(["eval", "--model", str(bundle_dir), "--model", "interp", "--model", "zerovel", "--data", str(data),
                 "--classifier", str(classifier_dir), "--judge", str(judge_dir),
                 "--out", str(out), "--limit", "4", "--diversity-cases", "2",
                 "--diversity-samples", "2", "--render-cases", "2", "--quiet"])
    assert code == 0
    stdout = capsys.readouterr().out
    assert "### Unchanged controls" in stdout and "| 10 | random |" in stdout and "### Style on the 40-frame gap" in stdout
    for name in ("report.json", "report.md", "reference_stats.json", "metrics_over_gap.png", "controls.png",
                 "contact_sheet.png"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    assert (out / "metrics_over_gap.png").read_bytes()[:4] == b"\x89PNG"
    report = json.loads((out / "report.json").read_text())
    assert report["command"].startswith("rsmt eval --model") and "--limit 4" in report["command"]
    model = report["methods"]["random"]
    assert model["kind"] == "bundle" and model["max_transition"] == 120  # twice the training horizon
    rows = model["variants"]
    assert rows["gap40-dt2"]["frames"] == 80 and "unavailable" not in rows["gap40-dt2"]  # within 2 x 60
    for v in GAPS:
        assert rows[v]["diversity_cm"] > 0 and rows[v]["diversity_cases"] == 2
        assert rows[v]["l2p"] > 0 and rows[v]["last_frame_cm"] >= 0
    _check_style_scores(model, stdout)
    assert 0.0 <= report["ground_truth"]["gap40"]["style_accuracy"] <= 1.0
    interp = report["methods"]["interp"]["variants"]
    assert "diversity_cm" not in interp["gap40"] and interp["gap40"]["last_frame_cm"] < 1e-3
    assert report["classifier"]["styles"] == ["bouncy", "brisk", "slow"]


def test_contact_sheet_always_has_interpolation(cache: MotionCache, stats) -> None:
    run = evaluate(cache, [resolve_method("zerovel")], EvalSettings(limit=4, render_cases=2), progress=False, stats=stats)
    assert list(run.render) == ["ground truth", "zerovel", "interp"]
    assert "interp" not in run.report["methods"]
    assert run.render["interp"]["gap40"].shape == run.render["zerovel"]["gap40"].shape == (2, 41, 21, 3)


def test_bundle_is_deterministic_without_noise(cache: MotionCache, bundle_dir: Path) -> None:
    from model.evaluation.methods import Request

    method = BundleMethod(bundle_dir, batch=3)
    cs = CaseSet.load(cache, build_cases(cache, cache.split.test, limit=3))
    a = method.generate(cs, Request(variant("gap10")))
    b = method.generate(cs, Request(variant("gap10")))
    assert a[0].shape == (3, 10, 21, 4) and a[1].shape == (3, 10, 3)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    s1 = method.generate(cs, Request(variant("gap10"), seeds=[1, 2, 3]))
    s2 = method.generate(cs, Request(variant("gap10"), seeds=[4, 5, 6]))
    assert not torch.equal(s1[1], s2[1])


@pytest.mark.slow  # evaluates a bundle three times
def test_noise_samples_as_a_default_request_does_reproducibly(cache: MotionCache, bundle_dir: Path, stats) -> None:
    def gap40(settings: EvalSettings) -> tuple[float, str]:
        run = evaluate(cache, [BundleMethod(bundle_dir)], settings, progress=False, stats=stats)
        return run.report["methods"]["random"]["variants"]["gap40"]["l2p"], run.report["protocol"]["noise"]

    base = EvalSettings(limit=4, render_cases=0, diversity_cases=0)
    plain, plain_noise = gap40(base)
    sampled, sampled_noise = gap40(replace(base, noise=True))
    assert plain_noise.startswith("none") and sampled_noise.startswith("sampled")
    assert sampled != plain
    assert gap40(replace(base, noise=True))[0] == sampled  # a seed per case from settings.seed
    assert gap40(replace(base, noise=True, seed=1))[0] != sampled
    assert gap40(replace(base, seed=1))[0] == plain  # the seed draws noise only when asked to


def test_output_steps_can_be_chosen_for_an_evaluation(cache: MotionCache, bundle_dir: Path, dataset: tuple[Path, Path],
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    from model.evaluation.methods import Request

    cs = CaseSet.load(cache, build_cases(cache, cache.split.test, limit=2))
    raw = BundleMethod(bundle_dir, overrides=Overrides(smoothing=0.0, foot_lock=False))
    smooth = BundleMethod(bundle_dir, overrides=Overrides(smoothing=0.5, foot_lock=True))
    steering = {"window": 0, "momentum": 1.0, "max_step_cm": 10.0, "turn_window": 0, "max_turn_deg": 4.0,
                "height_window": 0, "max_rise_cm": 2.0, "retarget_turn_window": 0, "retarget_max_turn_deg": 4.0}
    assert smooth.describe()["output"] == {"smoothing": 0.5, "foot_lock": True, "root_smoothing": None,
                                           "steering": steering, "floor": False, "stride_warp": 0.0,
                                           "foot_plant": False}
    steered = BundleMethod(bundle_dir, overrides=Overrides(steering=12))
    assert steered.describe()["output"]["steering"] == {**steering, "window": 12}
    assert BundleMethod(bundle_dir, overrides=Overrides(floor=True)).describe()["output"]["floor"] is True
    assert BundleMethod(bundle_dir, overrides=Overrides(stride_warp=1.5)).describe()["output"]["stride_warp"] == 1.5
    a = raw.generate(cs, Request(variant("gap10")))
    b = smooth.generate(cs, Request(variant("gap10")))
    assert not torch.allclose(a[1][:, :5], b[1][:, :5], atol=1e-4)  # filtered along the way
    assert torch.allclose(a[1][:, -1], b[1][:, -1], atol=1e-5)  # the arrival frame is the network's own
    data, _ = dataset
    assert main(["eval", "--model", str(bundle_dir), "--data", str(data), "--smoothing", "1.5", "--quiet"]) == 2
    assert "--smoothing" in capsys.readouterr().err
    assert main(["eval", "--model", str(bundle_dir), "--data", str(data), "--steering", "-1", "--quiet"]) == 2
    assert "--steering" in capsys.readouterr().err
    assert main(["eval", "--model", str(bundle_dir), "--data", str(data), "--stride-warp", "5", "--quiet"]) == 2
    assert "--stride-warp" in capsys.readouterr().err


def test_unknown_model_is_an_error(dataset: tuple[Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    data, _ = dataset
    assert main(["eval", "--model", "no-such-bundle", "--data", str(data), "--quiet"]) == 2
    assert "neither" in capsys.readouterr().err


def test_styles_filter(dataset: tuple[Path, Path], cache: MotionCache, capsys: pytest.CaptureFixture[str]) -> None:
    data, _ = dataset
    one = cache.styles[1]
    assert main(["eval", "--model", "interp", "--data", str(data), "--styles", one, "--json", "--quiet",
                 "--diversity-cases", "0"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["cases"] > 0 and set(report["styles"]) == {one}
    assert "--styles " + one in report["command"]
    assert main(["eval", "--model", "interp", "--data", str(data), "--styles", "no-such-style", "--quiet"]) == 2
    assert "unknown style" in capsys.readouterr().err


def test_accuracy_by_style_agrees_with_the_overall_accuracy() -> None:
    from model.evaluation.style_scores import StyleScorer

    scorer = StyleScorer.__new__(StyleScorer)  # only the style index is needed here
    scorer.index = {"a": 0, "b": 1, "c": 2}
    labels = torch.tensor([0, 0, 0, 1, 1, 2, -1])
    logits = torch.nn.functional.one_hot(torch.tensor([0, 0, 1, 1, 0, 2, 0]), 3).float()
    per = scorer.accuracy_by_style(logits, labels)
    assert per == pytest.approx({"a": 2 / 3, "b": 1 / 2, "c": 1.0})
    counts = {"a": 3, "b": 2, "c": 1}
    assert sum(per[s] * n for s, n in counts.items()) / 6 == pytest.approx(StyleScorer.accuracy(logits, labels))


def test_accuracy_by_style_groups_cases_by_another_label() -> None:
    from types import SimpleNamespace
    from typing import cast

    from model.evaluation.style_scores import StyleScorer

    # A stand-in with only the index the method reads (no classifier to build): cast, as it is no StyleScorer.
    scorer = cast(StyleScorer, SimpleNamespace(index={"a": 0, "b": 1, "c": 2}))
    logits = torch.eye(3)[[0, 1, 1, 2, 0]]  # predictions a, b, b, c, a
    labels = torch.tensor([0, 1, 2, 2, -1])  # requested styles; the last is unknown to the classifier
    by_label = StyleScorer.accuracy_by_style(scorer, logits, labels)
    assert by_label == {"a": 1.0, "b": 1.0, "c": 0.5}
    # The same hits grouped by context style: context a holds cases 0 and 2 (one hit), b holds case 1.
    context = torch.tensor([0, 1, 0, 2, 1])
    by_context = StyleScorer.accuracy_by_style(scorer, logits, labels, groups=context)
    assert by_context == {"a": 0.5, "b": 1.0, "c": 1.0}  # case 4's unknown label is left out of group b


def test_a_style_with_an_adapter_is_scored_on_its_weights_the_others_on_the_bundles(
        cache: MotionCache, bundle_dir: Path, tmp_path: Path) -> None:
    import copy
    import shutil

    from model.evaluation.methods import Request
    from model.inference.bundle_adapters import adapter_from
    from model.inference.bundle_styles import StyleClip
    from model.inference.style_packing import write_adapter

    bundle = Bundle.load(bundle_dir)
    tuned = copy.deepcopy(bundle.sampler)
    with torch.no_grad():
        for name, p in tuned.named_parameters():
            if name.startswith(("film1.", "lstm.")):
                p.add_(0.2 * torch.randn(p.shape, generator=torch.Generator().manual_seed(4)))
    shutil.copytree(bundle_dir, tmp_path / "adapted")
    write_adapter(tmp_path / "adapted", adapter_from(bundle.sampler, tuned, "bouncy", bundle.version),
                  StyleClip("bouncy", cache.clip(cache.split.train[0]).window(0, 60).to(torch.float32), "x"))
    bundle.sampler = tuned
    bundle.save(tmp_path / "own")
    cs = CaseSet.load(cache, build_cases(cache, cache.split.test, limit=9))
    mine = [i for i, c in enumerate(cs.cases) if c.style == "bouncy"]
    assert mine and len(mine) < len(cs)
    adapted = BundleMethod(tmp_path / "adapted", batch=4)
    assert adapted.describe()["adapters"] == ["bouncy"]
    got = adapted.generate(cs, Request(variant("gap10")))
    base = BundleMethod(bundle_dir, batch=4).generate(cs, Request(variant("gap10")))
    own = BundleMethod(tmp_path / "own", batch=4).generate(cs, Request(variant("gap10")))
    for i in range(len(cs)):
        want = own if i in mine else base
        assert torch.allclose(got[0][i], want[0][i], atol=1e-4) and torch.allclose(got[1][i], want[1][i], atol=1e-3)
    assert not torch.allclose(got[1][mine[0]], base[1][mine[0]], atol=1e-3)


def test_eval_runs_motion_matching_and_the_second_judge_with_the_gait_figures(
        dataset: tuple[Path, Path], cache: MotionCache, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    from model.evaluation.judge_windows import real_windows
    from model.evaluation.sequence_judge import JudgeTraining, train_sequence_judge

    windows, styles, _ = real_windows(cache, cache.split.train)
    index = {s: k for k, s in enumerate(cache.styles)}
    judge2 = train_sequence_judge(windows, torch.tensor([index[s] for s in styles]), cache.styles, cache.skeleton(0),
                                  cache.fps, JudgeTraining(steps=20, batch=16, width=8)).save(tmp_path / "judge2")
    data, root = dataset
    monkeypatch.setenv("RSMT_CACHE", str(root))
    assert main(["eval", "--model", "interp", "--data", str(data), "--judge2", str(judge2), "--limit", "4",
                 "--render-cases", "0", "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert list(report["methods"]) == ["interp", "motion matching"] and report["judge2"]["path"] == str(judge2)
    mm = report["methods"]["motion matching"]
    assert mm["database_takes"] == len(cache.split.train)
    for name, m in report["methods"].items():
        for v, r in m["variants"].items():
            assert r["last_frame_cm"] < 1e-3, (name, v)  # both land on the target
            assert r["toe_skate"] >= 0 and r["longest_airborne_frames"] >= 0 and r["max_root_speed_cm_s"] > 0
            if r.get("backward_share_cases"):
                assert 0.0 <= r["backward_share"] <= 1.0
        g40 = m["variants"]["gap40"]
        assert "toe_skate_gt" in g40 and 0.0 <= g40["judge2_accuracy"] <= 1.0
    assert report["ground_truth"]["gap40"]["toe_skate"] == report["methods"]["interp"]["variants"]["gap40"]["toe_skate_gt"]
    # The backward share reads d = -1 as moving against the facing for interpolation (it slides back).
    assert report["methods"]["interp"]["variants"]["gap40-d-1"]["backward_share"] > 0.5
    assert main(["eval", "--model", "interp", "--data", str(data), "--limit", "2", "--render-cases", "0",
                 "--no-motion-matching", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "### Feet, direction and speed, all contents" in text and "| motion matching |" not in text


def test_eval_command_on_held_out_styles(dataset: tuple[Path, Path], cache: MotionCache, monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """``--split holdout --holdout-style S``: cases of S's takes only, motion matching from the split without S, and
    ``--clips-only`` takes giving no case."""
    data, root = dataset
    monkeypatch.setenv("RSMT_CACHE", str(root))
    one = cache.styles[0]
    split = cache.make_split(holdout_styles=[one])
    skipped = cache.takes[split.holdout[0]].take_id
    assert main(["eval", "--model", "interp", "--data", str(data), "--split", "holdout", "--holdout-style", one,
                 "--clips-only", skipped, "--render-cases", "0", "--diversity-cases", "0", "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["styles"] == [one] and report["split"] == "holdout"
    assert report["settings"]["holdout_styles"] == [one] and report["settings"]["clips_only"] == [skipped]
    assert report["takes"] == len(split.holdout) - 1
    assert report["methods"]["motion matching"]["database_takes"] == len(split.train) < len(cache.split.train)
    assert f"--holdout-style {one} --clips-only {skipped}" in report["command"]
    assert main(["eval", "--model", "interp", "--data", str(data), "--split", "holdout", "--quiet"]) != 0
    assert "needs the held-out styles" in capsys.readouterr().err


def test_a_style_set_changes_its_styles_cases_only(cache: MotionCache, bundle_dir: Path) -> None:
    """Cases of a style given a set run on the set's clips encoded together; every other case as before."""
    from model.evaluation.runner import style_set_takes

    one = cache.styles[0]
    train = [cache.takes[i].take_id for i in cache.split.train if cache.takes[i].style == one][:2]
    sets = style_set_takes(cache, [train])
    assert list(sets) == [one] and len(sets[one]) == 2
    case_list = build_cases(cache, cache.split.test, limit=6)
    plain, with_set = CaseSet.load(cache, case_list), CaseSet.load(cache, case_list, sets)
    assert plain.style_sets == [] and [len(s) for s in with_set.style_sets] == [2 if c.style == one else 0
                                                                               for c in case_list]
    method = resolve_method(str(bundle_dir))
    request = Request(variant("gap10"))
    a, b = method.generate(plain, request)[0], method.generate(with_set, request)[0]
    mine = torch.tensor([c.style == one for c in case_list])
    assert mine.any() and (~mine).any()
    # Other cases move by float rounding only (their codes are padded to the set's longer code in the batch).
    assert (a[~mine] - b[~mine]).abs().max() < 1e-5 < 1e-3 < (a[mine] - b[mine]).abs().max()
    sub = with_set.subset([int(i) for i in torch.nonzero(mine)[:1, 0]])
    assert len(sub.style_sets) == 1 and len(sub.style_sets[0]) == 2
    other = next(s for s in cache.styles if s != one)
    mixed = [train[0], next(t.take_id for t in cache.takes if t.style == other)]
    for bad, message in (([mixed], "clips of one style"), ([train[:1], train[1:]], "two style sets"),
                         ([["nosuch"]], "no take nosuch"), ([train * 3], "1 to 5 clips")):
        with pytest.raises(ValueError, match=message):
            style_set_takes(cache, bad)


def test_eval_runs_every_source_of_a_database_bundle_side_by_side(dataset: tuple[Path, Path], cache: MotionCache,
                                                                  tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    from model.data.database_build import build_database

    data, root = dataset
    monkeypatch.setenv("RSMT_CACHE", str(root))
    bundle = Bundle.create(synthetic_skeleton())
    bundle.database = build_database(cache)
    folder = bundle.save(tmp_path / "db")
    assert main(["eval", "--model", str(folder), "--data", str(data), "--source", "network,matching,hybrid",
                 "--limit", "3", "--diversity-cases", "0", "--render-cases", "0", "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert {"db", "db (matching)", "db (hybrid)", "motion matching"} <= set(report["methods"])
    assert report["methods"]["db (matching)"]["source"] == "matching"
    matching = report["methods"]["db (matching)"]["variants"]["gap40"]
    assert matching["last_frame_cm"] < 1.0  # a played window is blended onto the target
    assert main(["eval", "--model", str(folder), "--data", str(data), "--source", "capture", "--quiet"]) == 2
    assert "--source" in capsys.readouterr().err
