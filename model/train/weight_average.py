"""Weight averaging of bundles fine-tuned from one parent ("model soup").

Two samplers continued from the same checkpoint stay in one basin of the loss, so a weighted mean
of their weights is itself a working model, and it often sits above the straight line between the
two on a trade-off. For the default model: the 15,000-step sampler carries the requested style 67%
of the time at L2P 1.80, its 17,000-step continuation with three style critics 81% at L2P 1.90,
and their half-and-half mean 75% at L2P 1.81 (docs/experiments/2026-11-evaluation-history.md). Averaging unrelated models
(different seeds, say) gives nonsense; nothing here can tell, so only average a bundle with its own
continuations.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from model.inference.bundle import Bundle, BundleError, BundleMeta

Tensor = torch.Tensor


def _check_same_shape(bundles: Sequence[Bundle]) -> None:
    first = bundles[0]
    for other in bundles[1:]:
        if other.config.to_dict() != first.config.to_dict():
            raise BundleError("bundles to average must have the same sampler config")
        if other.manifold_config.to_dict() != first.manifold_config.to_dict():
            raise BundleError("bundles to average must have the same manifold config")
        if other.phase_config.to_dict() != first.phase_config.to_dict():
            raise BundleError("bundles to average must have the same phase config")
        if other.skeleton.to_dict() != first.skeleton.to_dict():
            raise BundleError("bundles to average must share one skeleton")
        if (other.phase_model is None) != (first.phase_model is None):
            raise BundleError("either every bundle to average has a phase model or none has")


def _mix(states: Sequence[dict[str, Tensor]], weights: Sequence[float]) -> dict[str, Tensor]:
    out = {}
    for key, first in states[0].items():
        if first.is_floating_point():
            acc = torch.zeros_like(first, dtype=torch.float64)
            for w, state in zip(weights, states):
                acc += w * state[key].double()
            out[key] = acc.to(first.dtype)
        else:  # counters and index buffers must agree; there is no mean of them
            if any(not torch.equal(first, state[key]) for state in states[1:]):
                raise BundleError(f"bundles to average differ in the non-float tensor {key!r}")
            out[key] = first.clone()
    return out


def average_bundles(bundles: Sequence[Bundle], weights: Sequence[float] | None = None,
                    name: str | None = None) -> Bundle:
    """A new bundle whose every float weight is ``sum_i w_i * weight_i`` (weights normalised to sum 1).

    The skeleton, configs, output and inference settings are the first bundle's; its meta too, with ``notes``
    naming the sources and their weights. The inputs are left unchanged.
    """
    if len(bundles) < 2:
        raise ValueError("averaging needs at least two bundles")
    weights = [1.0] * len(bundles) if weights is None else [float(w) for w in weights]
    if len(weights) != len(bundles):
        raise ValueError(f"{len(weights)} weights for {len(bundles)} bundles")
    if any(not w >= 0 for w in weights) or sum(weights) <= 0:  # `not >=` also refuses NaN
        raise ValueError("averaging weights must be 0 or more, and not all 0")
    total = sum(weights)
    weights = [w / total for w in weights]
    _check_same_shape(bundles)
    first = bundles[0]
    sources = ", ".join(f"{b.version} x {w:.3g}" for b, w in zip(bundles, weights))
    meta = BundleMeta(**{**first.meta.__dict__, "name": name or first.meta.name,
                         "notes": f"weight average of {sources}" + (f"; {first.meta.notes}" if first.meta.notes else "")})
    out = Bundle.create(first.skeleton, first.config, first.manifold_config, first.phase_config, meta)
    out.sampler.load_state_dict(_mix([b.sampler.state_dict() for b in bundles], weights), strict=True)
    if first.phase_model is None:
        out.phase_model = None
    else:
        assert out.phase_model is not None
        phases = [b.phase_model for b in bundles if b.phase_model is not None]  # every one (_check_same_shape)
        out.phase_model.load_state_dict(_mix([p.state_dict() for p in phases], weights), strict=True)
    out.output = first.output
    out.inference = first.inference
    out.sampler.eval()
    return out
