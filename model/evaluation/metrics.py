"""Evaluation metrics for motion transitions (RSMT, Tang et al. 2023, Sec. 5 "Metrics"), batched, in torch.

Conventions (see :mod:`model.motion.rotations`): quaternions are x,y,z,w; positions are in cm with Y up;
frames are at the 30 fps model rate. Shapes use ``B`` batch (transitions), ``T`` frames, ``J``
joints. Every metric returns a 0-dim tensor (float64 for NPSS and the Fréchet distance, the input
dtype otherwise); call ``float()`` on it to report it.

Definitions and their sources:

* :func:`l2p`, :func:`l2q`, :func:`npss`: Harvey et al. 2020 ("Robust motion in-betweening",
  the LaFAN1 benchmark, ``lafan1/benchmarks.py``), used unchanged by RSMT's ``benchmark.py``
  (reference doc Sec. 6.2).
* :func:`foot_skate`: Zhang et al. 2018 (MANN) as used by RSMT (paper Sec. 5, reference Sec. 6.2),
  with a per-joint ground level (:func:`ground_levels`) and horizontal foot speed.
* :func:`diversity`: RSMT paper Sec. 5 ("the L2 distance between the global joint positions of any
  two sequences"), as a true mean over pairs.
* :func:`frechet_distance`: the Fréchet distance between two Gaussians (FID/FMD; Heusel et al.
  2017; RSMT's FMD, paper Sec. 5).

Reporting conventions (scaling such as RSMT's ``100 x NPSS``) belong to the reporting code, not here.
Metrics that are ratios over a batch (:func:`npss`, :func:`foot_skate`) also have a ``*_terms``
function returning numerator and denominator, so an evaluator can pool several batches exactly.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import torch

from model.motion.rotations import quat_make_continuous

Tensor = torch.Tensor

_STD_FLOOR = 1e-6
"""Smallest per-coordinate std used when standardising (a coordinate that never varies in the
training data would otherwise divide by zero)."""

FOOT_HEIGHT_THRESHOLD_CM = 2.5
"""H in the foot-skate weight ``clamp(2 - 2^(h/H), 0, 1)`` (RSMT paper Sec. 5, MANN)."""


def _check_same_shape(a: Tensor, b: Tensor, what: str, last: int | None = None, ndim: int | None = None) -> None:
    if a.shape != b.shape:
        raise ValueError(f"{what}: prediction {list(a.shape)} and ground truth {list(b.shape)} differ in shape")
    if last is not None and a.shape[-1] != last:
        raise ValueError(f"{what}: the last dimension must be {last}, got {list(a.shape)}")
    if ndim is not None and a.dim() != ndim:
        raise ValueError(f"{what}: expected {ndim} dimensions, got {list(a.shape)}")


# --------------------------------------------------------------------------- position statistics
@dataclass(frozen=True)
class PositionStats:
    """Per-coordinate mean and std of global joint positions, for standardising L2P.

    LaFAN1 (``x_mean``/``x_std`` of shape ``(1, J*3, 1)``) and RSMT (``style100_benchmark_stat``,
    ``pos_stat`` per coordinate, 23x3) both compute these over the **training split**, in the frame
    the metric is computed in (for RSMT the clip canonical frame, reference doc Sec. 1.5a / 1.7).

    Attributes:
        mean: ``[J, 3]`` mean position in cm.
        std: ``[J, 3]`` population standard deviation in cm (``unbiased=False``, as ``np.std``).
        count: number of frames the statistics were computed from (0 when unknown).
    """

    mean: Tensor
    std: Tensor
    count: int = 0

    def __post_init__(self) -> None:
        if self.mean.dim() != 2 or self.mean.shape[-1] != 3 or self.mean.shape != self.std.shape:
            raise ValueError(
                f"PositionStats needs mean and std of shape [J, 3], got {list(self.mean.shape)} and {list(self.std.shape)}"
            )

    @property
    def num_joints(self) -> int:
        return int(self.mean.shape[0])

    @classmethod
    def from_positions(cls, global_positions: Tensor | Sequence[Tensor]) -> PositionStats:
        """Statistics over every frame of ``global_positions``.

        Args:
            global_positions: ``[N, T, J, 3]`` (any leading dimensions ``[..., J, 3]`` work), or a
                sequence of ``[T_i, J, 3]`` tensors of different lengths, in cm, in the frame the
                metric will be computed in (the clip canonical frame).
        """
        if isinstance(global_positions, Tensor):
            flat = global_positions.reshape(-1, *global_positions.shape[-2:])
        else:
            parts = [p.reshape(-1, *p.shape[-2:]) for p in global_positions]
            if not parts:
                raise ValueError("PositionStats.from_positions needs at least one frame")
            flat = torch.cat(parts, dim=0)
        if flat.shape[0] == 0 or flat.shape[-1] != 3:
            raise ValueError(f"expected positions [..., J, 3] with at least one frame, got {list(flat.shape)}")
        x = flat.to(torch.float64)
        mean = x.mean(dim=0)
        std = x.std(dim=0, unbiased=False) if x.shape[0] > 1 else torch.zeros_like(mean)
        return cls(mean=mean.float(), std=std.float(), count=int(x.shape[0]))

    def standardize(self, positions: Tensor) -> Tensor:
        """``(positions - mean) / max(std, 1e-6)`` for positions ``[..., J, 3]``."""
        if positions.shape[-2:] != self.mean.shape:
            raise ValueError(
                f"positions have {list(positions.shape[-2:])} joints x coords; the statistics are for {list(self.mean.shape)}"
            )
        mean = self.mean.to(positions.dtype).to(positions.device)
        std = self.std.to(positions.dtype).to(positions.device).clamp_min(_STD_FLOOR)
        return (positions - mean) / std

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``{"format": 1, "units": "cm", "count": n, "mean": [[x,y,z],...], "std": [...]}``."""
        return {
            "format": 1,
            "units": "cm",
            "count": self.count,
            "mean": self.mean.tolist(),
            "std": self.std.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> PositionStats:
        try:
            mean = torch.tensor(data["mean"], dtype=torch.float32)
            std = torch.tensor(data["std"], dtype=torch.float32)
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"invalid position statistics: {exc!r}") from exc
        return cls(mean=mean, std=std, count=int(data.get("count", 0)))


