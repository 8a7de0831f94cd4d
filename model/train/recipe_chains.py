"""Named training recipes: presets run one after the other on one run folder, then packaged.

A recipe ``recipes/chains/NAME.json`` lists its stages in order, each an ``rsmt train all`` or
``rsmt train sampler`` with a preset (each later preset continues the sampler of the one before
from its checkpoint), and the settings of the ``rsmt package`` step that ends it. Its ``changes``
(settings, as in a preset) apply on top of every stage's preset; a recipe that ``extends`` another
takes that one's stages, package settings and changes, and adds its own. Each stage
writes its bundle to ``RUN/stages/LABEL``. A stage whose bundle is already there is skipped, so a
stopped recipe, run again, goes on where it stopped (a stage cut short resumes from its checkpoint
in the run folder).
"""

from __future__ import annotations

import json
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import torch

from model.train.pipeline import STAGES, TrainConfig, run
from model.train.presets import RECIPE_DIR, base_dict, deep_merge, load_preset, training_differences

CHAIN_DIR = RECIPE_DIR / "chains"
# The train commands a stage may run, and the pipeline stages each trains.
STAGE_COMMANDS: dict[str, tuple[str, ...]] = {"all": STAGES, "sampler": ("sampler",)}


@dataclass(frozen=True)
class ChainStage:
    """One stage of a recipe: ``rsmt train COMMAND --preset PRESET``, its bundle in ``RUN/stages/LABEL``."""

    label: str
    command: str
    preset: str

    def __post_init__(self) -> None:
        if self.command not in STAGE_COMMANDS:
            raise ValueError(f"stage {self.label!r}: command must be one of {', '.join(STAGE_COMMANDS)}, not {self.command!r}")
        if not self.label or Path(self.label).name != self.label or self.label.startswith("."):
            raise ValueError(f"stage label {self.label!r} must be a plain folder name")


# Package settings renamed to their names in the bundle; a chain with the old ones still loads until the next release.
RENAMED_PACKAGE_KEYS = {"steer_facing": "turn_window", "steer_height": "height_window",
                        "retarget_facing": "retarget_turn_window", "retarget_turn_cap": "retarget_max_turn_deg",
                        "steer_cap": "max_step_cm"}


def _renamed_package_keys(recipe: str, package: dict[str, Any]) -> dict[str, Any]:
    old = sorted(k for k in package if k in RENAMED_PACKAGE_KEYS)
    if old:
        warnings.warn(f"recipe {recipe!r}: the package settings {', '.join(old)} are deprecated and go in the next "
                      f"release: use {', '.join(RENAMED_PACKAGE_KEYS[k] for k in old)}", DeprecationWarning, stacklevel=3)
    return {RENAMED_PACKAGE_KEYS.get(k, k): v for k, v in package.items()}


@dataclass(frozen=True)
class PackageSettings:
    """The ``rsmt package`` step that ends a recipe; None keeps the trained bundle's own setting."""

    name: str | None = None
    float16: bool = False
    smoothing: float | None = None
    foot_lock: bool | None = None
    int8_lstm: bool | None = None
    steering: int | None = None
    turn_window: int | None = None  # the parts of steering by their names in the bundle (steering.NAME)
    height_window: int | None = None
    retarget_turn_window: int | None = None
    retarget_max_turn_deg: float | None = None
    floor: bool | None = None
    foot_plant: bool | None = None
    stride_warp: float | None = None
    max_step_cm: float | None = None

    def arguments(self) -> list[str]:
        """These settings as ``rsmt package`` options."""
        args = ["--float16"] if self.float16 else []
        if self.name is not None:
            args += ["--name", self.name]
        if self.smoothing is not None:
            args += ["--smoothing", repr(self.smoothing)]
        for flag, value in (("--foot-lock", self.foot_lock), ("--int8-lstm", self.int8_lstm), ("--floor", self.floor),
                            ("--foot-plant", self.foot_plant)):
            if value is not None:
                args += [flag, "on" if value else "off"]
        for flag, frames in (("--steering", self.steering), ("--turn-window", self.turn_window),
                             ("--height-window", self.height_window),
                             ("--retarget-turn-window", self.retarget_turn_window)):
            if frames is not None:
                args += [flag, str(frames)]
        for flag, amount in (("--retarget-max-turn-deg", self.retarget_max_turn_deg), ("--stride-warp", self.stride_warp),
                             ("--max-step-cm", self.max_step_cm)):
            if amount is not None:
                args += [flag, repr(amount)]
        return args


