"""A training term on the style code itself: codes of one style close together, codes of different styles apart.

The sampler's losses reach the style encoder only through the motion it conditions, so nothing stops
the code from collapsing towards a constant that the recurrent core learns to ignore (what the paper's
authors report) or from encoding the clip's content (walk against run) more than its style. This term
(a supervised contrastive loss, Khosla et al. 2020) reads the time-mean code of clips of several styles
drawn each step: a clip's code is pulled towards those of other clips of its style, whatever their
content, and pushed from every other style's. It adds no parameters, so checkpoints are unchanged.
"""

from __future__ import annotations

import torch

Tensor = torch.Tensor


def supervised_contrastive(codes: Tensor, labels: Tensor, temperature: float) -> Tensor:
    """Supervised contrastive loss of ``codes [N, C]`` (any scale: they are normalised) with classes ``labels [N]``.

    For every anchor with at least one other sample of its class, minus the mean log-probability of
    picking one of those among all other samples by cosine similarity / ``temperature``; averaged over
    such anchors (0 when there is none). Lower when each class's codes point one way and classes apart.
    """
    if codes.dim() != 2 or labels.shape != codes.shape[:1]:
        raise ValueError(f"codes [N, C] and labels [N], got {tuple(codes.shape)} and {tuple(labels.shape)}")
    if temperature <= 0:
        raise ValueError(f"temperature must be above 0, got {temperature}")
    z = torch.nn.functional.normalize(codes, dim=-1)
    sim = z @ z.T / temperature
    eye = torch.eye(len(z), dtype=torch.bool, device=z.device)
    sim = sim.masked_fill(eye, float("-inf"))  # an anchor is never its own candidate
    log_prob = sim - torch.logsumexp(sim, dim=1, keepdim=True)
    positive = (labels[:, None] == labels[None, :]) & ~eye
    count = positive.sum(1)
    has = count > 0
    if not has.any():
        return codes.sum() * 0.0
    mean_pos = log_prob.masked_fill(~positive, 0.0).sum(1)[has] / count[has]
    return -mean_pos.mean()


def time_mean_code(code: Tensor) -> Tensor:
    """The style code ``[B, T', C]`` averaged over its time steps (what FiLM reads), ``[B, C]``."""
    return code.mean(dim=1)
