"""Style adapters: weights of their own for a style learned after the bundle was trained.

Fine-tuning a new style changes weights every style shares (the FiLM and attention layers, the
recurrent core); measured on test, the other styles fell from 76% to 25-42% of the style judge's
reading (docs/experiments/2026-11-25-unseen-styles.md). An adapter keeps the tuned weights beside
the bundle's own instead of over them: the new style runs on its weights, every other style on the
bundle's weights, unchanged to the bit. A bundle can carry several.

Layout::

    BUNDLE/adapters/NAME/
      adapter.json          format, name, the bundle version it was tuned from, its own version, notes
      weights.safetensors   the sampler tensors fine-tuning changed (as tuned, float32), and no others
      styles/               the style's built-in code, encoded by the adapted weights (format of
                            :mod:`model.inference.bundle_styles`, the adapter's version)

The built-in style ``builtin:NAME`` is the adapter's; a request naming it runs on the adapter's
weights (:class:`model.inference.engine.Engine` keeps one weight set per adapter).
"""

from __future__ import annotations

import copy
import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import torch
from safetensors.torch import load_file, save_file

from model.inference.bundle_styles import BuiltinStyle, StyleFolderError, check_name, load_styles, save_styles
from model.inference.weights_hash import weights_hash
from model.motion.skeleton import Skeleton
from model.nets.sampler import TransitionSampler
from model.nets.transition_net import TransitionNet

N = TypeVar("N", bound=TransitionNet)

ADAPTERS_DIR = "adapters"
ADAPTER_FORMAT = "rsmt-adapter/1"


class AdapterError(ValueError):
    """An adapter folder that cannot be read, or does not fit the bundle it sits in."""


@dataclass(frozen=True, eq=False)
class StyleAdapter:
    """The weights of style ``name``: sampler state-dict entries that replace the bundle's (``tensors``),
    tuned from the bundle whose weights are version ``base_version``."""

    name: str
    tensors: dict[str, torch.Tensor]
    base_version: str
    notes: str = ""

    @property
    def version(self) -> str:
        """The version of the adapted weights (the base's version and the replaced tensors)."""
        return weights_hash(self.tensors, salt=self.base_version)

    @property
    def nbytes(self) -> int:
        return sum(t.numel() * t.element_size() for t in self.tensors.values())

    def apply(self, sampler: N) -> N:
        """A copy of ``sampler`` (the bundle's network) with this adapter's tensors in place, in eval mode, frozen."""
        own = sampler.state_dict()
        unknown = sorted(k for k in self.tensors if k not in own)
        if unknown:
            raise AdapterError(f"adapter {self.name!r}: tensors the model does not have: {', '.join(unknown[:5])}")
        wrong = sorted(k for k, t in self.tensors.items() if t.shape != own[k].shape)
        if wrong:
            raise AdapterError(f"adapter {self.name!r}: tensors of another shape than the model's: {', '.join(wrong[:5])}")
        adapted = copy.deepcopy(sampler)
        adapted.load_state_dict({**own, **self.tensors}, strict=True)
        adapted.eval()
        for p in adapted.parameters():
            p.requires_grad_(False)
        return adapted


def adapter_from(base: TransitionSampler, tuned: TransitionSampler, name: str, base_version: str,
                 notes: str = "", blend: float = 1.0) -> StyleAdapter:
    """The adapter holding every tensor of ``tuned`` that differs from ``base`` (same architecture), moved
    back toward ``base`` by ``blend``: ``blend * tuned + (1 - blend) * base`` (1: the tuned weights as they are)."""
    check_name(name)
    if not 0.0 < blend <= 1.0:
        raise AdapterError(f"adapter {name!r}: blend must be in (0, 1]; got {blend}")
    mine, theirs = base.state_dict(), tuned.state_dict()
    if mine.keys() != theirs.keys():
        raise AdapterError(f"adapter {name!r}: the tuned network is not of the bundle's architecture")
    changed: dict[str, torch.Tensor] = {}
    for k, v in theirs.items():
        old, new = mine[k].detach().cpu(), v.detach().cpu()
        if not torch.equal(new, old):
            mixed = blend * new + (1.0 - blend) * old if new.is_floating_point() and blend < 1.0 else new
            changed[k] = mixed.clone().contiguous()
    if not changed:
        raise AdapterError(f"adapter {name!r}: fine-tuning changed no weight")
    return StyleAdapter(name, changed, base_version, notes)