@dataclass(frozen=True)
class Recipe:
    """A named chain of training stages and the packaging of the last stage's bundle."""

    name: str
    about: str
    stages: tuple[ChainStage, ...]
    package: PackageSettings
    changes: dict[str, Any] = field(default_factory=dict)  # on top of every stage's preset

    @classmethod
    def from_dict(cls, name: str, data: dict[str, Any]) -> Recipe:
        _check_keys("recipe", data, {"about", "stages", "package", "changes"})
        stages = []
        for entry in data.get("stages", []):
            _check_keys("stage", entry, {f.name for f in fields(ChainStage)})
            stages.append(ChainStage(**entry))
        if not stages:
            raise ValueError(f"recipe {name!r} has no stages")
        if stages[0].command != "all":
            raise ValueError(f"recipe {name!r}: the first stage must train every stage (command 'all')")
        labels = [s.label for s in stages]
        if len(set(labels)) != len(labels):
            raise ValueError(f"recipe {name!r}: stage labels must differ, got {labels}")
        package = _renamed_package_keys(name, data.get("package", {}))
        _check_keys("package", package, {f.name for f in fields(PackageSettings)})
        changes = data.get("changes", {})
        if not isinstance(changes, dict):
            raise ValueError(f"recipe {name!r}: changes are a JSON object of settings, got {changes!r}")
        deep_merge(base_dict(), changes, "changes")  # names real settings
        return cls(name, str(data.get("about", "")), tuple(stages), PackageSettings(**package), changes)

    def to_dict(self) -> dict[str, Any]:
        out = {"about": self.about, "stages": [asdict(s) for s in self.stages], "package": asdict(self.package)}
        return out | ({"changes": self.changes} if self.changes else {})

    def stage_config(self, stage: ChainStage) -> TrainConfig:
        """The training config of ``stage``: its preset with the recipe's changes."""
        return load_preset(stage.preset, changes=self.changes)

    def stage_command(self, stage: ChainStage) -> str:
        """What ``stage`` runs, as the command that would run it by hand (and whether the recipe changes it)."""
        changed = " with the recipe's changes" if self.changes else ""
        return f"rsmt train {stage.command} --preset {stage.preset}{changed}"


def _check_keys(what: str, data: Any, known: set[str]) -> None:
    if not isinstance(data, dict):
        raise ValueError(f"a {what} is a JSON object, got {data!r}")
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"unknown {what} setting(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")


def recipe_names(folder: Path = CHAIN_DIR) -> list[str]:
    """The recipes in ``folder``, by name."""
    return sorted(p.stem for p in folder.glob("*.json"))


def _recipe_dict(name: str, folder: Path, seen: tuple[str, ...] = ()) -> dict[str, Any]:
    path = folder / f"{name}.json"
    if not path.is_file():
        raise FileNotFoundError(f"no training recipe {name!r} in {folder}; recipes: {', '.join(recipe_names(folder))}")
    if name in seen:
        raise ValueError(f"recipes extend each other in a circle: {' -> '.join((*seen, name))}")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    if not isinstance(data, dict) or "extends" not in data:
        return data
    own = {k: v for k, v in data.items() if k != "extends"}
    parent = _recipe_dict(str(data["extends"]), folder, (*seen, name))
    return {**parent, **{k: v for k, v in own.items() if k not in ("package", "changes")},
            "package": {**parent.get("package", {}), **own.get("package", {})},
            "changes": deep_merge(parent.get("changes", {}), own.get("changes", {}), new_keys=True)}


