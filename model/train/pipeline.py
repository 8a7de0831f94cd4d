"""The whole recipe: data → phase model → labels → manifold → sampler → bundle, stage by stage.

Each stage writes its weights into the run folder, so ``rsmt train manifold`` can follow an earlier
``rsmt train phase``, and ``rsmt train all`` resumes wherever a previous run stopped.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import logging
import os
import sys
import time
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import torch
from safetensors.torch import load_file, save_file

from model.data.preprocessed import MotionCache, load_motion_cache
from model.data.splits import Split
from model.inference.bundle import Bundle, BundleMeta
from model.nets.manifold import ManifoldConfig, MotionManifold
from model.nets.phase import PeriodicAutoencoder, PhaseConfig
from model.nets.sampler import SamplerConfig, TransitionSampler
from model.nets.style_classifier import StyleClassifier, StyleClassifierConfig
from model.train import distributed
from model.train.classifier_stage import TrainSettings, build_windows, train_classifier
from model.train.empty_split import empty_split_message
from model.train.loop import resolve_device
from model.train.manifold_stage import ManifoldStageConfig, train_manifold
from model.train.motion_tensors import MotionTensors, mean_skeleton
from model.train.phase_stage import PhaseStageConfig, label_tensors, phase_summary, train_phase
from model.train.sampler_config import SamplerStageConfig
from model.train.sampler_stage import train_sampler
from model.train.velocity_flag import widen_checkpoint

log = logging.getLogger(__name__)
T = TypeVar("T")
STAGES = ("phase", "manifold", "sampler")


# A run's defaults are the default preset's, every value of recipes/base.json: its sections (networks of the
# compact size, the sampler schedule the shipped model's recipe builds on, every stage's settings) are read from
# there, their one place; the run's plain settings below are held equal to it by tests/model/train/test_presets.py.
# The stage and network classes keep their own defaults (the paper-size sampler, every extra loss off) for what
# builds them alone.
BASE_CONFIG = Path(__file__).resolve().parent / "recipes" / "base.json"


@functools.lru_cache(maxsize=1)
def _base_config() -> dict[str, Any]:
    return json.loads(BASE_CONFIG.read_text())


def _from_base(section: str, cls: type[T]) -> Callable[[], T]:
    """The default factory of a section of :class:`TrainConfig`: that section of recipes/base.json."""
    return lambda: _from_dict(cls, copy.deepcopy(_base_config()[section]))


@dataclass
class TrainConfig:
    """Everything a training run depends on; saved beside every stage's weights."""

    name: str = "rsmt-default"
    about: str = ""
    seed: int = 0
    fps: float = 30.0
    profile: str | None = None
    units: str = "auto"  # the takes' units: auto (read from the height), cm, m, mm, inch or cm per unit
    ratios: tuple[float, float, float] = (0.8, 0.1, 0.1)
    holdout_styles: tuple[str, ...] = ()
    augment: bool = True
    threads: int = 1  # torch threads (0: torch's choice); --threads sets it for the machine at hand
    sampler: SamplerConfig = field(default_factory=_from_base("sampler", SamplerConfig))
    manifold: ManifoldConfig = field(default_factory=_from_base("manifold", ManifoldConfig))
    phase: PhaseConfig = field(default_factory=_from_base("phase", PhaseConfig))
    phase_stage: PhaseStageConfig = field(default_factory=_from_base("phase_stage", PhaseStageConfig))
    manifold_stage: ManifoldStageConfig = field(default_factory=_from_base("manifold_stage", ManifoldStageConfig))
    sampler_stage: SamplerStageConfig = field(default_factory=_from_base("sampler_stage", SamplerStageConfig))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        return _from_dict(cls, data)

    @classmethod
    def load(cls, path: str | Path) -> TrainConfig:
        try:
            return cls.from_dict(json.loads(Path(path).read_text()))
        except (json.JSONDecodeError, TypeError) as exc:
            raise ValueError(f"{path}: not a valid training config: {exc}") from exc


def _from_dict(cls: type, data: dict[str, Any]) -> Any:
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - known
    if unknown:
        raise TypeError(f"unknown field(s) for {cls.__name__}: {', '.join(sorted(unknown))}")
    kwargs = {}
    for name, value in data.items():
        hint = hints[name]
        if isinstance(hint, type) and dataclasses.is_dataclass(hint) and isinstance(value, dict):
            kwargs[name] = _from_dict(hint, value)
        elif isinstance(value, list):
            kwargs[name] = tuple(value)
        else:
            kwargs[name] = value
    return cls(**kwargs)