# --------------------------------------------------------------------------- reconstruction
def l2p(pred_pos: Tensor, gt_pos: Tensor, stats: PositionStats, last_frame: bool = False) -> Tensor:
    """L2P: mean L2 norm of the per-frame difference of standardised global positions.

    LaFAN1 / RSMT definition (reference doc Sec. 6.2): positions are standardised per coordinate
    with the training statistics, flattened to ``J*3`` values per frame, and
    ``mean_{batch, frames} || x_pred - x_gt ||_2`` is returned. Unitless. (The mean cancels in the
    difference; only the std matters.)

    Args:
        pred_pos, gt_pos: ``[B, T, J, 3]`` global positions in cm (the clip canonical frame).
        stats: :class:`PositionStats` of the training split.
        last_frame: score only the final frame ``T-1`` (RSMT's "L2 norm of global position of the
            last frame", used under changed controls; pass the target pose as ``gt_pos`` there).

    Returns:
        0-dim tensor.
    """
    _check_same_shape(pred_pos, gt_pos, "l2p", last=3, ndim=4)
    if last_frame:
        pred_pos, gt_pos = pred_pos[:, -1:], gt_pos[:, -1:]
    diff = stats.standardize(pred_pos) - stats.standardize(gt_pos)
    return diff.flatten(start_dim=2).norm(dim=-1).mean()


def align_quat_signs(q: Tensor, reference: Tensor) -> Tensor:
    """Flip each quaternion of ``q`` whose dot product with ``reference`` is negative. Same shape."""
    dot = (q * reference).sum(-1, keepdim=True)
    return torch.where(dot < 0, -q, q)


def l2q(pred_rot: Tensor, gt_rot: Tensor) -> Tensor:
    """L2Q: mean L2 norm of the per-frame difference of global quaternions (LaFAN1 definition).

    Each predicted quaternion is first given the sign that agrees with its ground truth (``q`` and
    ``-q`` are the same rotation), so the score is the distance to the nearer of the two. Then the
    quaternions are flattened to ``J*4`` values per frame and ``mean_{batch, frames} ||q_pred -
    q_gt||_2`` is returned.

    Args:
        pred_rot, gt_rot: ``[B, T, J, 4]`` global x,y,z,w quaternions (unit length).

    Returns:
        0-dim tensor.
    """
    _check_same_shape(pred_rot, gt_rot, "l2q", last=4, ndim=4)
    pred = align_quat_signs(pred_rot, gt_rot)
    return (pred - gt_rot).flatten(start_dim=2).norm(dim=-1).mean()


