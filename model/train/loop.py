"""The training loop every stage shares: progress bar, validation each epoch, checkpoints, resume.

Resume state (weights, optimiser moments, RNG, step, history) is written as safetensors + JSON in
the run folder, atomically, every ``checkpoint_every_s`` seconds and at each epoch's end; nothing
is pickled. A run that is stopped (Ctrl-C, a killed process) restarts from its last checkpoint
when launched again with the same run folder.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import torch
from safetensors.torch import load_file, save_file
from torch import nn
from tqdm import tqdm

from model.train import distributed

if TYPE_CHECKING:
    from model.train.motion_tensors import MotionTensors

log = logging.getLogger(__name__)
M = TypeVar("M", bound=nn.Module)
Tensor = torch.Tensor


@dataclass
class LoopConfig:
    """Schedule of one training stage.

    Attributes:
        iterations: optimiser steps in total.
        epoch_iterations: steps between validations (an "epoch" of the progress report).
        lr / lr_final: learning rate, decayed by cosine to ``lr_final`` after ``warmup``.
        warmup: steps of linear warm-up.
        grad_clip: gradient-norm clip.
        weight_decay: AdamW decay (biases and norms excluded).
        seed: torch seed at the start (restored from checkpoints on resume).
        checkpoint_every_s: seconds between checkpoints within an epoch.
        time_limit_s: stop (after a checkpoint) when this much time has passed in this run; 0 = none.
        restart_at / restart_lr: warm restarts: from step ``restart_at`` on, another cosine from
            ``restart_lr`` down to ``lr_final`` until the next restart or the end (0 = none). Each
            may be one number or a list (several restarts). Lengthening a finished run this way
            keeps the schedule of its first part, so the run resumes from its checkpoint and the
            same config trained from scratch repeats it.
    """

    iterations: int = 1000
    epoch_iterations: int = 100
    lr: float = 1e-3
    lr_final: float = 1e-5
    warmup: int = 50
    grad_clip: float = 1.0
    weight_decay: float = 0.0
    seed: int = 0
    checkpoint_every_s: float = 120.0
    time_limit_s: float = 0.0
    restart_at: int | tuple[int, ...] = 0
    restart_lr: float | tuple[float, ...] = 0.0

    def restarts(self) -> list[tuple[int, float]]:
        """``(step, lr)`` of every warm restart inside the run, in order."""
        steps = (self.restart_at,) if isinstance(self.restart_at, int) else tuple(self.restart_at)
        lrs = (self.restart_lr,) if isinstance(self.restart_lr, (int, float)) else tuple(self.restart_lr)
        if len(steps) != len(lrs):
            raise ValueError(f"restart_at has {len(steps)} steps but restart_lr {len(lrs)} rates")
        return sorted((int(a), float(r)) for a, r in zip(steps, lrs, strict=True) if 0 < a < self.iterations)


@dataclass
class LoopResult:
    history: list[dict] = field(default_factory=list)
    seconds: float = 0.0
    finished: bool = False


DEVICE_CHOICES = ("auto", "cpu", "cuda")


def seeded_start(make: Callable[[], M], seed: int, train: MotionTensors, val: MotionTensors,
                 device: torch.device | str | None) -> tuple[M, MotionTensors, MotionTensors]:
    """A stage's model and data on :func:`resolve_device`'s device. The model is built on the CPU right after seeding
    torch with ``seed``, then moved: the same seed gives the same start on any device and in any process (torch 2.13
    seeds its global RNG randomly at start-up)."""
    dev = resolve_device(device)
    torch.manual_seed(seed)
    return make().to(dev), train.to(dev), val.to(dev)


def resolve_device(device: str | torch.device | None = "auto") -> torch.device:
    """The torch device to train on: ``auto`` (or ``None``) is CUDA when torch sees a GPU, else the CPU.

    Asking for CUDA where there is none fails here, with a message saying so, instead of deep
    inside torch at the first tensor moved.
    """
    if device is None or (isinstance(device, str) and device == "auto"):
        device = "cuda" if torch.cuda.is_available() else "cpu"
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise ValueError(f"unknown device {device!r}: use one of {', '.join(DEVICE_CHOICES)}") from exc
    if dev.type == "cpu":
        return dev
    if dev.type != "cuda":
        raise ValueError(f"unsupported device {device!r}: use one of {', '.join(DEVICE_CHOICES)}")
    if not torch.cuda.is_available():
        why = "this torch build has no CUDA support" if torch.version.cuda is None else "no CUDA GPU is visible"
        raise ValueError(f"device {str(device)!r} was asked for, but {why} (torch.cuda.is_available() is False); "
                         "use --device cpu or auto")
    if dev.index is not None and dev.index >= torch.cuda.device_count():
        raise ValueError(f"device {str(device)!r} was asked for, but only {torch.cuda.device_count()} CUDA GPU(s) are visible")
    # An explicit index, as tensors report it, so device comparisons hold.
    return dev if dev.index is not None else torch.device("cuda", torch.cuda.current_device())


def cpu_randn_like(t: Tensor) -> Tensor:
    """Standard normal noise shaped like ``t``, drawn from the CPU generator and moved to ``t``'s device.

    Drawing on the CPU keeps every random number in the CPU RNG, the one checkpoints save, so a
    resumed GPU run draws what it would have, and a GPU run draws the same noise as a CPU run.
    """
    return torch.randn(t.shape, dtype=t.dtype).to(t.device)


def step_generator(seed: int, step: int) -> torch.Generator:
    """The random stream of one training step: a resumed run draws exactly the batches it would have.

    Under ``torchrun`` each rank draws its own batches (:func:`model.train.distributed.step_seed`);
    one process draws exactly what it always has.
    """
    return torch.Generator().manual_seed(distributed.step_seed(seed, step))


def make_optimizer(params: list[tuple[str, nn.Parameter]], cfg: LoopConfig,
                   lr_scales: Mapping[str, float] | None = None) -> torch.optim.Optimizer:
    """AdamW with decay on matrices only (biases, norms and gains stay undecayed).

    ``lr_scales`` maps a parameter-name prefix to a multiplier of the schedule's rate for those
    parameters (their own groups, each carrying ``lr_scale``); without it, two groups as always."""
    scales = {k: float(v) for k, v in (lr_scales or {}).items() if float(v) != 1.0}

    def scale_of(name: str) -> float:
        return next((v for k, v in scales.items() if name.startswith(k)), 1.0)

    groups: list[dict[str, Any]] = []
    for scale in [1.0, *sorted(set(scales.values()))]:
        mine = [(n, p) for n, p in params if scale_of(n) == scale]
        extra = {} if scale == 1.0 else {"lr_scale": scale}
        groups += [{"params": [p for _, p in mine if p.dim() >= 2], "weight_decay": cfg.weight_decay} | extra,
                   {"params": [p for _, p in mine if p.dim() < 2], "weight_decay": 0.0} | extra]
    return torch.optim.AdamW(groups, lr=cfg.lr, betas=(0.9, 0.99))


def learning_rate(step: int, cfg: LoopConfig) -> float:
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    restarts = cfg.restarts()
    ends = [a for a, _ in restarts[1:]] + [cfg.iterations] if restarts else []
    for (start, peak), end in reversed(list(zip(restarts, ends, strict=True))):
        if step >= start:
            progress = (step - start) / max(1, end - start)
            return cfg.lr_final + 0.5 * (peak - cfg.lr_final) * (1 + math.cos(math.pi * progress))
    end = restarts[0][0] if restarts else cfg.iterations
    progress = min(1.0, (step - cfg.warmup) / max(1, end - cfg.warmup))
    return cfg.lr_final + 0.5 * (cfg.lr - cfg.lr_final) * (1 + math.cos(math.pi * progress))


def _atomic_write_text(path: Path, text: str) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def save_checkpoint(folder: Path, model: nn.Module, optimizer: torch.optim.Optimizer, step: int, history: list[dict],
                    extra: dict | None = None) -> None:
    """Weights, optimiser moments and RNG in safetensors; counters and history in JSON.

    Tensors are written from the CPU whatever the device trained on, so a checkpoint resumes anywhere.
    """
    folder.mkdir(parents=True, exist_ok=True)
    tensors = {f"model.{k}": v.detach().cpu().contiguous().clone() for k, v in model.state_dict().items()}
    opt = optimizer.state_dict()
    for pid, state in opt["state"].items():
        for k, v in state.items():
            t = v if torch.is_tensor(v) else torch.tensor(v)
            tensors[f"opt.{pid}.{k}"] = t.detach().cpu().contiguous().clone()
    tensors["rng.torch"] = torch.get_rng_state()
    tmp = folder / "checkpoint.safetensors.tmp"
    save_file(tensors, str(tmp))
    os.replace(tmp, folder / "checkpoint.safetensors")
    meta = {"step": step, "history": history, "param_groups": [
        {k: v for k, v in g.items() if k != "params"} | {"params": list(g["params"])} for g in opt["param_groups"]
    ], "extra": extra or {}}
    _atomic_write_text(folder / "checkpoint.json", json.dumps(meta, indent=1))


def load_checkpoint(folder: Path, model: nn.Module, optimizer: torch.optim.Optimizer) -> tuple[int, list[dict], dict] | None:
    """Restore a checkpoint written by :func:`save_checkpoint`; ``None`` when there is none.

    The tensors load on the CPU; ``load_state_dict`` copies them onto the model's device, and the
    optimiser's onto each parameter's device (its step counters stay on the CPU, as AdamW keeps them).
    """
    if not (folder / "checkpoint.json").is_file() or not (folder / "checkpoint.safetensors").is_file():
        return None
    meta = json.loads((folder / "checkpoint.json").read_text())
    tensors = load_file(str(folder / "checkpoint.safetensors"))
    model.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model.")}, strict=True)
    state: dict[int, dict] = {}
    for key, v in tensors.items():
        if key.startswith("opt."):
            _, pid, name = key.split(".", 2)
            state.setdefault(int(pid), {})[name] = v
    optimizer.load_state_dict({"state": state, "param_groups": meta["param_groups"]})
    torch.set_rng_state(tensors["rng.torch"])
    return int(meta["step"]), list(meta["history"]), dict(meta.get("extra", {}))


def _resume(name: str, folder: Path, model: nn.Module, optimizer: torch.optim.Optimizer,
            cfg: LoopConfig) -> tuple[int, list[dict]]:
    """The step to start at and the history so far: from the folder's checkpoint, or 0 and none."""
    restored = load_checkpoint(folder, model, optimizer)
    if restored is None:
        return 0, []
    start, history, _ = restored
    log.info("%s: resuming at step %d of %d", name, start, cfg.iterations)
    return start, history


