"""A motion-style classifier for evaluation: style accuracy and FMD of generated transitions.

RSMT (paper Sec. 5) scores style with a classifier built from a style encoder plus a pooling
layer (removing time) and a softmax layer; the pooled features also give the Fréchet Motion
Distance (FMD). This is a small temporal CNN in that spirit.

Input: :func:`model.motion.features.local_frame_features` of a window, i.e. every frame in its own
facing frame (translation and facing invariant), per joint position, velocity and 6D rotation,
``[B, T, J*12]`` for ``T`` frames of motion (``T + 1`` poses: frame 0 only gives the first
velocity). The classifier was designed for ``T = 40``, the length of a 40-frame transition, but it
pools over time and accepts any ``T >= 1``.

Which channels it sees is the config's ``inputs``:

* ``"pose"``: all of them as they are. Style is easy to recognise from the pose alone, so such a
  classifier also calls a plain interpolation between two styled key poses "styled".
* ``"motion"`` (default): positions and rotations with their **window mean removed** (the mean
  pose of the window is subtracted, leaving how the pose moves about it), velocities unchanged.
* ``"deviation"``: like ``"motion"``, but the velocities' window mean is removed too (no average
  speed either).
* ``"velocity"``: velocities only.

The chosen input and its numbers (real-data accuracy and accuracy on interpolated transitions)
are in ``docs/experiments/2026-11-evaluation-history.md``. Channels are then normalised per channel by the training
statistics held as (non-persistent) buffers: they are saved in ``config.json``, not in the weights.

Saved as a folder: ``weights.safetensors`` (parameters only) and ``config.json`` (the config,
the style names, the normalisation and a training record). No pickle.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file
from torch import nn

from model.motion.features import local_frame_features
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor

FORMAT = "rsmt-style-classifier/1"
INPUTS = ("pose", "motion", "deviation", "velocity", "dynamics", "acceleration")
FEATURES_PER_JOINT = 12  # position 3, velocity 3, 6D rotation 6 (local_frame_features)
_STD_FLOOR = 1e-4


class ClassifierError(ValueError):
    """A classifier folder that is missing, incomplete or inconsistent."""


@dataclass
class StyleClassifierConfig:
    """Shape of the classifier.

    Attributes:
        styles: class names, in logit order.
        joints: joints of the rig (the input has ``joints * 12`` channels).
        window: frames of motion per training window (40: a 40-frame transition).
        inputs: which channels it sees (module docstring): pose, motion, deviation or velocity.
        channels: width of the convolutions.
        layers: number of convolution blocks (each halves the time resolution after the first).
        kernel: temporal kernel size.
        feature_dim: size of the pooled feature used for FMD.
        dropout: dropout before the softmax layer.
    """

    styles: list[str]
    joints: int = 21
    window: int = 40
    inputs: str = "motion"
    channels: int = 96
    layers: int = 3
    kernel: int = 5
    feature_dim: int = 64
    dropout: float = 0.2

    def __post_init__(self) -> None:
        if self.inputs not in INPUTS:
            raise ValueError(f"inputs must be one of {', '.join(INPUTS)}, got {self.inputs!r}")
        if len(self.styles) < 2:
            raise ValueError("a style classifier needs at least two styles")
        if self.joints < 1 or self.window < 1 or self.layers < 1 or self.kernel < 1:
            raise ValueError("joints, window, layers and kernel must be positive")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> StyleClassifierConfig:
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in names})


def input_channels(config: StyleClassifierConfig) -> int:
    """Channels after the input selection: 12 per joint, or 3 for velocities only."""
    per_joint = 3 if config.inputs in ("velocity", "dynamics", "acceleration") else FEATURES_PER_JOINT
    return config.joints * per_joint


def select_inputs(features: Tensor, inputs: str) -> Tensor:
    """Apply the input selection to ``local_frame_features`` ``[B, T, J*12]`` (see the module docstring)."""
    b, t, c = features.shape
    if c % FEATURES_PER_JOINT:
        raise ValueError(f"expected J*12 channels of local_frame_features, got {c}")
    x = features.reshape(b, t, c // FEATURES_PER_JOINT, FEATURES_PER_JOINT)
    pos, vel, rot = x[..., 0:3], x[..., 3:6], x[..., 6:12]
    if inputs == "pose":
        out = x
    elif inputs == "motion":
        out = torch.cat([pos - pos.mean(1, keepdim=True), vel, rot - rot.mean(1, keepdim=True)], dim=-1)
    elif inputs == "deviation":
        out = x - x.mean(1, keepdim=True)
    elif inputs == "velocity":
        out = vel
    elif inputs == "dynamics":
        out = vel - vel.mean(1, keepdim=True)
    elif inputs == "acceleration":
        acc = vel[:, 1:] - vel[:, :-1]
        out = torch.cat([acc[:, :1], acc], dim=1) if t > 1 else torch.zeros_like(vel)
    else:
        raise ValueError(f"unknown inputs {inputs!r}")
    return out.reshape(b, t, -1)


def motion_features(global_positions: Tensor, global_rotations: Tensor, skeleton: Skeleton) -> Tensor:
    """Classifier input for motion given as world positions ``[..., T+1, J, 3]`` and rotations ``[..., T+1, J, 4]``.

    Returns ``[..., T, J*12]`` (:func:`model.motion.features.local_frame_features`). Pass the last
    context frame followed by a transition's frames to classify the transition.
    """
    return local_frame_features(global_positions, global_rotations, skeleton)


class StyleClassifier(nn.Module):
    """Temporal CNN: input selection, normalisation, conv blocks, pooled feature, linear classifier."""

    # Buffers (registered in __init__).
    mean: Tensor
    std: Tensor

    def __init__(self, config: StyleClassifierConfig) -> None:
        super().__init__()
        self.config = config
        self.record: dict[str, Any] = {}  # the training record, when loaded from a folder
        c_in = input_channels(config)
        self.register_buffer("mean", torch.zeros(c_in), persistent=False)
        self.register_buffer("std", torch.ones(c_in), persistent=False)
        blocks: list[nn.Module] = []
        width = c_in
        for i in range(config.layers):
            if i > 0:
                blocks.append(nn.AvgPool1d(2, ceil_mode=True))
            blocks += [
                nn.Conv1d(width, config.channels, config.kernel, padding=config.kernel // 2),
                nn.GroupNorm(8 if config.channels % 8 == 0 else 1, config.channels),
                nn.LeakyReLU(0.2),
            ]
            width = config.channels
        self.body = nn.Sequential(*blocks)
        self.project = nn.Conv1d(width, config.feature_dim, 1)
        self.drop = nn.Dropout(config.dropout)
        self.head = nn.Linear(config.feature_dim, len(config.styles))

    @property
    def styles(self) -> list[str]:
        return list(self.config.styles)

    def set_normalisation(self, mean: Tensor, std: Tensor) -> None:
        """Per-channel statistics of the selected inputs (of the training windows)."""
        c = input_channels(self.config)
        if mean.shape != (c,) or std.shape != (c,):
            raise ValueError(f"normalisation must have {c} channels, got {list(mean.shape)} and {list(std.shape)}")
        self.mean.copy_(mean.to(self.mean.dtype))
        self.std.copy_(std.to(self.std.dtype).clamp_min(_STD_FLOOR))

    def prepare(self, features: Tensor) -> Tensor:
        """``local_frame_features`` ``[B, T, J*12]`` to the normalised network input ``[B, C, T]``."""
        if features.dim() != 3 or features.shape[-1] != self.config.joints * FEATURES_PER_JOINT:
            raise ValueError(f"expected features [B, T, {self.config.joints * FEATURES_PER_JOINT}], "
                             f"got {list(features.shape)}")
        x = select_inputs(features.to(self.mean.dtype), self.config.inputs)
        return ((x - self.mean) / self.std).transpose(1, 2)

    def features(self, features: Tensor) -> Tensor:
        """Pooled features ``[B, feature_dim]`` (time averaged out), the space FMD is measured in."""
        h = self.body(self.prepare(features))
        return torch.relu(self.project(h)).mean(dim=-1)

    def forward(self, features: Tensor) -> Tensor:
        """Logits ``[B, styles]`` for ``local_frame_features`` ``[B, T, J*12]``."""
        return self.head(self.drop(self.features(features)))

    @torch.no_grad()
    def predict(self, features: Tensor, batch: int = 512) -> tuple[Tensor, Tensor]:
        """``(logits [B, S], pooled features [B, D])`` in eval mode, in batches."""
        was = self.training
        self.eval()
        logits, feats = [], []
        for i in range(0, features.shape[0], batch):
            f = self.features(features[i:i + batch])
            feats.append(f)
            logits.append(self.head(f))
        self.train(was)
        if not logits:
            return torch.zeros(0, len(self.config.styles)), torch.zeros(0, self.config.feature_dim)
        return torch.cat(logits), torch.cat(feats)

    # ------------------------------------------------------------------ files
    def save(self, path: str | Path, record: dict[str, Any] | None = None) -> Path:
        """Write ``weights.safetensors`` and ``config.json`` (with ``record``, e.g. training results)."""
        path = Path(path)
        path.mkdir(parents=True, exist_ok=True)
        tensors = {k: v.detach().contiguous() for k, v in self.state_dict().items()}
        save_file(tensors, str(path / "weights.safetensors"), metadata={"format": FORMAT})
        config = {
            "format": FORMAT,
            "config": self.config.to_dict(),
            "styles": self.styles,
            "normalisation": {"inputs": self.config.inputs, "mean": self.mean.tolist(), "std": self.std.tolist()},
            "record": record or {},
        }
        (path / "config.json").write_text(json.dumps(config, indent=1))
        return path

    @classmethod
    def load(cls, path: str | Path) -> StyleClassifier:
        """Load strictly; a missing file, tensor or field is a :class:`ClassifierError`."""
        path = Path(path)
        for name in ("config.json", "weights.safetensors"):
            if not (path / name).is_file():
                raise ClassifierError(f"{path} is not a style classifier: {name} is missing")
        try:
            data = json.loads((path / "config.json").read_text())
        except json.JSONDecodeError as exc:
            raise ClassifierError(f"{path}/config.json is not valid JSON: {exc}") from exc
        if data.get("format") != FORMAT:
            raise ClassifierError(f"{path}: unsupported classifier format {data.get('format')!r} (expected {FORMAT})")
        try:
            config = StyleClassifierConfig.from_dict(data["config"])
            norm = data["normalisation"]
            model = cls(config)
            model.set_normalisation(torch.tensor(norm["mean"]), torch.tensor(norm["std"]))
            model.load_state_dict(load_file(str(path / "weights.safetensors")), strict=True)
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise ClassifierError(f"{path}: inconsistent classifier: {exc}") from exc
        model.record = data.get("record", {})
        return model.eval()