def save_adapters(bundle: str | Path, adapters: dict[str, StyleAdapter], styles: dict[str, BuiltinStyle],
                  skeleton: Skeleton, fps: float) -> None:
    """Write ``BUNDLE/adapters/`` (replacing any older one): each adapter with its style's code, which must be
    encoded by the adapted weights (``styles[name].version == adapter.version``)."""
    folder = Path(bundle) / ADAPTERS_DIR
    if folder.exists():
        shutil.rmtree(folder)
    for name, adapter in sorted(adapters.items()):
        style = styles.get(name)
        if style is None:
            raise AdapterError(f"adapter {name!r} has no built-in style code: encode it with the adapted weights")
        if style.version != adapter.version:
            raise AdapterError(f"the code of style {name!r} was encoded by model version {style.version}, not by its "
                               f"adapter's weights (version {adapter.version})")
        path = folder / check_name(name)
        path.mkdir(parents=True)
        save_file(adapter.tensors, str(path / "weights.safetensors"),
                  metadata={"format": ADAPTER_FORMAT, "base_version": adapter.base_version})
        meta = {"format": ADAPTER_FORMAT, "name": name, "base_version": adapter.base_version,
                "version": adapter.version, "tensors": len(adapter.tensors), "notes": adapter.notes}
        (path / "adapter.json").write_text(json.dumps(meta, indent=1) + "\n")
        save_styles(path, [style], skeleton, fps, adapter.version)


def load_adapters(bundle: str | Path, skeleton: Skeleton, fps: float,
                  base_version: str) -> tuple[dict[str, StyleAdapter], dict[str, BuiltinStyle]]:
    """The adapters of a bundle whose weights are ``base_version``, and their styles (each marked with its
    adapter in :attr:`BuiltinStyle.weights`); empty when there is no ``adapters/`` folder."""
    folder = Path(bundle) / ADAPTERS_DIR
    adapters: dict[str, StyleAdapter] = {}
    styles: dict[str, BuiltinStyle] = {}
    if not folder.is_dir():
        return adapters, styles
    for path in sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith(".")):
        try:
            meta = json.loads((path / "adapter.json").read_text())
        except FileNotFoundError as exc:
            raise AdapterError(f"{path}: adapter.json is missing") from exc
        except json.JSONDecodeError as exc:
            raise AdapterError(f"{path}/adapter.json is not valid JSON: {exc}") from exc
        if meta.get("format") != ADAPTER_FORMAT:
            raise AdapterError(f"{path}: unsupported adapter format {meta.get('format')!r} (expected {ADAPTER_FORMAT})")
        name = check_name(str(meta.get("name", "")))
        if name != path.name:
            raise AdapterError(f"{path}: the folder holds adapter {name!r}; the folder must carry its name")
        if meta.get("base_version") != base_version:
            raise AdapterError(f"{path}: tuned from model version {meta.get('base_version')}, but this bundle's weights "
                               f"are version {base_version}: fine-tune again from this bundle")
        if not (path / "weights.safetensors").is_file():
            raise AdapterError(f"{path}: weights.safetensors is missing")
        adapter = StyleAdapter(name, load_file(str(path / "weights.safetensors")), base_version, str(meta.get("notes", "")))
        if meta.get("version") != adapter.version:
            raise AdapterError(f"{path}: the weights are not the ones adapter.json names (version {adapter.version}, "
                               f"recorded {meta.get('version')})")
        try:
            own = load_styles(path, skeleton, fps, adapter.version)
        except StyleFolderError as exc:
            raise AdapterError(f"{path}: {exc}") from exc
        if set(own) != {name}:
            raise AdapterError(f"{path}: its styles folder must hold style {name!r} alone (holds {', '.join(own) or 'none'})")
        adapters[name] = adapter
        style = own[name]
        styles[name] = BuiltinStyle(name, style.frames, style.context, style.version, style.source, weights=name)
    return adapters, styles