# --------------------------------------------------------------------------- NPSS
NpssSpectrum = Literal["real", "power"]


def _npss_spectrum(x: Tensor, spectrum: NpssSpectrum) -> Tensor:
    """Per-channel spectrum of ``x [B, T, C]`` along time: ``[B, F, C]``."""
    if spectrum == "real":
        return torch.fft.fft(x, dim=1).real.square()
    if spectrum == "power":
        return torch.fft.rfft(x, dim=1).abs().square()
    raise ValueError(f"spectrum must be 'real' or 'power', got {spectrum!r}")


def npss_terms(pred_rot: Tensor, gt_rot: Tensor, spectrum: NpssSpectrum = "real") -> tuple[Tensor, Tensor]:
    """Per-channel earth mover's distances and their weights, ``(emd [B, J*4], weight [B, J*4])``.

    ``npss = (emd * weight).sum() / weight.sum()``; pool batches by summing both sums. See :func:`npss`.
    """
    _check_same_shape(pred_rot, gt_rot, "npss", last=4, ndim=4)
    if pred_rot.shape[1] < 1:
        raise ValueError("npss needs at least one frame")
    # Sign alignment: make each joint's quaternion track continuous in time, independently for the
    # prediction and the ground truth. Flipping a whole channel track leaves its spectrum unchanged,
    # so after this the score no longer depends on the signs the inputs came with.
    pred = quat_make_continuous(pred_rot.to(torch.float64), dim=1).flatten(start_dim=2)
    gt = quat_make_continuous(gt_rot.to(torch.float64), dim=1).flatten(start_dim=2)
    p_pow = _npss_spectrum(pred, spectrum)
    g_pow = _npss_spectrum(gt, spectrum)
    p_tot = p_pow.sum(dim=1, keepdim=True)
    g_tot = g_pow.sum(dim=1, keepdim=True)
    # A channel that is identically zero has no spectrum: its cdf is taken as 0 and, for the
    # ground truth, its weight is 0, so it does not count (LaFAN1's code would produce NaN).
    p_cdf = torch.cumsum(torch.where(p_tot > 0, p_pow / p_tot.clamp_min(1e-300), 0.0), dim=1)
    g_cdf = torch.cumsum(torch.where(g_tot > 0, g_pow / g_tot.clamp_min(1e-300), 0.0), dim=1)
    emd = (p_cdf - g_cdf).abs().sum(dim=1)
    return emd, g_tot.squeeze(1)


def npss(pred_rot: Tensor, gt_rot: Tensor, spectrum: NpssSpectrum = "real") -> Tensor:
    """Normalised Power Spectrum Similarity on global quaternions (Gopalakrishnan et al. 2019).

    Implements LaFAN1's ``fast_npss`` (``lafan1/benchmarks.py``), which RSMT's ``benchmark.py``
    reuses (reference doc Sec. 6.2), on the quaternions flattened to ``C = J*4`` channels:

    1. align signs (each joint's track is made continuous over time, see :func:`npss_terms`);
    2. per channel, a spectrum over time (below), normalised to sum to 1, then its cumulative sum;
    3. per channel, EMD = sum over frequencies of ``|cdf_pred - cdf_gt|``;
    4. the mean of the EMDs over all batch items and channels **jointly**, weighted by each
       channel's total GT power (``np.average(emd, weights=gt_total_power)`` in LaFAN1), so a clip
       with more motion energy weighs more.

    Spectrum: ``"real"`` (default) is what LaFAN1's and RSMT's code do: the real part of the full
    FFT, squared (``np.square(np.real(np.fft.fft(x, axis=1)))``). It is what the published tables
    (LaFAN1, RSMT's 100xNPSS) were computed with, so numbers are comparable. ``"power"`` is the
    textbook power spectrum ``|rfft|^2`` (one-sided, shift-invariant). They give different values.

    Args:
        pred_rot, gt_rot: ``[B, T, J, 4]`` global x,y,z,w quaternions (usually the generated frames only).
        spectrum: ``"real"`` or ``"power"``.

    Returns:
        0-dim float64 tensor; unscaled (RSMT reports ``100 x`` this value).
    """
    emd, weight = npss_terms(pred_rot, gt_rot, spectrum)
    total = weight.sum()
    if total <= 0:
        return torch.zeros((), dtype=torch.float64)
    return (emd * weight).sum() / total