def load_recipe(name: str, folder: Path = CHAIN_DIR) -> Recipe:
    """The recipe ``folder/NAME.json`` (with the recipe it extends, if any), checked."""
    data = _recipe_dict(name, folder)
    try:
        return Recipe.from_dict(name, data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{folder / f'{name}.json'}: {exc}") from exc


@dataclass(frozen=True)
class StageReport:
    """What :func:`run_recipe` reports as each stage ends (or is skipped)."""

    index: int  # from 0
    stage: ChainStage
    folder: Path  # the stage's bundle
    seconds: float | None  # wall time; None when the stage was done before and skipped


def stage_folder(run_dir: Path, stage: ChainStage) -> Path:
    return run_dir / "stages" / stage.label


def stage_done(run_dir: Path, stage: ChainStage, cfg: TrainConfig) -> bool:
    """Whether the stage's bundle is in the run folder, complete (its ``train_config.json`` is written last).

    A bundle there trained with other settings than the stage's preset is an error rather than a
    stage to skip or to overwrite.
    """
    saved = stage_folder(run_dir, stage) / "train_config.json"
    if not saved.is_file():
        return False
    differences = training_differences(TrainConfig.load(saved), cfg)
    if differences:
        raise ValueError(f"{saved.parent} holds a bundle trained with other settings than stage {stage.label}'s "
                         f"({', '.join(differences[:4])}{', ...' if len(differences) > 4 else ''}): remove that "
                         "folder or use another run folder")
    return True


def _apply_data_settings(configs: list[TrainConfig], settings: dict[str, str]) -> None:
    for key, value in settings.items():
        if key not in ("profile", "units"):
            raise ValueError(f"a recipe's data setting is profile or units, not {key!r}")
        for cfg in configs:
            setattr(cfg, key, value)


def run_recipe(recipe: Recipe, data_dir: Path, run_dir: Path, threads: int = 0, compile: bool = False,
               device: torch.device | str = "auto", progress: bool = True, command: str | None = None,
               report: Callable[[StageReport], None] | None = None,
               holdout_styles: tuple[str, ...] = (), manifest: Path | None = None,
               data_settings: dict[str, str] | None = None) -> Path | None:
    """Run the recipe's stages in order in ``run_dir``, skipping those whose bundle is there already.

    ``threads`` (when not 0), ``compile`` and ``device`` are the machine's, as for ``rsmt train``.
    ``holdout_styles`` are put aside from every stage's data (and so from its critics): the recipe
    then trains a model that never saw them, the yardstick of unseen styles. ``manifest`` labels the
    takes; ``data_settings`` (``profile``, ``units``) replace those of every stage's preset.
    Every stage's preset is resolved and checked against the run folder before anything trains.
    Returns the last stage's bundle folder, or None when a stage stopped before its end.
    """
    configs = [recipe.stage_config(stage) for stage in recipe.stages]
    if holdout_styles:
        held = tuple(sorted(set(holdout_styles)))
        for cfg in configs:
            cfg.holdout_styles = held
    _apply_data_settings(configs, data_settings or {})
    done = [stage_done(run_dir, stage, cfg) for stage, cfg in zip(recipe.stages, configs)]
    first_missing = done.index(False) if False in done else len(done)
    if any(done[first_missing:]):
        later = ", ".join(s.label for s, d in zip(recipe.stages[first_missing:], done[first_missing:]) if d)
        raise ValueError(f"stage {recipe.stages[first_missing].label} has no bundle in {run_dir} but later stages do "
                         f"({later}): their checkpoint is past its end; use another run folder")
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "recipe.json").write_text(json.dumps({"name": recipe.name, **recipe.to_dict()}, indent=1))
    for i, (stage, cfg) in enumerate(zip(recipe.stages, configs)):
        folder = stage_folder(run_dir, stage)
        if done[i]:
            if report:
                report(StageReport(i, stage, folder, None))
            continue
        if threads:
            cfg.threads = threads
        began = time.monotonic()
        what = f"stage {stage.label}: {recipe.stage_command(stage)}"
        bundle = run(cfg, data_dir, run_dir, STAGE_COMMANDS[stage.command], folder, progress=progress,
                     command=f"{command or f'rsmt train recipe {recipe.name}'} ({what})", device=device, compile=compile,
                     manifest=manifest)
        if bundle is None:
            return None
        if report:
            report(StageReport(i, stage, folder, time.monotonic() - began))
    return stage_folder(run_dir, recipe.stages[-1])
