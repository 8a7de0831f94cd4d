"""Training presets: one complete base config, and per preset only the settings it changes.

``recipes/base.json`` holds every setting of :class:`model.train.pipeline.TrainConfig`. A preset
``recipes/NAME.json`` holds the keys it changes, nested as in the base (``{"sampler_stage":
{"loop": {"iterations": 18000}}}``), and an ``about`` that says what it is for. Loading a preset
merges it into the base: objects key by key, anything else (numbers, strings, lists, null)
replaced whole. A preset may change another preset instead of the base by naming it in
``"extends"``. A key the base does not have is an error, so a misspelt setting cannot pass
unnoticed.

The presets a recipe chain runs (``recipes/chains/``) and the ``default`` of ``rsmt train`` live in
``recipes/``; the trials no chain runs (stages tried and not shipped, paper-size networks, the
held-out-style experiment) in ``recipes/experiments/``. Both load by name.
"""

from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path
from typing import Any

from model.train.pipeline import TrainConfig, fit_to_skeleton

RECIPE_DIR = Path(__file__).resolve().parent / "recipes"
BASE = "base"
EXTENDS = "extends"  # the preset a preset changes (default: the base)
EXPERIMENTS = "experiments"  # the subfolder of the presets no recipe chain runs


def deep_merge(base: dict[str, Any], changes: dict[str, Any], where: str = "", new_keys: bool = False) -> dict[str, Any]:
    """A copy of ``base`` with ``changes`` applied: nested objects are merged key by key, other values replaced.

    Raises ValueError naming the key (dotted, after ``where``) when ``changes`` has a key ``base``
    lacks (unless ``new_keys``: two sets of changes merged), or gives an object where ``base`` has a
    plain value or the other way round.
    """
    merged = copy.deepcopy(base)
    for key, value in changes.items():
        path = f"{where}.{key}" if where else key
        if key not in base:
            if not new_keys:
                raise ValueError(f"unknown setting {path!r}: the base config has no such key")
            merged[key] = copy.deepcopy(value)
            continue
        if isinstance(base[key], dict) != isinstance(value, dict):
            kind = "an object of settings" if isinstance(base[key], dict) else "a single value"
            raise ValueError(f"setting {path!r} must be {kind}, as in the base config")
        merged[key] = deep_merge(base[key], value, path, new_keys) if isinstance(value, dict) else copy.deepcopy(value)
    return merged


def _read(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a preset is a JSON object")
    return data


def preset_names(folder: Path = RECIPE_DIR) -> list[str]:
    """The presets in ``folder`` and its ``experiments`` subfolder, by name (the base is not one)."""
    files = [*folder.glob("*.json"), *(folder / EXPERIMENTS).glob("*.json")]
    return sorted(p.stem for p in files if p.stem != BASE)


def preset_path(name: str, folder: Path = RECIPE_DIR) -> Path:
    """The file of the preset ``name``: in ``folder``, else in its ``experiments`` subfolder."""
    for path in (folder / f"{name}.json", folder / EXPERIMENTS / f"{name}.json"):
        if name != BASE and path.is_file():
            return path
    raise FileNotFoundError(f"no training preset {name!r} in {folder}; presets: {', '.join(preset_names(folder))}")


def preset_changes(name: str, folder: Path = RECIPE_DIR) -> dict[str, Any]:
    """The preset file's own content: the settings it changes, its ``about`` and maybe ``extends``."""
    return _read(preset_path(name, folder))


def preset_dict(name: str, folder: Path = RECIPE_DIR, _seen: tuple[str, ...] = ()) -> dict[str, Any]:
    """The complete config of a preset as a JSON object: the base (or the preset it extends) with its changes."""
    if name in _seen:
        raise ValueError(f"presets extend each other in a circle: {' -> '.join((*_seen, name))}")
    changes = preset_changes(name, folder)
    parent = changes.pop(EXTENDS, None)
    start = base_dict(folder) if parent is None else preset_dict(parent, folder, (*_seen, name))
    try:
        return deep_merge(start, changes)
    except ValueError as exc:
        raise ValueError(f"{preset_path(name, folder)}: {exc}") from exc


def base_dict(folder: Path = RECIPE_DIR) -> dict[str, Any]:
    """The base config every preset changes, as a JSON object."""
    return _read(folder / f"{BASE}.json")


def load_preset(name: str, folder: Path = RECIPE_DIR, changes: dict[str, Any] | None = None) -> TrainConfig:
    """The typed training config of a preset, with ``changes`` (settings, as in a preset) on top."""
    try:
        return TrainConfig.from_dict(deep_merge(preset_dict(name, folder), changes or {}))
    except TypeError as exc:
        raise ValueError(f"preset {name!r}: not a valid training config: {exc}") from exc


def training_differences(stored: TrainConfig, wanted: TrainConfig) -> list[str]:
    """The settings, dotted, in which a run's saved config ``stored`` trains differently from ``wanted``.

    Left out: ``about``, ``threads`` (a property of the machine, set by ``--threads``) and the
    sizes the run fits to its rig (joints, root, phase channels: :func:`fit_to_skeleton`), which
    ``wanted`` takes from ``stored``.
    """
    fitted = fit_to_skeleton(copy.deepcopy(wanted), stored.sampler.joints, stored.sampler.root)
    a, b = _flat(dataclasses.asdict(stored)), _flat(dataclasses.asdict(fitted))
    return [k for k in sorted(a.keys() | b.keys()) if k not in ("about", "threads") and a.get(k) != b.get(k)]


def _flat(data: dict[str, Any], where: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in data.items():
        path = f"{where}.{key}" if where else key
        out.update(_flat(value, path) if isinstance(value, dict) else {path: value})
    return out
