"""Hand-computed cases for the evaluation metrics (model/evaluation/metrics.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.evaluation.metrics import (
    PositionStats,
    align_quat_signs,
    diversity,
    foot_skate,
    foot_skate_terms,
    frechet_distance,
    ground_levels,
    l2p,
    l2q,
    last_frame_error_cm,
    mean_joint_error_cm,
    npss,
    npss_terms,
)
from model.motion.rotations import quat_normalize, quat_slerp, yaw_quat

FEET = [1, 2]


def random_quats(shape: tuple[int, ...], seed: int, dtype=torch.float64) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return quat_normalize(torch.randn(*shape, 4, generator=g, dtype=dtype))


def smooth_quat_tracks(b: int, t: int, j: int, seed: int) -> torch.Tensor:
    """[B, T, J, 4] quaternions moving smoothly from one random rotation to another."""
    a = random_quats((b, 1, j), seed)
    c = random_quats((b, 1, j), seed + 1)
    w = torch.linspace(0, 1, t, dtype=torch.float64)[None, :, None]
    return quat_slerp(a, c, w)


def lafan1_fast_npss(gt_seq: np.ndarray, pred_seq: np.ndarray) -> float:
    """LaFAN1's benchmarks.fast_npss, verbatim in substance, as the reference."""
    gt_power = np.square(np.real(np.fft.fft(gt_seq, axis=1)))
    pred_power = np.square(np.real(np.fft.fft(pred_seq, axis=1)))
    gt_total = np.sum(gt_power, axis=1)
    pred_total = np.sum(pred_power, axis=1)
    cdf_gt = np.cumsum(gt_power / gt_total[:, None, :], axis=1)
    cdf_pred = np.cumsum(pred_power / pred_total[:, None, :], axis=1)
    emd = np.linalg.norm(cdf_pred - cdf_gt, ord=1, axis=1)
    return float(np.average(emd, weights=gt_total))


# --------------------------------------------------------------------------- PositionStats / L2P
def test_position_stats_known_values_and_json_round_trip():
    # Two frames per joint: x in {0, 2} -> mean 1, population std 1.
    pos = torch.zeros(1, 2, 3, 3)
    pos[0, 1, :, 0] = 2.0
    pos[..., 1] = 5.0
    stats = PositionStats.from_positions(pos)
    assert stats.count == 2
    torch.testing.assert_close(stats.mean[:, 0], torch.ones(3))
    torch.testing.assert_close(stats.std[:, 0], torch.ones(3))
    torch.testing.assert_close(stats.mean[:, 1], torch.full((3,), 5.0))
    assert torch.all(stats.std[:, 1] == 0)
    back = PositionStats.from_dict(json.loads(json.dumps(stats.to_dict())))
    torch.testing.assert_close(back.mean, stats.mean)
    torch.testing.assert_close(back.std, stats.std)
    assert back.count == 2
    # A list of clips of different lengths gives the same as their concatenation.
    clips = [torch.randn(4, 3, 3), torch.randn(7, 3, 3)]
    a = PositionStats.from_positions(clips)
    b = PositionStats.from_positions(torch.cat(clips)[None])
    torch.testing.assert_close(a.mean, b.mean)
    torch.testing.assert_close(a.std, b.std)


def test_position_stats_rejects_bad_shapes():
    with pytest.raises(ValueError):
        PositionStats(mean=torch.zeros(3, 3), std=torch.zeros(4, 3))
    with pytest.raises(ValueError):
        PositionStats.from_dict({"mean": [[0, 0, 0]]})


def _stats(j: int, std: float) -> PositionStats:
    return PositionStats(mean=torch.randn(j, 3), std=torch.full((j, 3), std))


def test_l2p_identical_is_zero():
    pos = torch.randn(3, 5, 4, 3) * 30
    assert l2p(pos, pos.clone(), _stats(4, 7.0)).item() == 0.0
    assert l2p(pos, pos.clone(), _stats(4, 7.0), last_frame=True).item() == 0.0