def fit_to_skeleton(cfg: TrainConfig, joints: int, root: int) -> TrainConfig:
    """Make the three model configs agree with the rig and with each other."""
    cfg.sampler.joints = cfg.manifold.joints = joints
    cfg.manifold.root = cfg.sampler.root = root
    cfg.manifold.phases = cfg.phase.phases = cfg.sampler.phases
    cfg.manifold.latent = cfg.sampler.latent
    cfg.phase.channels = joints * 3
    cfg.phase.fps = cfg.sampler.fps = cfg.fps
    return cfg


@dataclass
class PreparedData:
    cache: MotionCache
    train: MotionTensors
    val: MotionTensors
    data_dir: Path
    split: Split


def prepare_data(cfg: TrainConfig, data_dir: Path, progress: bool = True, manifest: Path | None = None) -> PreparedData:
    cache = load_motion_cache(data_dir, fps=cfg.fps, profile=cfg.profile, manifest=manifest, progress=progress,
                              units=cfg.units)
    split = cache.make_split(cfg.ratios, cfg.holdout_styles)
    if not split.train or not split.val:
        raise ValueError(empty_split_message(cache, split, data_dir, manifest))
    skeleton = mean_skeleton(cache, split.train)
    train = MotionTensors.from_cache(cache, split.train, skeleton, augment=cfg.augment, seed=cfg.seed, progress=progress)
    val = MotionTensors.from_cache(cache, split.val, skeleton, augment=False, progress=progress)
    fit_to_skeleton(cfg, skeleton.num_joints, skeleton.roles.root)
    return PreparedData(cache, train, val, data_dir, split)


def style_critics(cfg: TrainConfig, data: PreparedData, run_dir: Path,
                  progress: bool = True) -> tuple[list[StyleClassifier], float | None]:
    """The frozen style classifiers behind the sampler's style loss, one per ``critic_inputs`` entry,
    each trained once per run (about a minute) and kept in the run folder.

    Returns the critics and the seconds spent training them (None when all were reloaded). The
    first lives in ``critic/`` (where runs with a single critic keep it), the others in
    ``critic-<inputs>/``.

    They learn from the run's training split only, each with its own seed; the evaluation
    classifier (``rsmt train classifier``) is a separate network, so a sampler cannot be tuned to
    the very network that scores it (though a critic may read the same inputs as the evaluation
    classifier, as the default model's acceleration critic does: docs/experiments/2026-11-evaluation-history.md).
    """
    stage = cfg.sampler_stage
    styles = [s for s in data.cache.styles if s not in cfg.holdout_styles]
    critics, seconds = [], None
    windows = None  # built once, for the first critic that has to be trained
    for i, inputs in enumerate(stage.critic_inputs):
        folder = run_dir / ("critic" if i == 0 else f"critic-{inputs}")
        config = StyleClassifierConfig(styles=styles, joints=data.train.skeleton.num_joints, inputs=inputs)
        if (folder / "weights.safetensors").is_file():
            critic = StyleClassifier.load(folder)
            if critic.config.to_dict() == config.to_dict():
                critics.append(critic)
                continue
            log.info("style critic in %s has another config; training a new one", folder)
        began = time.monotonic()
        settings = TrainSettings(epochs=stage.critic_epochs, iterations=stage.critic_iterations, seed=cfg.seed + 1 + i)
        if windows is None:
            windows = (build_windows(data.cache, data.split.train, config.window, settings.step, settings.mirror, styles,
                                     progress, "critic windows"),
                       build_windows(data.cache, data.split.val, config.window, settings.eval_step, False, styles,
                                     progress, "critic val windows"))
        result = train_classifier(*windows, config, settings, progress, report=log.info)
        result.model.save(folder, {"role": "style critic of the sampler's style loss", "best_epoch": result.best_epoch,
                                   "history": result.history, "seconds": round(result.seconds, 1)})
        critics.append(result.model)
        seconds = (seconds or 0.0) + time.monotonic() - began
    return critics, seconds


def save_stage_weights(module: torch.nn.Module, folder: Path, config: dict) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    # CPU tensors whatever the device trained on, so the weights load anywhere.
    save_file({k: v.detach().cpu().contiguous() for k, v in module.state_dict().items()}, str(folder / "weights.safetensors"))
    (folder / "config.json").write_text(json.dumps(config, indent=1))


def load_stage_weights(module: torch.nn.Module, folder: Path, stage: str) -> None:
    path = folder / "weights.safetensors"
    if not path.is_file():
        raise FileNotFoundError(f"stage {stage!r} has no weights in {folder}: train it first (rsmt train {stage})")
    module.load_state_dict(load_file(str(path)), strict=True)  # copied onto the module's device


