"""Training on several processes (``torchrun``): the process group and the few collectives the loop needs.

``rsmt train`` started by ``torchrun --nproc_per_node N`` finds ``WORLD_SIZE``/``RANK``/``LOCAL_RANK``
in its environment and joins a process group (gloo on the CPU, NCCL on GPUs, one GPU per local rank).
Every process then trains the same model on its own batches: :func:`average_gradients` averages the
gradients after each backward pass, so every rank takes the same optimiser step. Rank 0 alone
validates, writes checkpoints, stage weights and the bundle, and shows progress bars.

Without a process group (one process, the usual case) every helper here is a no-op: the world is 1
process of rank 0, and the training numbers are exactly those of a run that never imported this.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager

import torch
import torch.distributed as dist
from torch import nn

Tensor = torch.Tensor

# Offsets that give each rank (and each rank's global RNG) its own random streams in a run of several
# processes; rank 0's step generator keeps the stream a single process would draw. torch's CPU
# generator keeps only a seed's low 32 bits, so the offsets are 32-bit: with fewer than 256 ranks
# and a few million steps, no two (step, rank, stream) share a seed.
_RANK_STRIDE = 0x9E3779B1
_GLOBAL_STREAM = 0xF36AD779


def launched() -> bool:
    """True when started by ``torchrun`` (or a launcher like it) with more than one process."""
    return int(os.environ.get("WORLD_SIZE", "1")) > 1 and "RANK" in os.environ


def active() -> bool:
    """True when this process is part of a process group of more than one process."""
    return dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1


def world_size() -> int:
    return dist.get_world_size() if active() else 1


def rank() -> int:
    return dist.get_rank() if active() else 0


def is_main() -> bool:
    """True on rank 0, the process that validates and writes files (and in a single process)."""
    return rank() == 0


def start(device: torch.device) -> torch.device:
    """Join the process group when launched by ``torchrun``; returns the device this process trains on.

    On CUDA each process takes the GPU of its local rank (``cuda:LOCAL_RANK``) and the group uses
    NCCL; on the CPU it uses gloo. Without ``torchrun`` (or with one process) nothing happens.
    """
    if not launched() or active():
        return device
    local = int(os.environ.get("LOCAL_RANK", os.environ["RANK"]))
    if device.type == "cuda":
        if local >= torch.cuda.device_count():
            raise ValueError(f"local rank {local} has no GPU: only {torch.cuda.device_count()} CUDA GPU(s) are visible")
        device = torch.device("cuda", local)
        torch.cuda.set_device(device)
        dist.init_process_group("nccl", device_id=device)
    else:
        dist.init_process_group("gloo")
    print(f"process {rank()} of {world_size()} training on {device}", file=sys.stderr, flush=True)
    return device


def stop() -> None:
    """Leave the process group, if this process joined one. No barrier: after an error on one rank the
    others are stuck in a collective, and this rank's exit is what lets torchrun stop them."""
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def barrier() -> None:
    """Wait for every rank (a no-op in one process)."""
    if active():
        dist.barrier()


@contextmanager
def main_first() -> Iterator[None]:
    """Rank 0 runs the block first (building caches, training critics, writing files), then the others,
    which find its results on disk instead of writing the same files at the same time."""
    if not is_main():
        barrier()
    yield
    if is_main():
        barrier()


def step_seed(seed: int, step: int) -> int:
    """The seed of a training step's random stream: ``(seed, step)`` in one process, and on rank 0 of
    several; each other rank has its own stream, so the ranks draw different batches."""
    return seed * 1_000_003 + step + rank() * _RANK_STRIDE


def reseed_global(seed: int, step: int) -> None:
    """In a run of several processes, seed torch's global RNG (noise drawn outside the step generator)
    from ``(seed, step, rank)`` before each step: the ranks draw different noise, and a resumed run
    draws what it would have whichever rank's RNG state its checkpoint holds. A no-op in one process,
    whose global RNG goes on from the checkpoint as before."""
    if active():
        torch.manual_seed(step_seed(seed, step) + _GLOBAL_STREAM)


def average_gradients(params: Iterable[nn.Parameter]) -> None:
    """Replace each parameter's gradient by its mean over the ranks, as DistributedDataParallel would.

    A rank whose step did not reach a parameter (gradient ``None``) counts as a zero gradient; a
    parameter no rank reached keeps ``None``, so the optimiser skips it as it would in one process.
    One all-reduce per (device, dtype) of the gradients flattened together. A no-op in one process.
    """
    if not active():
        return
    groups: dict[tuple[torch.device, torch.dtype], list[nn.Parameter]] = {}
    for p in params:
        if p.requires_grad:
            groups.setdefault((p.device, p.dtype), []).append(p)
    n = dist.get_world_size()
    for (device, dtype), ps in groups.items():
        grads = [p.grad.reshape(-1) if p.grad is not None else torch.zeros(p.numel(), device=device, dtype=dtype)
                 for p in ps]
        reached = torch.tensor([p.grad is not None for p in ps], device=device, dtype=dtype)
        flat = torch.cat([*grads, reached])
        dist.all_reduce(flat)
        offset = 0
        for p, any_rank in zip(ps, flat[-len(ps):].tolist()):
            size = p.numel()
            if any_rank > 0:
                mean = flat[offset:offset + size].view_as(p) / n
                if p.grad is None:
                    p.grad = mean.clone()
                else:
                    p.grad.copy_(mean)
            offset += size


def broadcast_state(module: nn.Module) -> None:
    """Copy rank 0's parameters and buffers to every rank (a no-op in one process)."""
    if not active():
        return
    with torch.no_grad():
        for t in module.state_dict().values():
            if t.is_contiguous():
                dist.broadcast(t, 0)
            else:
                tmp = t.contiguous()
                dist.broadcast(tmp, 0)
                t.copy_(tmp)


def rank0_decides(flag: bool) -> bool:
    """Rank 0's ``flag`` on every rank, for decisions that must agree, such as stopping at a time limit."""
    if not active():
        return flag
    device = torch.device("cuda", torch.cuda.current_device()) if dist.get_backend() == "nccl" else torch.device("cpu")
    t = torch.tensor([1 if flag else 0], device=device)
    dist.broadcast(t, 0)
    return bool(t.item())