def test_l2p_known_offset():
    # std 2 cm everywhere, every joint 2 cm off in x -> 1 per joint -> sqrt(J) per frame.
    j = 4
    gt = torch.randn(2, 6, j, 3) * 20
    pred = gt.clone()
    pred[..., 0] += 2.0
    assert l2p(pred, gt, _stats(j, 2.0)).item() == pytest.approx(math.sqrt(j), rel=1e-5)
    # Per-coordinate std: an error of 3 cm in y with std 3 counts as 1, the same 3 cm in x with std 30 as 0.1.
    stats = PositionStats(mean=torch.zeros(1, 3), std=torch.tensor([[30.0, 3.0, 30.0]]))
    g = torch.zeros(1, 1, 1, 3)
    assert l2p(g + torch.tensor([0.0, 3.0, 0.0]), g, stats).item() == pytest.approx(1.0)
    assert l2p(g + torch.tensor([3.0, 0.0, 0.0]), g, stats).item() == pytest.approx(0.1)


def test_l2p_last_frame_variant():
    j, t = 3, 5
    gt = torch.randn(2, t, j, 3)
    pred = gt.clone()
    pred[:, -1, :, 2] += 1.0  # only the last frame is off, by one std in z on each joint
    stats = _stats(j, 1.0)
    assert l2p(pred, gt, stats, last_frame=True).item() == pytest.approx(math.sqrt(j), rel=1e-5)
    assert l2p(pred, gt, stats).item() == pytest.approx(math.sqrt(j) / t, rel=1e-5)


def test_l2p_zero_std_is_floored_not_nan():
    stats = PositionStats(mean=torch.zeros(1, 3), std=torch.zeros(1, 3))
    g = torch.zeros(1, 2, 1, 3)
    assert torch.isfinite(l2p(g + 1e-3, g, stats))


def test_l2p_rejects_mismatched_shapes():
    with pytest.raises(ValueError):
        l2p(torch.zeros(1, 2, 3, 3), torch.zeros(1, 3, 3, 3), _stats(3, 1.0))


# --------------------------------------------------------------------------- L2Q
def test_l2q_identical_and_sign_flipped_are_zero():
    q = random_quats((2, 5, 3), seed=0)
    assert l2q(q, q.clone()).item() == 0.0
    signs = torch.where(torch.rand(2, 5, 3, 1) < 0.5, -1.0, 1.0).double()
    assert l2q(q * signs, q).item() == pytest.approx(0.0, abs=1e-12)


def test_l2q_known_value():
    # 90 degrees about Y against identity: per joint ||q - id||^2 = 2 - 2 cos(45 deg) = 2 - sqrt(2).
    j = 5
    gt = yaw_quat(torch.full((2, 4, j), math.pi / 2, dtype=torch.float64))
    pred = torch.zeros_like(gt)
    pred[..., 3] = 1.0
    assert l2q(pred, gt).item() == pytest.approx(math.sqrt(j * (2 - math.sqrt(2))), rel=1e-12)
    # The same with the prediction's sign flipped: the nearer sign is used.
    assert l2q(-pred, gt).item() == pytest.approx(math.sqrt(j * (2 - math.sqrt(2))), rel=1e-12)


def test_align_quat_signs():
    ref = random_quats((10,), seed=3)
    assert torch.all((align_quat_signs(-ref, ref) * ref).sum(-1) > 0)


# --------------------------------------------------------------------------- NPSS
def test_npss_identical_is_zero():
    q = smooth_quat_tracks(3, 20, 4, seed=1)
    for spectrum in ("real", "power"):
        assert npss(q, q.clone(), spectrum=spectrum).item() == 0.0


