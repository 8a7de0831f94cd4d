"""The seam around the network: what the engine, the batch, the ONNX export and the service ask of a transition
network, and the networks a bundle may hold, by name.

A transition network turns a style clip into a style context once, warms up on a transition's context frames
(``begin``), and then advances every live character by one frame (``step``) towards its target, all in one batch.
Its per-character state and its style context are :class:`~model.nets.tensor_record.TensorRecord` s, so everything
above this seam stacks, indexes, traces and exports them without knowing their fields. The state has four fields
every network keeps under these names, which steering, the speed cap and the reach read and move: ``pose`` (the
current pose), ``tta`` (frames left, the next one included), ``target_pos`` and ``target_rot`` (what it aims at).

:data:`NETWORKS` maps the name a bundle's ``config.json`` gives (``network``; absent: ``rsmt``) to the function
that builds the network from the bundle's sampler config (:class:`~model.nets.sampler.SamplerConfig`: the shapes
and limits every network shares) and its manifold decoder. ``docs/architecture.md`` says how to add one.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any, Protocol, TypeVar

import torch

from model.nets.manifold import ManifoldDecoder
from model.nets.pose_state import PoseState
from model.nets.sampler import SamplerConfig, TransitionSampler

Tensor = torch.Tensor
S = TypeVar("S", bound="NetState")


class NetState(Protocol):
    """A network's per-character state (a :class:`TensorRecord` with at least these fields)."""

    pose: PoseState
    tta: Tensor
    target_pos: Tensor
    target_rot: Tensor

    def flat(self) -> tuple[Tensor, ...]: ...

    def carried(self) -> tuple[Tensor, ...]: ...

    def with_carried(self: S, tensors: Any) -> S: ...

    def index(self: S, idx: Any) -> S: ...

    @classmethod
    def stack(cls: type[S], items: Any) -> S: ...

    @classmethod
    def flat_names(cls) -> tuple[str, ...]: ...

    @classmethod
    def carried_names(cls) -> tuple[str, ...]: ...

    @classmethod
    def from_flat(cls: type[S], tensors: Any) -> S: ...


class StyleRecord(Protocol):
    """A network's style context (a :class:`TensorRecord`)."""

    TIME_AXES: dict[str, int]

    def flat(self) -> tuple[Tensor, ...]: ...

    def index(self, idx: Any) -> Any: ...

    @property
    def nbytes(self) -> int: ...

    @classmethod
    def stack(cls, items: Any) -> Any: ...

    @classmethod
    def flat_names(cls) -> tuple[str, ...]: ...

    @classmethod
    def from_flat(cls, tensors: Any) -> Any: ...


class TransitionNet(Protocol):
    """What everything above the seam asks of a transition network (a ``torch.nn.Module``).

    ``config`` holds the shapes and limits: ``context`` frames read, ``max_transition``, ``style_frames_min`` /
    ``style_frames_max``, ``fps``, ``joints``. ``state_type`` and ``style_type`` are its record classes.
    """

    config: SamplerConfig
    state_type: type[Any]
    style_type: type[Any]

    def encode_style(self, features: Tensor) -> Tensor:
        """Style clip features ``[B, T, J*12]`` (:func:`model.motion.features.local_frame_features`) to a code
        ``[B, T', C]``; codes of several clips are joined along ``T'`` (:mod:`model.inference.style_sets`)."""
        ...

    def style_context(self, code: Tensor) -> Any:
        """A code to the style context each frame reads (a ``style_type``)."""
        ...

    def noise(self, generator: torch.Generator | None) -> Tensor:
        """One transition's noise ``[1, N]`` drawn from ``generator``, zeros where it is None (deterministic)."""
        ...

    def begin(self, context: PoseState, target: PoseState, frames: Tensor, noise: Tensor, style: Any, *,
              velocity_known: Tensor | None = None) -> Any:
        """The state before the first new frame: ``context [B, K, J, *]`` and ``target [B, J, *]`` in each
        transition's canonical frame, ``frames [B]`` to generate, ``noise [B, N]``, the batch's style contexts,
        ``velocity_known [B]`` whether each target came with the frame before it."""
        ...

    def step(self, state: Any, style: Any) -> tuple[Any, dict[str, Tensor]]:
        """Every character one frame on: the new state (``tta`` one less) and the raw predictions."""
        ...

    def target_fields(self, state: Any, target: PoseState, velocity_known: Tensor, frames: Tensor) -> dict[str, Tensor]:
        """The fields of ``state`` (characters under way) that a new ``target [B, J, *]`` and ``frames [B]`` left
        change (a retarget or a new duration writes them)."""
        ...

    def reencoded(self, state: Any) -> dict[str, Tensor]:
        """The state's fields these weights compute from it (a style switch onto these weights rewrites them)."""
        ...

    def parameters(self, recurse: bool = True) -> Iterator[torch.nn.Parameter]: ...

    def named_parameters(self, prefix: str = "", recurse: bool = True,
                         remove_duplicate: bool = True) -> Iterator[tuple[str, torch.nn.Parameter]]: ...

    def state_dict(self, *args: Any, **kwargs: Any) -> dict[str, Any]: ...

    def load_state_dict(self, state_dict: Any, strict: bool = True, assign: bool = False) -> Any: ...

    def eval(self) -> Any: ...

    def modules(self) -> Iterator[torch.nn.Module]: ...


NetFactory = Callable[[SamplerConfig, ManifoldDecoder], TransitionNet]
NETWORKS: dict[str, NetFactory] = {"rsmt": TransitionSampler}
DEFAULT_NETWORK = "rsmt"


def build_network(name: str, config: SamplerConfig, decoder: ManifoldDecoder) -> TransitionNet:
    """The network ``name`` of :data:`NETWORKS`; an unknown name is a ValueError naming those there are."""
    factory = NETWORKS.get(name)
    if factory is None:
        raise ValueError(f"unknown network {name!r}; known: {', '.join(sorted(NETWORKS))}")
    return factory(config, decoder)
