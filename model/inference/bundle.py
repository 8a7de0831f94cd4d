"""Model bundles: a directory holding everything a trained model needs, and nothing executable.

Layout::

    BUNDLE/
      config.json          every network config, the format version, fps, data, licence, eval figures
      weights.safetensors  the weights and normalisation statistics (no pickle anywhere)
      skeleton.json        the rig the model was trained on
      README.md            the model card (optional for loading)
      styles/              built-in style codes, served as ``builtin:NAME`` (optional; :mod:`model.inference.bundle_styles`)

A bundle loads from its own files alone; loading is strict (missing or unexpected tensors fail).
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

from model.inference.bundle_styles import BuiltinStyle, StyleFolderError, load_styles, save_styles
from model.inference.output_settings import OutputConfig
from model.inference.settings import InferenceConfig
from model.motion.skeleton import Skeleton
from model.nets.manifold import ManifoldConfig, ManifoldDecoder
from model.nets.phase import PeriodicAutoencoder, PhaseConfig
from model.nets.sampler import SamplerConfig, TransitionSampler

FORMAT = "rsmt-bundle/1"
log = logging.getLogger(__name__)
DEFAULT_BUNDLE = Path(__file__).resolve().parent.parent / "default_bundle"


class BundleError(ValueError):
    """A bundle that is missing, incomplete or inconsistent."""


@dataclass
class BundleMeta:
    """Descriptive fields saved in ``config.json``."""

    name: str = "rsmt"
    training_data: str = "synthetic (untrained)"
    license: str = "CC BY-NC 4.0 (inherits the training data's licence)"
    training_command: str = ""
    training_time_s: dict[str, float] = field(default_factory=dict)
    evaluation: dict[str, Any] = field(default_factory=dict)
    notes: str = ""


@dataclass
class Bundle:
    """A loaded model: skeleton, sampler (with its manifold decoder), optional phase model."""

    skeleton: Skeleton
    sampler: TransitionSampler
    manifold_config: ManifoldConfig
    phase_config: PhaseConfig
    phase_model: PeriodicAutoencoder | None = None
    meta: BundleMeta = field(default_factory=BundleMeta)
    version: str = "unsaved"
    output: OutputConfig = field(default_factory=OutputConfig)  # the engine's post-processing of frames
    inference: InferenceConfig = field(default_factory=InferenceConfig)  # how the engine runs the network
    styles: dict[str, BuiltinStyle] = field(default_factory=dict)  # built-in style codes by name (styles/)

    @property
    def config(self) -> SamplerConfig:
        return self.sampler.config

    @classmethod
    def create(
        cls,
        skeleton: Skeleton,
        sampler: SamplerConfig | None = None,
        manifold: ManifoldConfig | None = None,
        phase: PhaseConfig | None = None,
        meta: BundleMeta | None = None,
        seed: int = 0,
    ) -> Bundle:
        """A bundle with freshly initialised (random) weights sized for ``skeleton``."""
        j = skeleton.num_joints
        torch.manual_seed(seed)
        sampler = sampler or SamplerConfig(joints=j)
        manifold = manifold or ManifoldConfig(joints=j, phases=sampler.phases, latent=sampler.latent, root=skeleton.roles.root)
        phase = phase or PhaseConfig(channels=j * 3, phases=sampler.phases, fps=sampler.fps)
        if not (sampler.joints == manifold.joints == j and sampler.phases == manifold.phases == phase.phases):
            raise BundleError("sampler, manifold and phase configs disagree on joints or phase channels")
        net = TransitionSampler(sampler, ManifoldDecoder(manifold))
        return cls(skeleton, net, manifold, phase, PeriodicAutoencoder(phase), meta or BundleMeta())

    def tensors(self) -> dict[str, torch.Tensor]:
        # Always CPU tensors: the file and the weights hash must not depend on where the model sits.
        out = {f"sampler.{k}": v.detach().cpu().contiguous() for k, v in self.sampler.state_dict().items()}
        if self.phase_model is not None:
            out.update({f"phase.{k}": v.detach().cpu().contiguous() for k, v in self.phase_model.state_dict().items()})
        return out

    def save(self, path: str | Path, weights_dtype: str = "float32") -> Path:
        """Write the bundle directory; returns it. The version is a hash of the weights.

        ``weights_dtype="float16"`` halves the file (the shipped default model stays a few MB);
        weights are widened back to float32 on load, so only their rounding changes: evaluate the
        saved bundle, not the one in memory.
        """
        if weights_dtype not in ("float32", "float16"):
            raise BundleError(f"weights_dtype must be float32 or float16, not {weights_dtype!r}")
        path = Path(path)
        path.mkdir(parents=True, exist_ok=True)
        weights = path / "weights.safetensors"
        tensors = self.tensors()
        if weights_dtype == "float16":
            tensors = {k: v.half() if v.is_floating_point() else v for k, v in tensors.items()}
        save_file(tensors, str(weights), metadata={"format": FORMAT, "weights_dtype": weights_dtype})
        self.version = _weights_hash(tensors)
        config = {
            "format": FORMAT,
            "version": self.version,
            "fps": self.config.fps,
            "sampler": self.config.to_dict(),
            "manifold": self.manifold_config.to_dict(),
            "phase": self.phase_config.to_dict(),
            "has_phase_model": self.phase_model is not None,
            "output": self.output.to_dict(),
            "inference": self.inference.to_dict(),
            "meta": self.meta.__dict__,
        }
        (path / "config.json").write_text(json.dumps(config, indent=1))
        self.skeleton.save(path / "skeleton.json")
        stale = sorted(n for n, s in self.styles.items() if s.version != self.version)
        if self.styles and not stale:
            save_styles(path, self.styles.values(), self.skeleton, self.config.fps, self.version)
        elif stale:  # codes belong to the weights that made them (fine-tuned, averaged or float16 weights: others)
            log.warning("%s: built-in styles %s were encoded by model version %s, not by these weights (%s); they are "
                        "not saved: re-encode them with `rsmt bundle add-styles %s --from DIR` (or --from-data DATA)",
                        path, ", ".join(stale), self.styles[stale[0]].version, self.version, path)
        return path

    @classmethod
    def load(cls, path: str | Path, styles: bool = True) -> Bundle:
        """Load strictly; any missing file, tensor or field is a :class:`BundleError`.

        ``styles=False`` leaves the ``styles/`` folder unread (``bundle.styles`` empty): for the commands
        that rewrite it, which must work on a folder that no longer loads (old format, other weights)."""
        path = Path(path)
        for name in ("config.json", "weights.safetensors", "skeleton.json"):
            if not (path / name).is_file():
                raise BundleError(f"{path} is not a model bundle: {name} is missing")
        try:
            config = json.loads((path / "config.json").read_text())
        except json.JSONDecodeError as exc:
            raise BundleError(f"{path}/config.json is not valid JSON: {exc}") from exc
        if config.get("format") != FORMAT:
            raise BundleError(f"{path}: unsupported bundle format {config.get('format')!r} (expected {FORMAT})")
        skeleton = Skeleton.load(path / "skeleton.json")
        bundle = cls.create(
            skeleton,
            SamplerConfig.from_dict(config["sampler"]),
            ManifoldConfig(**config["manifold"]),
            PhaseConfig(**config["phase"]),
            BundleMeta(**config.get("meta", {})),
        )
        try:
            bundle.output = OutputConfig.from_dict(config.get("output", {}))
        except (TypeError, ValueError) as exc:
            raise BundleError(f"{path}/config.json: bad output settings: {exc}") from exc
        try:
            bundle.inference = InferenceConfig.from_dict(config.get("inference", {}))
        except (TypeError, ValueError) as exc:
            raise BundleError(f"{path}/config.json: bad inference settings: {exc}") from exc
        if not config.get("has_phase_model", True):
            bundle.phase_model = None
        tensors = load_file(str(path / "weights.safetensors"))
        sampler_sd = {k[len("sampler."):]: v for k, v in tensors.items() if k.startswith("sampler.")}
        phase_sd = {k[len("phase."):]: v for k, v in tensors.items() if k.startswith("phase.")}
        try:
            bundle.sampler.load_state_dict(sampler_sd, strict=True)
            if bundle.phase_model is not None:
                bundle.phase_model.load_state_dict(phase_sd, strict=True)
        except RuntimeError as exc:
            raise BundleError(f"{path}: weights do not match the config: {exc}") from exc
        bundle.version = config.get("version") or _weights_hash(tensors)
        try:
            bundle.styles = load_styles(path, skeleton, bundle.config.fps, bundle.version) if styles else {}
        except StyleFolderError as exc:
            raise BundleError(f"{path}: bad built-in styles: {exc}") from exc
        bundle.sampler.eval()
        if bundle.phase_model is not None:
            bundle.phase_model.eval()
        return bundle


def _weights_hash(tensors: dict[str, torch.Tensor]) -> str:
    """A hash of the stored tensors (names, dtypes, shapes, bytes), not of the file: safetensors
    writes its metadata in no fixed order, so the same weights saved twice differ as files."""
    digest = hashlib.sha256()
    for name in sorted(tensors):
        t = tensors[name].contiguous().reshape(-1)  # 0-d tensors (BatchNorm counters) cannot be viewed as bytes
        digest.update(f"{name}:{t.dtype}:{tuple(t.shape)}".encode())
        digest.update(t.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return digest.hexdigest()[:16]