def test_npss_matches_lafan1_reference():
    gt = smooth_quat_tracks(4, 30, 5, seed=2)
    noise = 0.05 * torch.randn(gt.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    pred = quat_normalize(gt + noise)
    ours = npss(pred, gt).item()
    ref = lafan1_fast_npss(gt.flatten(2).numpy(), pred.flatten(2).numpy())
    assert ours > 0
    assert ours == pytest.approx(ref, rel=1e-9)


def test_npss_power_spectrum_variant_matches_numpy_rfft():
    gt = smooth_quat_tracks(2, 25, 3, seed=4)
    pred = smooth_quat_tracks(2, 25, 3, seed=9)
    g, p = gt.flatten(2).numpy(), pred.flatten(2).numpy()
    gp, pp = np.abs(np.fft.rfft(g, axis=1)) ** 2, np.abs(np.fft.rfft(p, axis=1)) ** 2
    gt_tot, pt_tot = gp.sum(1), pp.sum(1)
    emd = np.abs(np.cumsum(pp / pt_tot[:, None], 1) - np.cumsum(gp / gt_tot[:, None], 1)).sum(1)
    ref = float(np.average(emd, weights=gt_tot))
    assert npss(pred, gt, spectrum="power").item() == pytest.approx(ref, rel=1e-9)
    assert npss(pred, gt, spectrum="real").item() != pytest.approx(ref, rel=1e-3)


def test_npss_zero_channel_is_ignored_not_nan():
    # Pure yaw: the x and z components are identically 0 in both sequences.
    angles = torch.linspace(0, 1.5, 20, dtype=torch.float64)[None, :, None].expand(2, 20, 3)
    gt = yaw_quat(angles)
    pred = yaw_quat(angles * 0.8)
    value = npss(pred, gt)
    assert torch.isfinite(value) and value.item() > 0
    emd, weight = npss_terms(pred, gt)
    assert emd.shape == weight.shape == (2, 12)
    assert torch.all(weight[:, 0::4] == 0) and torch.all(weight[:, 2::4] == 0)


def test_npss_terms_pool_to_npss():
    gt = smooth_quat_tracks(4, 16, 2, seed=5)
    pred = smooth_quat_tracks(4, 16, 2, seed=6)
    e1, w1 = npss_terms(pred[:2], gt[:2])
    e2, w2 = npss_terms(pred[2:], gt[2:])
    pooled = ((e1 * w1).sum() + (e2 * w2).sum()) / (w1.sum() + w2.sum())
    torch.testing.assert_close(pooled, npss(pred, gt))


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    flip_seed=st.integers(0, 2**31 - 1),
    spectrum=st.sampled_from(["real", "power"]),
)
def test_npss_invariant_to_quaternion_sign_flips(seed, flip_seed, spectrum):
    gt = smooth_quat_tracks(2, 12, 3, seed=seed)
    pred = smooth_quat_tracks(2, 12, 3, seed=seed + 7)
    g = torch.Generator().manual_seed(flip_seed)
    flip_p = torch.where(torch.rand(2, 12, 3, 1, generator=g) < 0.5, -1.0, 1.0).double()
    flip_g = torch.where(torch.rand(2, 12, 3, 1, generator=g) < 0.5, -1.0, 1.0).double()
    base = npss(pred, gt, spectrum=spectrum)
    torch.testing.assert_close(npss(pred * flip_p, gt * flip_g, spectrum=spectrum), base, rtol=1e-9, atol=1e-12)
    assert npss(gt * flip_g, gt, spectrum=spectrum).item() == pytest.approx(0.0, abs=1e-12)


# --------------------------------------------------------------------------- joint errors in cm
def test_mean_joint_error_cm():
    gt = torch.randn(2, 4, 3, 3)
    assert mean_joint_error_cm(gt, gt.clone()).item() == 0.0
    assert mean_joint_error_cm(gt + torch.tensor([3.0, 4.0, 0.0]), gt).item() == pytest.approx(5.0)


def test_last_frame_error_cm():
    pred = torch.randn(2, 5, 3, 3)
    target = pred[:, -1].clone()
    assert last_frame_error_cm(pred, target).item() == 0.0
    moved = pred.clone()
    moved[:, :-1] += 100.0  # earlier frames do not count
    moved[:, -1, :, 1] += 2.0
    assert last_frame_error_cm(moved, target).item() == pytest.approx(2.0)
    # A [B, T, J, 3] target is read from its last frame.
    assert last_frame_error_cm(moved, pred).item() == pytest.approx(2.0)


# --------------------------------------------------------------------------- ground level / foot skate
def test_ground_levels_percentile_per_joint():
    n = 100
    pos = torch.zeros(1, n, 3, 3)
    pos[0, :, 1, 1] = torch.arange(n, dtype=torch.float32)  # heights 0..99
    pos[0, :, 2, 1] = 4.25  # a toe resting at 4.25 cm
    pos[0, 7, 2, 1] = -30.0  # one glitch frame: a percentile ignores it, the minimum would not
    levels = ground_levels(pos, FEET)
    assert levels.shape == (2,)
    assert levels[0].item() == pytest.approx(4.95)  # 5% of the way through 100 sorted samples
    assert levels[1].item() == pytest.approx(4.25)
    assert ground_levels(pos, FEET, percentile=0.0)[1].item() == pytest.approx(-30.0)
    # A list of clips of different lengths.
    assert ground_levels([pos[0, :40], pos[0, 40:]], FEET)[0].item() == pytest.approx(4.95)