def _labels(pae: PeriodicAutoencoder, tensors: MotionTensors, path: Path, progress: bool,
            device: torch.device | None = None) -> None:
    """Phase labels for every frame, reused from ``path`` when made by the same weights on the same frames.

    The key's sums are taken where the tensors are, so labels made on another device may not match
    it (sums in another order) and are then made again; the file always holds CPU tensors.
    """
    weights = torch.cat([p.detach().flatten() for p in pae.state_dict().values() if p.is_floating_point()])
    key = (f"{weights.double().sum().item():.12e}:{weights.numel()}:{len(tensors.positions)}:"
           f"{tensors.positions.double().sum().item():.9e}")
    if path.is_file():
        stored = load_file(str(path))
        if bytes(stored["key"].tolist()).decode() == key:
            where = tensors.positions.device
            tensors.phase, tensors.amplitude, tensors.frequency = (stored["phase"].to(where), stored["amplitude"].to(where),
                                                                   stored["frequency"].to(where))
            return
    label_tensors(pae, tensors, progress, device=device)
    assert tensors.phase is not None and tensors.amplitude is not None and tensors.frequency is not None
    if not distributed.is_main():  # under torchrun every rank labels its copy; rank 0 writes the file
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")  # then renamed: another rank may be reading the file
    save_file({"phase": tensors.phase.cpu(), "amplitude": tensors.amplitude.cpu(), "frequency": tensors.frequency.cpu(),
               "key": torch.tensor(list(key.encode()), dtype=torch.uint8)}, str(tmp))
    os.replace(tmp, path)


def _phase_model(cfg: TrainConfig, data: PreparedData, run_dir: Path, train: bool, timings: dict[str, float],
                 progress: bool, dev: torch.device) -> PeriodicAutoencoder | None:
    """The phase autoencoder, trained now (``train``) or loaded from the run folder, in eval mode; None when its
    training stopped before the end (time limit)."""
    pae = PeriodicAutoencoder(cfg.phase)
    if train:
        t0 = time.monotonic()
        pae, result = train_phase(data.train, data.val, cfg.phase, cfg.phase_stage, run_dir / "phase", progress, dev)
        if not result.finished:
            return None
        if distributed.is_main():
            save_stage_weights(pae, run_dir / "phase", cfg.phase.to_dict())
        timings["phase_s"] = round(time.monotonic() - t0, 1)
    else:
        load_stage_weights(pae, run_dir / "phase", "phase")
        pae.to(dev)
    return pae.eval()


def _manifold(cfg: TrainConfig, data: PreparedData, run_dir: Path, stages: tuple[str, ...], timings: dict[str, float],
              progress: bool, dev: torch.device) -> MotionManifold | None:
    """The motion manifold: trained now, loaded from the run folder when the sampler needs it, or fresh when
    nothing does; None when its training stopped before the end."""
    manifold = MotionManifold(cfg.manifold)
    if "manifold" in stages:
        t0 = time.monotonic()
        manifold, result = train_manifold(data.train, data.val, cfg.manifold, cfg.manifold_stage, run_dir / "manifold",
                                          progress, dev)
        if not result.finished:
            return None
        if distributed.is_main():
            save_stage_weights(manifold.decoder, run_dir / "manifold", cfg.manifold.to_dict())
        timings["manifold_s"] = round(time.monotonic() - t0, 1)
    elif "sampler" in stages:
        load_stage_weights(manifold.decoder, run_dir / "manifold", "manifold")
        manifold.to(dev)
    return manifold


def _sampler(cfg: TrainConfig, data: PreparedData, run_dir: Path, manifold: MotionManifold, timings: dict[str, float],
             progress: bool, dev: torch.device, compile: bool) -> TransitionSampler | None:
    """The sampler trained (or resumed) on the frozen manifold, with its style critics when the style loss is on;
    None when its training stopped before the end."""
    critics: list[StyleClassifier] = []
    if cfg.sampler_stage.w_style > 0:
        with distributed.main_first():  # under torchrun rank 0 trains them; the others load them
            critics, seconds = style_critics(cfg, data, run_dir, progress and distributed.is_main())
        if seconds is not None:  # trained now, not reloaded from the run folder
            timings["critic_s"] = round(seconds, 1)
    t0 = time.monotonic()
    torch.manual_seed(cfg.sampler_stage.loop.seed)  # the initial weights, in any process
    sampler = TransitionSampler(cfg.sampler, manifold.decoder)
    with distributed.main_first():  # a checkpoint of an earlier stage without the target-velocity flag grows it
        if distributed.is_main() and widen_checkpoint(run_dir / "sampler", sampler):
            log.info("sampler checkpoint in %s grown to read the target-velocity flag", run_dir / "sampler")
    sampler, result = train_sampler(data.train, data.val, sampler, cfg.sampler_stage, run_dir / "sampler", progress, dev,
                                    critics, compile=compile)
    if not result.finished:
        return None
    timings["sampler_s"] = round(time.monotonic() - t0, 1)
    return sampler