# --------------------------------------------------------------------------- distances in cm
def mean_joint_error_cm(pred_pos: Tensor, gt_pos: Tensor) -> Tensor:
    """Mean Euclidean distance in cm over batch, frames and joints.

    Args:
        pred_pos, gt_pos: ``[B, T, J, 3]`` global positions in cm.
    """
    _check_same_shape(pred_pos, gt_pos, "mean_joint_error_cm", last=3, ndim=4)
    return (pred_pos - gt_pos).norm(dim=-1).mean()


def last_frame_error_cm(pred_pos: Tensor, target_pos: Tensor) -> Tensor:
    """Mean Euclidean joint distance in cm between the final generated frame and the target pose.

    Args:
        pred_pos: ``[B, T, J, 3]`` generated positions in cm; frame ``T-1`` is scored.
        target_pos: ``[B, J, 3]`` target pose, or ``[B, T', J, 3]`` whose last frame is the target.
    """
    if pred_pos.dim() != 4 or pred_pos.shape[-1] != 3:
        raise ValueError(f"last_frame_error_cm: pred_pos must be [B, T, J, 3], got {list(pred_pos.shape)}")
    if target_pos.dim() == 4:
        target_pos = target_pos[:, -1]
    _check_same_shape(pred_pos[:, -1], target_pos, "last_frame_error_cm", last=3, ndim=3)
    return (pred_pos[:, -1] - target_pos).norm(dim=-1).mean()


# --------------------------------------------------------------------------- foot skate
def ground_levels(
    global_positions: Tensor | Sequence[Tensor], feet: Sequence[int], percentile: float = 5.0
) -> Tensor:
    """Ground level of each foot joint, in cm: a low percentile of its height over all frames.

    Foot joints never reach ``y = 0``: in the Bandai-Namco data the toes rest about 4.25 cm above the
    floor (about 1 cm more for some styles) and the ankles about 11.7 cm, so a foot-skate rule with
    the floor at 0 would see no contacts at all. The level is therefore found from the data, per
    joint. A low percentile is used rather than the minimum because a single capture glitch or
    a foot pushed into the floor would set the minimum, and rather than the median because in
    locomotion the feet are in the air for a large part of the time (more than half when running).
    The 5th percentile lies inside the contact phase for walking, running and standing takes.

    Args:
        global_positions: ``[N, T, J, 3]`` (any ``[..., J, 3]``) or a sequence of ``[T_i, J, 3]``,
            in cm, Y up (the training or evaluation data; yaw and XZ centring do not change it).
        feet: indices of the foot joints (``skeleton.feet``: left ankle, toe, right ankle, toe).
        percentile: in ``[0, 100]``, linear interpolation between samples.

    Returns:
        ``[len(feet)]`` heights in cm, in the order of ``feet``.
    """
    if not 0.0 <= percentile <= 100.0:
        raise ValueError(f"percentile must be in [0, 100], got {percentile}")
    idx = list(feet)
    if not idx:
        raise ValueError("ground_levels needs at least one foot joint")
    if isinstance(global_positions, Tensor):
        parts = [global_positions]
    else:
        parts = list(global_positions)
    heights = torch.cat([p[..., idx, 1].reshape(-1, len(idx)) for p in parts], dim=0).to(torch.float64)
    n = heights.shape[0]
    if n == 0:
        raise ValueError("ground_levels needs at least one frame")
    # Sort-based quantile (torch.quantile refuses inputs above 16M elements).
    srt = heights.sort(dim=0).values
    pos = percentile / 100.0 * (n - 1)
    lo = int(pos)
    hi = min(lo + 1, n - 1)
    frac = pos - lo
    level = srt[lo] + (srt[hi] - srt[lo]) * frac
    dtype = parts[0].dtype if parts[0].is_floating_point() else torch.float32
    return level.to(dtype)


def ground_contact_weight(height: Tensor, height_threshold_cm: float = FOOT_HEIGHT_THRESHOLD_CM) -> Tensor:
    """Foot skate's contact weight ``clamp(2 - 2^(h/H), 0, 1)`` for heights above the ground: 1 at or
    below it, 0 from ``H`` up (see :func:`foot_skate`)."""
    return (2.0 - torch.pow(2.0, height / height_threshold_cm)).clamp(0.0, 1.0)