def _feet_track(xs, ys, j: int = 3) -> torch.Tensor:
    """[1, T, J, 3] with joint 1 at the given x and y per frame, joint 2 far above the ground."""
    t = len(xs)
    pos = torch.zeros(1, t, j, 3, dtype=torch.float64)
    pos[0, :, 1, 0] = torch.tensor(xs, dtype=torch.float64)
    pos[0, :, 1, 1] = torch.tensor(ys, dtype=torch.float64)
    pos[0, :, 2, 1] = 50.0
    return pos


def test_foot_skate_planted_foot_is_zero():
    pos = _feet_track([3.0] * 10, [4.25] * 10)
    assert foot_skate(pos, FEET, [4.25, 0.0]).item() == 0.0
    total, count = foot_skate_terms(pos, FEET, [4.25, 0.0])
    assert count.item() == 9  # nine frame pairs of the grounded joint count as contact samples


def test_foot_skate_sliding_at_ground_scores_its_speed():
    pos = _feet_track([float(i) for i in range(10)], [11.7] * 10)  # 1 cm/frame at the ankle's ground level
    assert foot_skate(pos, FEET, [11.7, 0.0]).item() == pytest.approx(1.0, abs=1e-12)
    # Below the ground level counts fully too (w is clamped to 1).
    assert foot_skate(pos, FEET, [12.7, 0.0]).item() == pytest.approx(1.0, abs=1e-12)


def test_foot_skate_lifted_foot_is_excluded():
    pos = _feet_track([float(i) for i in range(10)], [4.25 + 3.0] * 10)
    assert foot_skate(pos, FEET, [4.25, 0.0]).item() == 0.0
    assert foot_skate_terms(pos, FEET, [4.25, 0.0])[1].item() == 0
    # Exactly at H: w = 2 - 2 = 0, excluded.
    pos = _feet_track([float(i) for i in range(10)], [2.5] * 10)
    assert foot_skate(pos, FEET, [0.0, 0.0]).item() == 0.0


def test_foot_skate_partial_weight_and_vertical_motion():
    # At h = H/2 the weight is 2 - sqrt(2); speed 2 cm/frame -> score 2 (2 - sqrt 2) per sample.
    pos = _feet_track([2.0 * i for i in range(5)], [1.25] * 5)
    assert foot_skate(pos, FEET, [0.0, 0.0]).item() == pytest.approx(2 * (2 - math.sqrt(2)), rel=1e-12)
    # Purely vertical motion near the ground is not skating (horizontal displacement only).
    pos = _feet_track([0.0] * 5, [0.0, 1.0, 0.0, 1.0, 0.0])
    assert foot_skate(pos, FEET, [0.0, 0.0]).item() == 0.0


def test_foot_skate_height_is_read_at_the_later_frame():
    # Frame 0 -> 1 moves 1 cm while landing (later frame on the ground); frame 1 -> 2 lifts off 10 cm up.
    pos = _feet_track([0.0, 1.0, 2.0], [10.0, 0.0, 10.0])
    total, count = foot_skate_terms(pos, FEET, [0.0, 0.0])
    assert total.item() == pytest.approx(1.0) and count.item() == 1


def test_foot_skate_hand_computed_mixture():
    # Two grounded samples at 1 and 3 cm/frame, one lifted sample: (1 + 3) / 2 = 2.
    pos = _feet_track([0.0, 1.0, 4.0, 9.0], [0.0, 0.0, 0.0, 5.0])
    assert foot_skate(pos, FEET, [0.0, 0.0]).item() == pytest.approx(2.0)


def test_foot_skate_rejects_wrong_ground_length():
    with pytest.raises(ValueError):
        foot_skate(torch.zeros(1, 3, 3, 3), FEET, [0.0])


# --------------------------------------------------------------------------- diversity
def test_diversity_identical_samples_is_zero():
    x = torch.randn(1, 2, 5, 4, 3).expand(6, 2, 5, 4, 3)
    assert diversity(x).item() == 0.0


def test_diversity_offset_samples():
    base = torch.randn(2, 5, 4, 3, dtype=torch.float64)
    d = 3.5
    x = torch.stack([base, base + torch.tensor([0.0, 0.0, d], dtype=torch.float64)])
    assert diversity(x).item() == pytest.approx(d)
    # Three samples at x-offsets 0, 1, 3: pair distances 1, 3, 2 -> mean 2.
    offs = torch.tensor([0.0, 1.0, 3.0], dtype=torch.float64)
    x3 = base[None] + torch.stack([offs, torch.zeros(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64)], -1)[
        :, None, None, None, :
    ]
    assert diversity(x3).item() == pytest.approx(2.0)