def _take_step(step: int, cfg: LoopConfig, model: nn.Module, params: list[tuple[str, nn.Parameter]],
               optimizer: torch.optim.Optimizer,
               train_step: Callable[[int], dict[str, float]]) -> tuple[float, dict[str, float]]:
    """One optimiser step at the schedule's rate: the rate used and ``train_step``'s losses."""
    model.train()
    lr = learning_rate(step, cfg)
    for g in optimizer.param_groups:
        g["lr"] = lr * g.get("lr_scale", 1.0)
    optimizer.zero_grad(set_to_none=True)
    distributed.reseed_global(cfg.seed, step)  # several processes: each rank its own noise
    losses = train_step(step)
    # Several processes: the mean gradient over the ranks, so every rank takes the same step.
    # (Not DistributedDataParallel: the stages call methods other than forward() and the
    # sampler keeps a frozen decoder; averaging here serves every stage alike.)
    distributed.average_gradients(p for _, p in params)
    torch.nn.utils.clip_grad_norm_([p for _, p in params], cfg.grad_clip)
    optimizer.step()
    return lr, losses


def _show_losses(running: dict[str, float], losses: dict[str, float], bar: tqdm) -> None:
    """Fold a step's losses into their running means and show the first four on the bar."""
    for k, v in losses.items():
        running[k] = 0.9 * running.get(k, v) + 0.1 * v
    bar.update(1)
    bar.set_postfix({k: f"{v:.4g}" for k, v in list(running.items())[:4]})


