"""Training the sampler with its per-frame functions compiled by ``torch.compile`` (inductor).

At training sizes (32-48 windows, width 192) a sampler frame costs about 200 small operations,
forward and backward, and on a CPU their dispatch, not their arithmetic, is most of the time.
Compiling the recurrent core and the frame step fuses their elementwise work into a few kernels:
a 40-frame rollout with its backward pass at 48 windows went from 0.59 to 0.36 s on the 2-core
development machine, and whole training steps (losses and critics included, which stay eager: they
run once per rollout) about 20% faster: 0.39-0.46 -> 0.32 s, and 0.55-0.67 -> 0.45-0.53 s with the
later losses.

Compilation is for training only: the inference engine has its own frozen TorchScript step
(:mod:`model.inference.traced_step`). Numbers match eager execution to float rounding, not bit for bit.
"""

from __future__ import annotations

import logging
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager

import torch

from model.nets.sampler import TransitionSampler

log = logging.getLogger(__name__)

# The per-frame methods replaced while compiled; instance attributes shadow the class's methods, so
# begin() and the rollout call the compiled versions without knowing it.
_COMPILED = ("_core", "step")


def compile_unavailable(device: torch.device) -> str | None:
    """Why ``torch.compile`` cannot run on ``device`` here, or None when it can."""
    if device.type == "cpu":
        compilers = [os.environ.get("CXX", ""), "c++", "g++", "clang++"]
        if not any(c and shutil.which(c) for c in compilers):
            return "no C++ compiler found (inductor builds CPU kernels with one; set CXX or install g++)"
        return None
    if device.type == "cuda":
        try:
            import triton  # noqa: F401
        except ImportError:
            return "triton is not installed (inductor builds CUDA kernels with it)"
        return None
    return f"not supported on {device.type}"


@contextmanager
def compiled_steps(model: TransitionSampler, enabled: bool = True) -> Iterator[bool]:
    """Within the block, ``model``'s recurrent core and frame step run compiled; yields whether they do.

    Falls back to eager execution, with a warning, where no compiler is available. Each batch size
    and grad mode compiles once (about a minute on the CPU the first time; inductor caches kernels
    on disk, so a resumed run compiles faster).
    """
    device = next(model.parameters()).device
    reason = compile_unavailable(device) if enabled else None
    if not enabled or reason:
        if reason:
            log.warning("training without torch.compile: %s", reason)
        yield False
        return
    limit = torch._dynamo.config.recompile_limit
    # Each function compiles once per batch size, grad mode and which inputs carry gradients (the
    # first frames come from data, the later ones from the network): about a dozen versions.
    torch._dynamo.config.recompile_limit = max(limit, 64)
    for name in _COMPILED:
        # dynamic=False: a handful of fixed batch sizes (train, cross-style, validation) each get
        # kernels specialised to their shapes.
        setattr(model, name, torch.compile(getattr(model, name), dynamic=False))
    try:
        yield True
    finally:
        for name in _COMPILED:
            delattr(model, name)
        torch._dynamo.config.recompile_limit = limit
