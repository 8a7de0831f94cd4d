"""Transition methods the evaluation runs on the same cases: model bundles and the baselines.

A method turns a batch of requests (context, target, frame count, style clip, noise) into
generated frames ``1..N`` as world-space local rotations ``[B, N, J, 4]`` and root positions
``[B, N, 3]``; frame ``N`` is meant to be the target.

* ``interp`` / ``zerovel``: :mod:`model.evaluation.baselines` (interpolation from the last context pose to
  the target; hold the last context pose, then jump). They ignore the style clip.
* ``gt``: the ground truth itself (only where it exists), a sanity check that must score 0.
* a bundle folder: the trained model through :class:`model.inference.engine.Engine`, noise off
  (``deterministic=True``) for every score except diversity. It is sent the target frame alone
  (``Request.target_frames = 1``, the default: what a game has) or with the frame before it
  (``target_frames = 2``: the target's velocity).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from model.evaluation.baselines import interpolate, zero_velocity
from model.evaluation.cases import LAST_CONTEXT, CaseSet, Variant
from model.inference.overrides import Overrides
from model.motion.clip import Clip

Tensor = torch.Tensor

BASELINES = {"interp": interpolate, "zerovel": zero_velocity}
GROUND_TRUTH = "gt"


class Unavailable(Exception):
    """A method cannot produce a variant (the reason is reported instead of numbers)."""


@dataclass(frozen=True)
class Request:
    """What a method is asked for: a variant of every case, a style pairing and optional noise seeds."""

    variant: Variant
    cross_style: bool = False
    seeds: Sequence[int] | None = None  # one per case: sample with noise; None: deterministic
    target_frames: int = 1  # 1: the target frame alone; 2: with the frame before it (its velocity)

    def style_clips(self, cases: CaseSet) -> list[Clip]:
        return cases.cross_clips if self.cross_style else cases.style_clips


class Method:
    """Base class: ``name``, whether it reads the style clip, whether it can sample."""

    name: str = ""
    kind: str = ""
    uses_style: bool = False
    stochastic: bool = False

    def generate(self, cases: CaseSet, request: Request, progress: bool = False) -> tuple[Tensor, Tensor]:
        raise NotImplementedError

    def describe(self) -> dict:
        return {"name": self.name, "kind": self.kind, "uses_style": self.uses_style, "stochastic": self.stochastic}


class BaselineMethod(Method):
    kind = "baseline"

    def __init__(self, name: str) -> None:
        self.name = name
        self.fn = BASELINES[name]

    def generate(self, cases: CaseSet, request: Request, progress: bool = False) -> tuple[Tensor, Tensor]:
        v = request.variant
        rot, root = cases.targets(v, 1)
        return self.fn(cases.rotations[:, LAST_CONTEXT], cases.roots[:, LAST_CONTEXT], rot[:, -1], root[:, -1], v.frames)


class GroundTruthMethod(Method):
    name = GROUND_TRUTH
    kind = "ground truth"

    def generate(self, cases: CaseSet, request: Request, progress: bool = False) -> tuple[Tensor, Tensor]:
        if not request.variant.has_ground_truth:
            raise Unavailable("no ground truth under changed controls")
        return cases.ground_truth_local(request.variant)


class BundleMethod(Method):
    """A model bundle run through the engine, in batches of ``batch`` transitions; ``source``: the engine's motion
    source (:data:`model.inference.engine.SOURCES`: the bundle's network, or matching over its motion database)."""

    kind = "bundle"
    uses_style = True
    stochastic = True

    def __init__(self, path: str | Path, batch: int = 128, name: str | None = None, exact_arrival: bool = False,
                 overrides: Overrides | None = None, source: str = "network") -> None:
        from model.inference.bundle import Bundle
        from model.inference.engine import Engine

        self.path = Path(path)
        self.bundle = Bundle.load(self.path)
        self.engine = Engine(self.bundle, overrides=overrides, source=source)
        self.source = source
        self.name = name or (self.path.name if source == "network" else f"{self.path.name} ({source})")
        self.batch = batch
        self.exact_arrival = exact_arrival

    def describe(self) -> dict:
        d = super().describe()
        d.update(path=str(self.path), version=self.bundle.version, bundle_name=self.bundle.meta.name,
                 max_transition=self.engine.max_frames, exact_arrival=self.exact_arrival, source=self.source,
                 output=self.engine.output.to_dict(), inference=self.engine.inference.to_dict(),
                 adapters=sorted(self.bundle.adapters))
        return d

    def generate(self, cases: CaseSet, request: Request, progress: bool = False) -> tuple[Tensor, Tensor]:
        from model.inference.style_sets import encode_style_set

        v = request.variant
        limit = self.engine.max_frames
        if v.frames > limit:
            raise Unavailable(f"{v.frames} frames exceed the model's limit of {limit} frames")
        clips = request.style_clips(cases)
        target_rot, target_root = cases.targets(v, request.target_frames)
        rots: list[Tensor] = []
        roots: list[Tensor] = []
        bar = tqdm(total=len(cases), desc=f"{self.name} {v.name}{' cross' if request.cross_style else ''}",
                   unit="case", disable=not progress, leave=False, file=sys.stderr)
        with bar:
            for lo in range(0, len(cases), self.batch):
                chars = []
                for b in range(lo, min(lo + self.batch, len(cases))):
                    # A clip of a style with an adapter in the bundle (a fine-tuned style) runs on its weights,
                    # as builtin:NAME does in the service; every other style on the bundle's own.
                    case = cases.cases[b]
                    named = case.cross_style if request.cross_style else case.style
                    weights = named if named in self.engine.weight_sets else ""
                    # A case asked with a style set (several clips of its style) encodes them together, as
                    # POST /v1/styles does with several motions.
                    together = cases.style_sets[b] if cases.style_sets and not request.cross_style else []
                    style, _ = (encode_style_set(self.engine, together, weights=weights) if together
                                else self.engine.encode_style(clips[b], weights=weights))
                    seed = None if request.seeds is None else int(request.seeds[b])
                    target = Clip(cases.skeletons[b], target_rot[b], target_root[b], cases.fps,
                                  name=f"{cases.cases[b].id}:target")
                    chars.append(self.engine.prepare(cases.context_clip(b), target, v.frames, style,
                                                     seed=seed, deterministic=request.seeds is None,
                                                     character_id=f"{cases.cases[b].id}:{v.name}",
                                                     exact_arrival=self.exact_arrival))
                for rot, root in self.engine.generate(chars):
                    rots.append(rot)
                    roots.append(root)
                bar.update(len(chars))
        return torch.stack(rots).float(), torch.stack(roots).float()


def resolve_method(spec: str, batch: int = 128, exact_arrival: bool = False,
                   overrides: Overrides | None = None, source: str = "network") -> Method:
    """``interp``, ``zerovel``, ``gt`` or the path of a model bundle.

    ``exact_arrival``, ``overrides`` (:class:`model.inference.overrides.Overrides`; None: the bundle's own
    settings) and ``source`` (what makes the motion: :data:`model.inference.engine.SOURCES`) are the engine's options
    for bundles.
    """
    if spec in BASELINES:
        return BaselineMethod(spec)
    if spec == GROUND_TRUTH:
        return GroundTruthMethod()
    path = Path(spec)
    if not path.is_dir():
        raise FileNotFoundError(f"--model {spec!r} is neither {', '.join([*BASELINES, GROUND_TRUTH])} nor a bundle folder")
    return BundleMethod(path, batch, exact_arrival=exact_arrival, overrides=overrides, source=source)