def _validate_epoch(name: str, step: int, lr: float, cfg: LoopConfig, model: nn.Module,
                    validate: Callable[[], dict[str, float]], running: dict[str, float],
                    history: list[dict], bar: tqdm) -> None:
    """Validate at an epoch's end, append the entry to ``history`` and write it under the bar."""
    model.eval()
    with torch.no_grad():
        figures = validate()
    entry = {"step": step, "lr": lr, **{f"train_{k}": round(v, 6) for k, v in running.items()},
             **{f"val_{k}": round(v, 6) for k, v in figures.items()}}
    history.append(entry)
    bar.write(f"{name} step {step}/{cfg.iterations}: "
              + ", ".join(f"{k} {v:.4g}" for k, v in entry.items() if k.startswith(("val_", "train_"))))


def _stop_at_time_limit(name: str, folder: Path, model: nn.Module, optimizer: torch.optim.Optimizer,
                        step: int, history: list[dict], cfg: LoopConfig, elapsed: float, main: bool) -> bool:
    """Whether the run stops at its time limit (after rank 0 writes a checkpoint).

    The ranks stop together, when rank 0 reaches the time limit."""
    if not (cfg.time_limit_s and distributed.rank0_decides(elapsed > cfg.time_limit_s and step < cfg.iterations)):
        return False
    if main:
        save_checkpoint(folder, model, optimizer, step, history)
    log.warning("%s: time limit reached at step %d; run again to resume", name, step)
    return True