def test_diversity_averages_over_cases():
    x = torch.zeros(2, 2, 3, 1, 3)
    x[1, 0, ..., 0] = 1.0  # case 0: samples 1 cm apart
    x[1, 1, ..., 0] = 3.0  # case 1: samples 3 cm apart
    assert diversity(x).item() == pytest.approx(2.0)


def test_diversity_needs_two_samples():
    with pytest.raises(ValueError):
        diversity(torch.zeros(1, 2, 3, 4, 3))


# --------------------------------------------------------------------------- Fréchet distance
def _exact_gaussian_set(n: int, mean: torch.Tensor, cov: torch.Tensor, seed: int) -> torch.Tensor:
    """n samples whose sample mean and unbiased covariance are exactly ``mean`` and ``cov``."""
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(n, mean.numel(), generator=g, dtype=torch.float64)
    x = x - x.mean(0)
    c = x.T @ x / (n - 1)
    white = x @ torch.linalg.inv(torch.linalg.cholesky(c)).T
    return white @ torch.linalg.cholesky(cov).T + mean


def test_frechet_self_distance_is_zero():
    x = torch.randn(50, 8, dtype=torch.float64)
    assert frechet_distance(x, x).item() == pytest.approx(0.0, abs=1e-8)
    y = torch.randn(3, 16)  # fewer samples than dimensions: rank-deficient covariance
    assert frechet_distance(y, y).item() == pytest.approx(0.0, abs=1e-5)


def test_frechet_diagonal_closed_form():
    mu_a, mu_b = torch.tensor([0.0, 1.0, 2.0]), torch.tensor([1.0, -1.0, 2.0])
    va, vb = torch.tensor([1.0, 4.0, 9.0]), torch.tensor([4.0, 1.0, 1.0])
    a = _exact_gaussian_set(200, mu_a.double(), torch.diag(va).double(), seed=0)
    b = _exact_gaussian_set(300, mu_b.double(), torch.diag(vb).double(), seed=1)
    expected = (mu_a - mu_b).square().sum() + (va.sqrt() - vb.sqrt()).square().sum()  # 5 + (1 + 1 + 4)
    assert expected.item() == pytest.approx(11.0)
    assert frechet_distance(a, b, eps=0.0).item() == pytest.approx(11.0, rel=1e-9)
    assert frechet_distance(a, b).item() == pytest.approx(11.0, rel=1e-5)


def test_frechet_non_commuting_2d_closed_form():
    # For 2x2 SPD M, tr sqrt(M) = sqrt(tr M + 2 sqrt(det M)); use M = Ca^(1/2) Cb Ca^(1/2) ~ Ca Cb.
    ca = torch.tensor([[2.0, 0.6], [0.6, 1.0]], dtype=torch.float64)
    cb = torch.tensor([[1.0, -0.4], [-0.4, 3.0]], dtype=torch.float64)
    mu_a = torch.tensor([0.5, -0.5], dtype=torch.float64)
    mu_b = torch.tensor([-1.0, 2.0], dtype=torch.float64)
    m = ca @ cb
    tr_sqrt = math.sqrt(torch.trace(m).item() + 2 * math.sqrt(torch.det(m).item()))
    expected = (mu_a - mu_b).square().sum().item() + torch.trace(ca + cb).item() - 2 * tr_sqrt
    a = _exact_gaussian_set(100, mu_a, ca, seed=2)
    b = _exact_gaussian_set(150, mu_b, cb, seed=3)
    assert frechet_distance(a, b, eps=0.0).item() == pytest.approx(expected, rel=1e-9)
    assert frechet_distance(b, a, eps=0.0).item() == pytest.approx(expected, rel=1e-9)  # symmetric


def test_frechet_tiny_sets_are_finite():
    a = torch.tensor([[1.0, 2.0]])
    b = torch.tensor([[4.0, 6.0]])
    assert frechet_distance(a, b).item() == pytest.approx(25.0, abs=1e-4)  # means only
    two = torch.tensor([[0.0, 0.0], [1.0, 1.0]])
    assert torch.isfinite(frechet_distance(two, b))
    with pytest.raises(ValueError):
        frechet_distance(torch.zeros(3, 2), torch.zeros(3, 4))