def foot_skate_terms(
    pos: Tensor, feet: Sequence[int], ground: Tensor | Sequence[float], height_threshold_cm: float = FOOT_HEIGHT_THRESHOLD_CM
) -> tuple[Tensor, Tensor]:
    """``(sum of v*w, number of samples with w > 0)`` for :func:`foot_skate`; pool batches by summing both."""
    if pos.dim() != 4 or pos.shape[-1] != 3:
        raise ValueError(f"foot_skate: pos must be [B, T, J, 3], got {list(pos.shape)}")
    if height_threshold_cm <= 0:
        raise ValueError("height_threshold_cm must be positive")
    idx = list(feet)
    ground_t = torch.as_tensor(ground, dtype=pos.dtype, device=pos.device).reshape(-1)
    if ground_t.numel() != len(idx):
        raise ValueError(f"ground has {ground_t.numel()} levels for {len(idx)} foot joints")
    p = pos[:, :, idx]  # [B, T, F, 3]
    if p.shape[1] < 2:
        zero = torch.zeros((), dtype=pos.dtype, device=pos.device)
        return zero, zero.clone()
    step = p[:, 1:] - p[:, :-1]
    v = step[..., [0, 2]].norm(dim=-1)  # horizontal cm/frame, [B, T-1, F]
    h = p[:, 1:, :, 1] - ground_t  # height above that joint's ground at the later frame
    w = ground_contact_weight(h, height_threshold_cm)
    return (v * w).sum(), (w > 0).sum().to(pos.dtype)


def foot_skate(
    pos: Tensor, feet: Sequence[int], ground: Tensor | Sequence[float], height_threshold_cm: float = FOOT_HEIGHT_THRESHOLD_CM
) -> Tensor:
    """Foot skate in cm/frame (MANN, Zhang et al. 2018; RSMT paper Sec. 5, reference doc Sec. 6.2).

    For each foot joint and each pair of consecutive frames ``t, t+1``:

    * ``v``: the **horizontal** (XZ) displacement ``||p^{t+1} - p^t||`` in cm/frame. MANN measures
      horizontal foot velocity; RSMT's code uses the full 3D displacement, which also counts a foot
      being lifted or planted as skating. We follow MANN: vertical motion is not sliding.
    * ``h``: height of the joint above its own ground level (:func:`ground_levels`) at ``t+1``.
      RSMT's code uses ``|y|`` with the floor at 0, which on rigs whose foot joints sit above the
      floor (toes ~4.25 cm, ankles ~11.7 cm here) would count no contact at all.
    * ``w = clamp(2 - 2^(h/H), 0, 1)`` with ``H = height_threshold_cm`` (2.5): 1 at or below the
      ground, 0 from ``H`` upwards.

    Score = ``sum(v*w) / #{w > 0}`` over the whole batch, i.e. the weighted speed averaged over the
    foot samples lower than ``H``; 0 when no sample is that low.

    Args:
        pos: ``[B, T, J, 3]`` global positions in cm, Y up, at the model rate (30 fps).
        feet: foot joint indices (``skeleton.feet``).
        ground: ``[len(feet)]`` ground level of each foot joint in cm.

    Returns:
        0-dim tensor, cm/frame.
    """
    total, count = foot_skate_terms(pos, feet, ground, height_threshold_cm)
    return total / count.clamp_min(1.0)


# --------------------------------------------------------------------------- root speed
def max_root_speed(pos: Tensor, fps: float, root: int = 0) -> Tensor:
    """Per sequence, the largest speed of the root joint between consecutive frames, in cm/s.

    A transition that corrects its course by jumping shows here: one frame's jump of ``x`` cm is a
    speed of ``x * fps`` cm/s.

    Args:
        pos: ``[B, T, J, 3]`` global positions in cm, ``T >= 2`` (put the last context frame first).
        fps: frames per second of ``pos``.
        root: index of the root joint.

    Returns:
        ``[B]`` tensor, cm/s.
    """
    if pos.dim() != 4 or pos.shape[-1] != 3 or pos.shape[1] < 2:
        raise ValueError(f"max_root_speed: pos must be [B, T>=2, J, 3], got {list(pos.shape)}")
    step = pos[:, 1:, root] - pos[:, :-1, root]
    return step.norm(dim=-1).amax(dim=1) * fps


