"""A copy of a transition network whose recurrent cells (LSTM or GRU) have int8 weights, for the engine's
per-frame step.

At batch 1 a frame reads every per-frame weight once (7.8 MB in float32 for the default model),
and on a shared 2-core machine those reads, not the arithmetic, set the latency. The LSTM cell
is the largest layer (3.4 MB); PyTorch's dynamic quantisation stores it as int8 (0.85 MB) and
quantises its inputs per call (fbgemm kernels). With the default model on the development machine,
alternating a float32 and an int8-LSTM engine in one process (five pairs, one thread), batch-1
medians went from 0.94-1.83 to 0.70-1.17 ms and 128 characters from 10.7-12.0 to 13.4-15.4
thousand character-frames/s; test figures are unchanged to the third digit (docs/experiments/2026-11-benchmark-runs.md).

The warm-up on the context frames (``begin``) keeps the float32 cell: it runs once per transition.
"""

from __future__ import annotations

import copy
import logging
import warnings

import torch

from model.nets.transition_net import TransitionNet

log = logging.getLogger(__name__)


def int8_lstm_sampler(sampler: TransitionNet) -> TransitionNet | None:
    """A copy of ``sampler`` with its recurrent cells (``LSTMCell``, ``GRUCell``) quantised to int8, or None where
    this PyTorch cannot (the float32 network then serves, with a warning); the network itself where it has none."""
    if not any(isinstance(m, (torch.nn.LSTMCell, torch.nn.GRUCell)) for m in sampler.modules()):
        return sampler
    try:
        with warnings.catch_warnings():
            # torch 2.13 marks its quantised tensor types deprecated (to move to torchao); the
            # kernels still run, and the failure path below covers a release without them.
            warnings.simplefilter("ignore")
            quantized = torch.ao.quantization.quantize_dynamic(copy.deepcopy(sampler), {torch.nn.LSTMCell, torch.nn.GRUCell},
                                                               dtype=torch.qint8)
    except Exception as exc:  # noqa: BLE001 - any failure keeps the float32 network
        log.warning("int8 LSTM unavailable (%s); the step runs in float32", exc)
        return None
    return quantized.eval()
