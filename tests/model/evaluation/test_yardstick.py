"""The yardstick of issue 23: one target frame by default, locomotion first, turned and moved targets,
the largest root speed, and the style judge (model/evaluation/style_judge.py), on synthetic data."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import pytest
import torch

from model.data.preprocessed import MotionCache, load_motion_cache
from model.data.synthetic import synthetic_skeleton, write_synthetic_dataset
from model.evaluation import CaseSet, EvalSettings, build_cases, evaluate, resolve_method
from model.evaluation.cases import LAST_CONTEXT, LOCOMOTION, variant
from model.evaluation.methods import BundleMethod, Request
from model.evaluation.metrics import max_root_speed
from model.evaluation.style_judge import StyleJudge, accuracy_report, fit_judge, take_windows, window_features
from model.evaluation.style_scores import judge_fmd_floor, judge_fmd_rows, judge_rows
from model.inference.bundle import Bundle
from model.motion.clip import Clip
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_rotate, yaw_quat
from rsmt_cli.main import main

pytestmark = pytest.mark.usefixtures("one_thread")

STANDING = "wave-both-hands"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Synthetic walks, plus copies of the straight walks under a standing content's name (not locomotion)."""
    root = tmp_path_factory.mktemp("yardstick")
    data = root / "data"
    for path in write_synthetic_dataset(data, takes_per_pair=3, frames=150):
        if "_walk_" in path.name:
            shutil.copy(path, path.with_name(path.name.replace("_walk_", f"_{STANDING}_")))
    return data, root / "cache"


@pytest.fixture(scope="module")
def cache(dataset: tuple[Path, Path]) -> MotionCache:
    data, root = dataset
    return load_motion_cache(data, root=root, workers=1, progress=False)


@pytest.fixture(scope="module")
def cases(cache: MotionCache) -> CaseSet:
    return CaseSet.load(cache, build_cases(cache, cache.split.train, limit=12))


@pytest.fixture(scope="module")
def bundle_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return Bundle.create(synthetic_skeleton()).save(tmp_path_factory.mktemp("bundle") / "random")


# ------------------------------------------------------------------ target frames
def test_the_default_target_is_one_frame_and_two_is_the_variant_with_velocity(cases: CaseSet, bundle_dir: Path) -> None:
    v = variant("gap20")
    assert Request(v).target_frames == 1
    one, two = cases.targets(v), cases.targets(v, 2)
    assert one[0].shape[1] == 1 and two[0].shape[1] == 2 and torch.equal(one[0][:, 0], two[0][:, 1])
    with pytest.raises(ValueError):
        cases.targets(v, 3)
    method = BundleMethod(bundle_dir)
    sub = cases.subset([0, 1])
    default = method.generate(sub, Request(v))
    velocity = method.generate(sub, Request(v, target_frames=2))
    assert not torch.allclose(default[1], velocity[1])  # the second frame reaches the model
    engine = method.engine
    for frames, (rot, root) in ((1, default), (2, velocity)):
        target_rot, target_root = sub.targets(v, frames)
        for b in range(2):
            style, _ = engine.encode_style(sub.style_clips[b])
            target = Clip(sub.skeletons[b], target_rot[b], target_root[b], sub.fps)
            ch = engine.prepare(sub.context_clip(b), target, v.frames, style, deterministic=True)
            direct = engine.generate([ch])[0]
            torch.testing.assert_close(direct[0].float(), rot[b])
            torch.testing.assert_close(direct[1].float(), root[b])
    # Baselines read the target frame only: the same either way.
    interp = resolve_method("interp")
    assert torch.equal(interp.generate(sub, Request(v))[1], interp.generate(sub, Request(v, target_frames=2))[1])


