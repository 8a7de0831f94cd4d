"""Model bundles: a directory holding everything a trained model needs, and nothing executable.

Layout::

    BUNDLE/
      config.json          every network config, the format version, fps, data, licence, eval figures
      weights.safetensors  the weights and normalisation statistics (no pickle anywhere)
      skeleton.json        the rig the model was trained on
      README.md            the model card (optional for loading)
      gait_limits.json     the capture's speed and hips height limits per built-in style (optional;
                           :mod:`model.motion.gait_limits`): the engine keeps the root within them
      styles/              built-in style codes, served as ``builtin:NAME`` (optional; :mod:`model.inference.bundle_styles`)
      adapters/NAME/       weights of their own for a style fine-tuned later (optional; :mod:`model.inference.bundle_adapters`)
      database.safetensors the compressed poses of real locomotion for motion matching, and database.json (optional;
                           :mod:`model.retrieval.database`, written by ``rsmt bundle database``)

A bundle loads from its own files alone; loading is strict (missing or unexpected tensors fail).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

from model.inference.bundle_adapters import AdapterError, StyleAdapter, load_adapters, save_adapters
from model.inference.bundle_styles import BuiltinStyle, StyleFolderError, load_styles, save_styles
from model.inference.output.settings import OutputConfig
from model.inference.settings import InferenceConfig
from model.inference.weights_hash import weights_hash
from model.motion.gait_limits import GaitLimits
from model.motion.skeleton import Skeleton
from model.nets.manifold import ManifoldConfig, ManifoldDecoder
from model.nets.phase import PeriodicAutoencoder, PhaseConfig
from model.nets.sampler import SamplerConfig, TransitionSampler
from model.nets.transition_net import DEFAULT_NETWORK, TransitionNet, build_network
from model.retrieval.database import DatabaseError, MotionDatabase

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
    """A loaded model: skeleton, transition network (with its manifold decoder), optional phase model.

    ``net`` is any network of :data:`model.nets.transition_net.NETWORKS` (``network`` names which; the RSMT
    sampler by default); :attr:`sampler` is the same network where code needs the RSMT sampler's own parts
    (training, fine-tuning)."""

    skeleton: Skeleton
    net: TransitionNet
    manifold_config: ManifoldConfig
    phase_config: PhaseConfig
    phase_model: PeriodicAutoencoder | None = None
    meta: BundleMeta = field(default_factory=BundleMeta)
    version: str = "unsaved"
    output: OutputConfig = field(default_factory=OutputConfig)  # the engine's post-processing of frames
    inference: InferenceConfig = field(default_factory=InferenceConfig)  # how the engine runs the network
    # Built-in style codes by name: styles/, and each adapter's style (``BuiltinStyle.weights`` names the adapter).
    styles: dict[str, BuiltinStyle] = field(default_factory=dict)
    adapters: dict[str, StyleAdapter] = field(default_factory=dict)  # weights of their own per style (adapters/)
    gait_limits: GaitLimits | None = None  # the capture's limits per style (gait_limits.json; None: none measured)
    network: str = DEFAULT_NETWORK  # the name of ``net`` in model.nets.transition_net.NETWORKS
    database: MotionDatabase | None = None  # real locomotion for motion matching (database.safetensors; None: none)

    @property
    def config(self) -> SamplerConfig:
        return self.net.config

    @property
    def sampler(self) -> TransitionSampler:
        """The network as the RSMT sampler; a BundleError for a bundle holding another network."""
        if not isinstance(self.net, TransitionSampler):
            raise BundleError(f"this bundle holds network {self.network!r}, not the RSMT sampler this needs")
        return self.net

    @sampler.setter
    def sampler(self, net: TransitionSampler) -> None:
        self.net = net

    @classmethod
    def create(
        cls,
        skeleton: Skeleton,
        sampler: SamplerConfig | None = None,
        manifold: ManifoldConfig | None = None,
        phase: PhaseConfig | None = None,
        meta: BundleMeta | None = None,
        seed: int = 0,
        network: str = DEFAULT_NETWORK,
    ) -> Bundle:
        """A bundle with freshly initialised (random) weights sized for ``skeleton``; ``network``: which of
        :data:`model.nets.transition_net.NETWORKS` (a BundleError for an unknown one)."""
        j = skeleton.num_joints
        torch.manual_seed(seed)
        sampler = sampler or SamplerConfig(joints=j)
        manifold = manifold or ManifoldConfig(joints=j, phases=sampler.phases, latent=sampler.latent, root=skeleton.roles.root)
        phase = phase or PhaseConfig(channels=j * 3, phases=sampler.phases, fps=sampler.fps)
        if not (sampler.joints == manifold.joints == j and sampler.phases == manifold.phases == phase.phases):
            raise BundleError("sampler, manifold and phase configs disagree on joints or phase channels")
        try:
            net = build_network(network, sampler, ManifoldDecoder(manifold))
        except ValueError as exc:
            raise BundleError(str(exc)) from None
        return cls(skeleton, net, manifold, phase, PeriodicAutoencoder(phase), meta or BundleMeta(), network=network)

    def tensors(self) -> dict[str, torch.Tensor]:
        # Always CPU tensors: the file and the weights hash must not depend on where the model sits.
        out = {f"sampler.{k}": v.detach().cpu().contiguous() for k, v in self.net.state_dict().items()}
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
        self.version = weights_hash(tensors)
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
        if self.network != DEFAULT_NETWORK:  # written only where it is not the default: older releases load the rest
            config["network"] = self.network
        (path / "config.json").write_text(json.dumps(config, indent=1))
        self.skeleton.save(path / "skeleton.json")
        if self.gait_limits is not None:
            self.gait_limits.save(path)
        self._save_styles(path)
        self._save_adapters(path)
        if self.database is not None:
            self.database.save(path)
        return path

    def _save_styles(self, path: Path) -> None:
        """``styles/``: the built-in styles encoded by these weights (none, with a warning, where any was not)."""
        own = {n: s for n, s in self.styles.items() if not s.weights}
        stale = sorted(n for n, s in own.items() if s.version != self.version)
        if own and not stale:
            save_styles(path, own.values(), self.skeleton, self.config.fps, self.version)
        elif stale:  # codes belong to the weights that made them (fine-tuned, averaged or float16 weights: others)
            log.warning("%s: built-in styles %s were encoded by model version %s, not by these weights (%s); they are "
                        "not saved: re-encode them with `rsmt bundle add-styles %s --from DIR` (or --from-data DATA)",
                        path, ", ".join(stale), own[stale[0]].version, self.version, path)

    def _save_adapters(self, path: Path) -> None:
        """``adapters/``: the style adapters tuned from these weights (the others left out with a warning)."""
        kept = {n: a for n, a in self.adapters.items() if a.base_version == self.version}
        if len(kept) < len(self.adapters):  # tuned from other weights: they would not fit these
            log.warning("%s: style adapters %s were tuned from model version %s, not from these weights (%s); they are "
                        "not saved: fine-tune them again from this bundle", path,
                        ", ".join(sorted(set(self.adapters) - set(kept))),
                        next(a.base_version for n, a in self.adapters.items() if n not in kept), self.version)
        if kept or (path / "adapters").exists():
            try:
                save_adapters(path, kept, self.styles, self.skeleton, self.config.fps)
            except AdapterError as exc:
                raise BundleError(f"{path}: {exc}") from exc

    def _load_database(self, path: Path) -> None:
        try:
            self.database = MotionDatabase.load(path, self.skeleton)
        except DatabaseError as exc:
            raise BundleError(str(exc)) from exc

    def _load_styles(self, path: Path, own: bool) -> None:
        """The built-in styles of ``styles/`` (``own``) and of the adapters, into ``self.styles``."""
        try:
            self.styles = load_styles(path, self.skeleton, self.config.fps, self.version) if own else {}
        except StyleFolderError as exc:
            raise BundleError(f"{path}: bad built-in styles: {exc}") from exc
        try:
            self.adapters, adapted = load_adapters(path, self.skeleton, self.config.fps, self.version)
        except (AdapterError, StyleFolderError) as exc:
            raise BundleError(f"{path}: bad style adapter: {exc}") from exc
        clash = sorted(set(adapted) & set(self.styles))
        if clash:
            raise BundleError(f"{path}: styles {', '.join(clash)} are built in twice, in styles/ and as adapters; "
                              "remove one")
        self.styles.update(adapted)

    @classmethod
    def load(cls, path: str | Path, styles: bool = True) -> Bundle:
        """Load strictly; any missing file, tensor or field is a :class:`BundleError`.

        ``styles=False`` leaves the ``styles/`` folder unread (``bundle.styles`` holds the adapters' styles
        alone): for the commands that rewrite it, which must work on a folder that no longer loads (old
        format, other weights)."""
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
            network=config.get("network", DEFAULT_NETWORK),
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
            bundle.net.load_state_dict(sampler_sd, strict=True)
            if bundle.phase_model is not None:
                bundle.phase_model.load_state_dict(phase_sd, strict=True)
        except RuntimeError as exc:
            raise BundleError(f"{path}: weights do not match the config: {exc}") from exc
        bundle.version = config.get("version") or weights_hash(tensors)
        try:
            bundle.gait_limits = GaitLimits.load(path)
        except ValueError as exc:
            raise BundleError(str(exc)) from exc
        bundle._load_styles(path, styles)
        bundle._load_database(path)
        bundle.net.eval()
        if bundle.phase_model is not None:
            bundle.phase_model.eval()
        return bundle