def _save_config(cfg: TrainConfig, run_dir: Path) -> None:
    """``RUN/train_config.json`` (under torchrun, by rank 0 only)."""
    if distributed.is_main():
        (run_dir / "train_config.json").write_text(json.dumps(cfg.to_dict(), indent=1))


def run(cfg: TrainConfig, data_dir: Path, run_dir: Path, stages: tuple[str, ...], out: Path | None,
        progress: bool = True, command: str | None = None, device: torch.device | str = "auto",
        compile: bool = False, manifest: Path | None = None) -> Bundle | None:
    """Run the given stages (in recipe order) and write the bundle when the sampler is done.

    ``device`` (``auto``: CUDA when there is a GPU, else the CPU) is where the networks train and
    the motion tensors live. It is a property of the machine, not of the recipe, so it is not part
    of ``cfg`` or of the saved ``train_config.json``: a run can resume on another device. Random
    draws stay on the CPU's generators, so the CPU path's numbers do not depend on this option.
    ``compile`` (also not part of the recipe) trains the sampler's per-frame functions through
    ``torch.compile`` (:mod:`model.train.step_compiler`). Returns None when a stage stopped before
    its end (time limit). ``manifest`` labels the takes of ``data_dir`` (a CSV, see
    :mod:`model.data.takes`). The run folder's ``train_config.json`` is written before the data
    are read, so a run that fails on them still leaves its settings there.
    """
    dev = resolve_device(device)
    log.info("training on %s", dev)
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    run_dir.mkdir(parents=True, exist_ok=True)
    timings_path = run_dir / "timings.json"
    timings: dict[str, float] = json.loads(timings_path.read_text()) if timings_path.is_file() else {}
    began = time.monotonic()
    _save_config(cfg, run_dir)  # rewritten below once fitted to the rig
    with distributed.main_first():  # under torchrun rank 0 builds the data cache; the others read it
        data = prepare_data(cfg, data_dir, progress and distributed.is_main(), manifest)
    # Data are read and augmented on the CPU, then held where the networks train.
    data.train, data.val = data.train.to(dev), data.val.to(dev)
    timings["data_s"] = round(time.monotonic() - began, 1)
    if distributed.world_size() > 1:  # under torchrun: how many processes trained (absent for one)
        timings["processes"] = distributed.world_size()
    else:
        timings.pop("processes", None)
    main = distributed.is_main()  # under torchrun only rank 0 writes files; in one process, this one
    _save_config(cfg, run_dir)
    if main:
        data.train.skeleton.save(run_dir / "skeleton.json")

    pae = _phase_model(cfg, data, run_dir, "phase" in stages, timings, progress, dev)
    if pae is None:
        return None
    t0 = time.monotonic()
    for part, tensors in (("train", data.train), ("val", data.val)):
        _labels(pae, tensors, run_dir / "phase" / f"labels_{part}.safetensors", progress and main, dev)
    timings["labels_s"] = round(time.monotonic() - t0, 1)
    if main:
        (run_dir / "phase_summary.json").write_text(json.dumps(phase_summary(data.train), indent=1))

    manifold = _manifold(cfg, data, run_dir, stages, timings, progress, dev)
    if manifold is None:
        return None
    bundle = None
    if "sampler" in stages:
        sampler = _sampler(cfg, data, run_dir, manifold, timings, progress, dev, compile)
        if sampler is None:
            return None
        meta = BundleMeta(
            name=cfg.name,
            training_data=f"{data_dir.name}: {len(data.cache.takes)} takes, styles {', '.join(data.cache.styles)}; "
                          f"train split {data.train.num_takes} takes incl. augmentation",
            training_command=command or " ".join(sys.argv),
            training_time_s=timings,
        )
        # A bundle is CPU tensors, as Bundle.load makes it: saved weights load anywhere, and the
        # returned bundle is ready for the CPU engine.
        sampler.cpu()
        pae.cpu()
        bundle = Bundle(data.train.skeleton, sampler, cfg.manifold, cfg.phase, pae, meta)
        if out is not None and main:
            bundle.save(out)
            (out / "train_config.json").write_text(json.dumps(cfg.to_dict(), indent=1))
    if main:
        timings_path.write_text(json.dumps(timings, indent=1))
    distributed.barrier()  # the others return when the bundle is written
    return bundle