def test_eval_command_sends_one_target_frame_unless_asked(dataset: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    data, root = dataset
    monkeypatch.setenv("RSMT_CACHE", str(root))
    base = ["eval", "--model", "interp", "--data", str(data), "--limit", "4", "--json", "--quiet",
            "--diversity-cases", "0", "--render-cases", "0"]
    assert main(base) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["target_frames"] == 1 and report["settings"]["target_frames"] == 1
    assert report["protocol"]["target"] == "the target frame alone" and "--target-frames 1" in report["command"]
    assert main([*base, "--target-frames", "2"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["target_frames"] == 2 and "velocity" in report["protocol"]["target"]


# ------------------------------------------------------------------ turned and moved targets
def _about(pivot: torch.Tensor, degrees: float, pos: torch.Tensor) -> torch.Tensor:
    q = yaw_quat(torch.full(pos.shape[:-1], math.radians(degrees)))
    return pivot + quat_rotate(q, pos - pivot)


def test_turning_the_target_turns_it_about_its_own_vertical(cases: CaseSet) -> None:
    base, plus, minus = (cases.target_positions(variant(n)) for n in ("gap40", "gap40-turn+90", "gap40-turn-90"))
    pivot = cases.roots[:, variant("gap40").target_frame].unsqueeze(1)
    torch.testing.assert_close(plus[:, 0], base[:, 0])  # the root stays
    torch.testing.assert_close(_about(pivot, -90.0, plus), base, atol=1e-3, rtol=0)  # +90 then -90: the original
    torch.testing.assert_close(_about(pivot, 180.0, minus), plus, atol=1e-3, rtol=0)
    assert (plus - base).norm(dim=-1).amax() > 10.0  # it did turn
    torch.testing.assert_close(plus[..., 1], base[..., 1])  # about the vertical: heights unchanged
    for name in ("gap40-turn+90", "gap40-side1m"):
        v = variant(name)
        rot, root = cases.targets(v, 2)
        pos, _ = forward_kinematics(rot, root, cases.offsets.unsqueeze(1), cases.skeleton.parents)
        torch.testing.assert_close(pos[:, -1], cases.target_positions(v), atol=1e-3, rtol=0)  # what a method is sent
    # The target's velocity turns with it.
    rot, root = cases.targets(variant("gap40-turn+90"), 2)
    orig = cases.roots[:, -1] - cases.roots[:, -2]
    torch.testing.assert_close(root[:, 1] - root[:, 0], _about(torch.zeros(3), 90.0, orig), atol=1e-3, rtol=0)


def test_moving_the_target_moves_it_one_metre_to_the_side(cases: CaseSet) -> None:
    base, side = cases.target_positions(variant("gap40")), cases.target_positions(variant("gap40-side1m"))
    shift = side - base
    torch.testing.assert_close(shift.norm(dim=-1), torch.full(shift.shape[:-1], 100.0), atol=1e-3, rtol=0)
    assert bool((shift[..., 1].abs() < 1e-4).all())
    travel = (cases.roots[:, -1] - cases.roots[:, LAST_CONTEXT]) * torch.tensor([1.0, 0.0, 1.0])
    s = shift[:, 0]
    torch.testing.assert_close((s * travel).sum(-1), torch.zeros(len(cases)), atol=1e-2, rtol=0)  # perpendicular
    assert bool((travel[:, 2] * s[:, 0] - travel[:, 0] * s[:, 2] > 0).all())  # to the left (facing +Z, left is +X)


# ------------------------------------------------------------------ root speed
def test_largest_root_speed_of_a_constant_velocity_clip_is_its_speed() -> None:
    fps, velocity = 30.0, torch.tensor([120.0, 0.0, 160.0])  # 200 cm/s
    t = torch.arange(20, dtype=torch.float32).view(1, 20, 1, 1) / fps
    pos = t * velocity + torch.randn(1, 1, 3, 3)  # three joints moving together
    torch.testing.assert_close(max_root_speed(pos, fps), torch.tensor([200.0]))
    pos[0, 7, 0] += torch.tensor([10.0, 0.0, 0.0])  # a 10 cm jump at one frame shows
    assert float(max_root_speed(pos, fps)[0]) > 400.0


# ------------------------------------------------------------------ locomotion first
def test_locomotion_cases_are_scored_apart_and_first(cache: MotionCache, capsys: pytest.CaptureFixture[str]) -> None:
    all_cases = build_cases(cache, cache.split.test)
    assert {c.content for c in all_cases} == {*LOCOMOTION[:3], STANDING}
    cs = CaseSet.load(cache, all_cases)
    assert cs.locomotion_index == [i for i, c in enumerate(all_cases) if c.content != STANDING]
    run = evaluate(cache, [resolve_method("interp")], EvalSettings(split="test", render_cases=0), progress=False)
    report = run.report
    loco_n = len(cs.locomotion_index)
    assert report["locomotion_cases"] == loco_n < report["cases"] == len(all_cases)
    m = report["methods"]["interp"]
    for name in ("gap40-turn+90", "gap40-turn-90", "gap40-side1m"):
        assert name not in m["variants"]
        row = m["locomotion"][name]
        assert row["cases"] == loco_n and row["last_frame_cm"] < 1e-3
    assert m["locomotion"]["gap40"]["cases"] == loco_n and m["variants"]["gap40"]["cases"] == len(all_cases)
    assert m["locomotion"]["gap40"]["l2p"] != m["variants"]["gap40"]["l2p"]
    gt = report["ground_truth_locomotion"]["gap40"]
    assert gt["max_root_speed_cm_s"] > 0 and gt["context_max_root_speed_cm_s"] > 0
    from model.evaluation.report import markdown

    text = markdown(report)
    assert text.index("# Locomotion cases") < text.index("# All contents")
    assert "turned +90°" in text and "1 m sideways" in text


# ------------------------------------------------------------------ the style judge
def test_judge_learns_separable_synthetic_styles_and_round_trips(cache: MotionCache, tmp_path: Path) -> None:
    feats, styles, contents = take_windows(cache, cache.split.train, step=10)
    index = {s: k for k, s in enumerate(cache.styles)}
    sk = cache.skeleton(cache.split.train[0])
    judge = fit_judge(feats, torch.tensor([index[s] for s in styles]), cache.styles, list(sk.names), cache.fps)
    vf, vs, vc = take_windows(cache, cache.split.test, step=10)
    report = accuracy_report(judge, vf, vs, vc, LOCOMOTION)
    assert report["accuracy"] > 0.9 > 1.0 / len(cache.styles), report
    loaded = StyleJudge.load(judge.save(tmp_path / "judge"))
    assert loaded.styles == judge.styles and loaded.joints == judge.joints
    torch.testing.assert_close(loaded.logits_of_features(vf), judge.logits_of_features(vf))
    assert not list((tmp_path / "judge").glob("*.pkl")) and (tmp_path / "judge" / "judge.json").is_file()
    # A sequence longer than a window is scored on its windows; a turn and a move do not change a thing.
    pos = cache_positions(cache, cache.split.test[0])[None, :90].double()
    turn = yaw_quat(torch.tensor(1.0, dtype=torch.float64)).expand(*pos.shape[:-1], 4)
    moved = quat_rotate(turn, pos) + torch.tensor([300.0, 0.0, -50.0], dtype=torch.float64)
    torch.testing.assert_close(judge.log_probs(moved), judge.log_probs(pos), atol=1e-4, rtol=1e-4)
    assert judge.log_probs(pos).shape == (1, len(cache.styles))
    torch.testing.assert_close(window_features(moved, cache.fps), window_features(pos, cache.fps), atol=1e-3, rtol=1e-4)


def cache_positions(cache: MotionCache, take: int) -> torch.Tensor:
    sk = cache.skeleton(take)
    pos, _ = forward_kinematics(cache.rotations(take).float(), cache.root_positions(take).float(), sk.offsets_tensor(),
                                sk.parents)
    return pos


def test_judge_on_separable_features_alone() -> None:
    gen = torch.Generator().manual_seed(0)
    centres = torch.randn(3, 5, generator=gen) * 3
    labels = torch.arange(3).repeat_interleave(40)
    feats = centres[labels] + torch.randn(120, 5, generator=gen)
    judge = fit_judge(feats, labels, ["a", "b", "c"], [f"j{i}" for i in range(5)], 30.0)
    assert float((judge.logits_of_features(feats).argmax(-1) == labels).double().mean()) > 0.9
    with pytest.raises(FileNotFoundError):
        StyleJudge.load(Path("/nonexistent-judge"))


def test_eval_with_judge_reports_which_classifier_and_per_style_rows(dataset: tuple[Path, Path], tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    data, root = dataset
    monkeypatch.setenv("RSMT_CACHE", str(root))
    out = tmp_path / "judge"
    assert main(["train", "judge", "--data", str(data), "--out", str(out), "--quiet"]) == 0
    assert "val windows" in capsys.readouterr().out
    assert main(["eval", "--model", "interp", "--data", str(data), "--judge", str(out), "--limit", "6", "--quiet",
                 "--diversity-cases", "0", "--render-cases", "0", "--out", str(tmp_path / "eval")]) == 0
    text = capsys.readouterr().out
    report = json.loads((tmp_path / "eval" / "report.json").read_text())
    assert report["judge"]["path"] == str(out) and "logistic regression" in report["judge"]["kind"]
    assert "Style scored by the judge" in text and "Style (judge) per requested style" in text
    gt = report["ground_truth_locomotion"]["gap40"]
    assert 0.0 <= gt["judge_accuracy"] <= 1.0 and set(gt["judge_accuracy_by_style"]) <= set(report["styles"])
    loco = report["methods"]["interp"]["locomotion"]
    assert "judge_accuracy" in loco["gap40-turn+90"] and "judge_accuracy" not in loco["gap40-dt0.5"]  # 20 frames
    # With another style's clip: scored on the clip's style; a transition is read as at most one of the two styles.
    cross = loco["gap40"]
    assert cross["judge_accuracy_cross"] + cross["judge_cross_as_context"] <= 1.0 + 1e-9
    assert "other-style clip" in text and "with another style's clip" in text
    # FMD in the judge's space: interpolation is farther from the real transitions than two halves of them.
    assert cross["judge_fmd"] > 0.0 and set(cross["judge_fmd_by_style"]) <= set(report["styles"])
    assert gt["judge_fmd_split_half"] >= 0.0 and 0.0 <= cross["judge_accuracy_prob"] <= 1.0
    assert "FMD in the judge's feature space" in text and "Mean probability the judge gives" in text
    assert "judge_fmd" not in loco["gap40-turn+90"]  # no ground truth there
    assert "What the judge reads interp's transitions as" in text
    assert cross["floor_depth_cm"] >= 0.0 and gt["floor_depth_cm"] >= 0.0 and "below floor cm" in text
    assert set(cross["judge_accuracy_read_as_by_style"]) == set(cross["judge_accuracy_by_style"])


def test_judge_fmd_is_zero_on_the_real_motion_and_grows_as_the_motion_departs(cache: MotionCache) -> None:
    feats, styles, _ = take_windows(cache, cache.split.train, step=10)
    index = {s: k for k, s in enumerate(cache.styles)}
    sk = cache.skeleton(cache.split.train[0])
    judge = fit_judge(feats, torch.tensor([index[s] for s in styles]), cache.styles, list(sk.names), cache.fps)
    takes = list(cache.split.train)[:6]
    real = torch.stack([cache_positions(cache, t)[:41] for t in takes]).double()
    names = [cache.styles[i % 2] for i in range(len(takes))]
    same = judge_fmd_rows(judge, real, real, names)
    assert same["judge_fmd"] == pytest.approx(0.0, abs=1e-4)
    assert all(x == pytest.approx(0.0, abs=1e-4) for x in same["judge_fmd_by_style"].values())
    def damped(a: float) -> torch.Tensor:  # each joint moves ``a`` times as far from where it starts
        return real[:, :1] + a * (real - real[:, :1])

    near, far = judge_fmd_rows(judge, damped(0.9), real, names), judge_fmd_rows(judge, damped(0.5), real, names)
    assert far["judge_fmd"] > near["judge_fmd"] > 1e-3
    with pytest.raises(ValueError):
        judge_fmd_rows(judge, real[:3], real, names)
    floor = judge_fmd_floor(judge, real, names)
    assert floor["judge_fmd_split_half"] >= 0.0 and floor["judge_fmd_split_half_by_style"] == {}  # 3 a style: too few
    rows = judge_rows(judge, real, names)
    probs = judge.log_probs(real).exp()
    want = probs[torch.arange(len(takes)), torch.tensor([judge.styles.index(n) for n in names])].mean()
    assert rows["judge_accuracy_prob"] == pytest.approx(float(want))
    assert set(rows["judge_accuracy_prob_by_style"]) == set(names)
    votes = probs.argmax(dim=-1)
    for style, shares in rows["judge_accuracy_read_as_by_style"].items():  # a confusion row per requested style
        assert sum(shares.values()) == pytest.approx(1.0)
        assert shares[style] == pytest.approx(rows["judge_accuracy_by_style"][style])
        mine = votes[[i for i, n in enumerate(names) if n == style]]
        assert all(shares[t] == pytest.approx(float((mine == judge.styles.index(t)).float().mean())) for t in shares)


def test_network_alone_adds_each_bundle_with_steering_off_beside_its_own(dataset: tuple[Path, Path], bundle_dir: Path,
                                                                          monkeypatch: pytest.MonkeyPatch,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    data, root = dataset
    monkeypatch.setenv("RSMT_CACHE", str(root))
    assert main(["eval", "--model", str(bundle_dir), "--model", "interp", "--data", str(data), "--limit", "3",
                 "--json", "--quiet", "--diversity-cases", "0", "--render-cases", "0", "--no-motion-matching",
                 "--steering", "30", "--network-alone"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert list(report["methods"]) == ["random", "random (steering 0)", "interp"]
    own, alone = (report["methods"][n]["output"] for n in ("random", "random (steering 0)"))
    assert own["steering"]["window"] == 30 and alone["steering"]["window"] == 0