# --------------------------------------------------------------------------- diversity
def diversity(samples: Tensor) -> Tensor:
    """Mean pairwise distance in cm between ``S`` sampled transitions of the same case.

    For each case ``b``: the mean over pairs ``i < j`` of the mean per-joint Euclidean distance
    ``mean_{t, joint} ||x_i - x_j||``; then the mean over cases. Two samples offset by ``d`` cm
    everywhere score ``d``.

    RSMT (paper Sec. 5; reference doc Sec. 6.2) instead sums the MSE in cm^2 over all ordered pairs
    and divides by ``N^2/2`` (50 for 10 samples, where there are 45 unordered pairs), which is
    neither a mean over pairs nor in cm. We report a true mean over pairs of a distance in cm,
    which is independent of ``S`` and directly readable; the numbers are therefore not comparable
    with the paper's diversity column.

    Args:
        samples: ``[S, B, T, J, 3]`` positions in cm, ``S >= 2`` samples per case.

    Returns:
        0-dim tensor, cm.
    """
    if samples.dim() != 5 or samples.shape[-1] != 3:
        raise ValueError(f"diversity: samples must be [S, B, T, J, 3], got {list(samples.shape)}")
    s = samples.shape[0]
    if s < 2:
        raise ValueError("diversity needs at least two samples per case")
    i, j = torch.triu_indices(s, s, offset=1, device=samples.device)
    d = (samples[i] - samples[j]).norm(dim=-1)  # [P, B, T, J]
    return d.mean(dim=(0, 2, 3)).mean()


# --------------------------------------------------------------------------- Fréchet distance
def _sqrtm_psd(m: Tensor) -> Tensor:
    """Square root of a symmetric positive semi-definite matrix by eigen-decomposition."""
    m = 0.5 * (m + m.transpose(-1, -2))
    evals, evecs = torch.linalg.eigh(m)
    return (evecs * evals.clamp_min(0.0).sqrt().unsqueeze(-2)) @ evecs.transpose(-1, -2)


def frechet_distance(feat_a: Tensor, feat_b: Tensor, eps: float = 1e-6) -> Tensor:
    """Fréchet distance between Gaussians fitted to two feature sets (FID / RSMT's FMD).

    ``||mu_a - mu_b||^2 + tr(C_a + C_b - 2 (C_a^{1/2} C_b C_a^{1/2})^{1/2})``, with unbiased sample
    covariances (as ``np.cov``) plus ``eps * I``. The matrix square roots are of symmetric PSD
    matrices, taken by eigen-decomposition in float64 with negative round-off eigenvalues clamped,
    so the result is real and finite even for one or two samples or rank-deficient sets (a set of
    one sample has covariance ``eps * I``). It equals the usual ``tr sqrtm(C_a C_b)`` form.

    Args:
        feat_a: ``[N, D]`` features; feat_b: ``[M, D]``.
        eps: diagonal added to both covariances.

    Returns:
        0-dim float64 tensor (>= 0 up to round-off; clamped at 0).
    """
    if feat_a.dim() != 2 or feat_b.dim() != 2 or feat_a.shape[1] != feat_b.shape[1]:
        raise ValueError(f"frechet_distance needs [N, D] and [M, D], got {list(feat_a.shape)} and {list(feat_b.shape)}")
    if feat_a.shape[0] < 1 or feat_b.shape[0] < 1:
        raise ValueError("frechet_distance needs at least one sample in each set")
    a = feat_a.to(torch.float64)
    b = feat_b.to(torch.float64)
    eye = torch.eye(a.shape[1], dtype=torch.float64, device=a.device)

    def cov(x: Tensor) -> Tensor:
        if x.shape[0] < 2:
            return eps * eye
        xc = x - x.mean(dim=0, keepdim=True)
        return xc.T @ xc / (x.shape[0] - 1) + eps * eye

    mu_a, mu_b = a.mean(dim=0), b.mean(dim=0)
    ca, cb = cov(a), cov(b)
    sa = _sqrtm_psd(ca)
    cross = _sqrtm_psd(sa @ cb @ sa)
    d = (mu_a - mu_b).square().sum() + torch.trace(ca) + torch.trace(cb) - 2.0 * torch.trace(cross)
    return d.clamp_min(0.0)