def train_loop(
    name: str,
    folder: Path,
    model: nn.Module,
    params: list[tuple[str, nn.Parameter]],
    cfg: LoopConfig,
    train_step: Callable[[int], dict[str, float]],
    validate: Callable[[], dict[str, float]],
    progress: bool = True,
    lr_scales: Mapping[str, float] | None = None,
) -> LoopResult:
    """Run (or resume) a stage. ``train_step(step)`` returns its losses after ``loss.backward()``.

    The loop owns zeroing, clipping, the learning-rate schedule and the optimiser step; ``lr_scales``
    (name prefix -> multiplier) gives some parameters a fraction of the schedule's rate.

    Under ``torchrun`` (:mod:`model.train.distributed`) every rank runs this loop on its own batches
    and the gradients are averaged over the ranks before clipping; rank 0 alone validates, writes
    checkpoints and shows the progress bar. In one process the distributed calls do nothing.
    """
    torch.manual_seed(cfg.seed)
    first = next(iter(p for _, p in params), None)
    log.info("%s: training on %s", name, first.device if first is not None else "cpu")
    optimizer = make_optimizer(params, cfg, lr_scales)
    start, history = _resume(name, folder, model, optimizer, cfg)
    distributed.broadcast_state(model)  # every rank starts from rank 0's weights (they agree already)
    main = distributed.is_main()
    began = time.monotonic()
    last_ckpt = began
    result = LoopResult(history=history)
    bar = tqdm(total=cfg.iterations, initial=start, desc=name, disable=not progress or not main, dynamic_ncols=True)
    running: dict[str, float] = {}
    step = start
    try:
        while step < cfg.iterations:
            lr, losses = _take_step(step, cfg, model, params, optimizer, train_step)
            step += 1
            _show_losses(running, losses, bar)
            epoch_end = step % cfg.epoch_iterations == 0 or step == cfg.iterations
            if epoch_end and main:  # rank 0 validates and keeps the history (the others' losses are not in it)
                _validate_epoch(name, step, lr, cfg, model, validate, running, history, bar)
            now = time.monotonic()
            if main and (epoch_end or now - last_ckpt > cfg.checkpoint_every_s):
                save_checkpoint(folder, model, optimizer, step, history)
                last_ckpt = now
            if _stop_at_time_limit(name, folder, model, optimizer, step, history, cfg, now - began, main):
                break
    except KeyboardInterrupt:
        if main:
            save_checkpoint(folder, model, optimizer, step, history)
        bar.close()
        raise
    bar.close()
    result.seconds = time.monotonic() - began
    result.finished = step >= cfg.iterations
    if main:
        (folder / "config.json").write_text(json.dumps(asdict(cfg), indent=1))
    distributed.barrier()  # the others wait until rank 0's files are written
    return result
