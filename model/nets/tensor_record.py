"""Records of batched tensors: what a transition network keeps per character (its state) and per style (its
style context), handled by the engine, the batch, the traced step and the ONNX export without knowing their fields.

A record is a dataclass whose fields are tensors with a leading batch dimension, or :class:`PoseState` s (named
in ``POSES``), which count as their four tensors when a record is laid flat (``rel``, ``vel``, ``rot``,
``root_xz``, in that order). ``FIXED`` names the fields a network's step passes through unchanged (a target, a
noise draw): the traced step and the ONNX ``step`` graph return only the others, the ``carried`` ones.
``TIME_AXES`` gives, per field, the axis of a style code's time steps, along which :meth:`TensorRecord.stack`
pads shorter codes with zeros (their ``mask`` field, where there is one, marks the real steps).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import fields
from typing import Any, ClassVar, TypeVar

import torch

from model.nets.pose_state import PoseState

Tensor = torch.Tensor
R = TypeVar("R", bound="TensorRecord")
POSE_PARTS = ("rel", "vel", "rot", "root_xz")


class TensorRecord:
    """Mixin for a dataclass of batched tensors and pose states (see the module's notes)."""

    POSES: ClassVar[tuple[str, ...]] = ()
    FIXED: ClassVar[tuple[str, ...]] = ()
    TIME_AXES: ClassVar[dict[str, int]] = {}

    @classmethod
    def _expand(cls, names: Sequence[str]) -> tuple[str, ...]:
        out: list[str] = []
        for name in names:
            out.extend(POSE_PARTS if name in cls.POSES else (name,))
        return tuple(out)

    @classmethod
    def flat_names(cls) -> tuple[str, ...]:
        """Every tensor's name, in field order, a pose state's four parts in its place."""
        return cls._expand([f.name for f in fields(cls)])  # type: ignore[arg-type]

    @classmethod
    def carried_names(cls) -> tuple[str, ...]:
        """The names of the tensors a step changes (every field not in ``FIXED``), laid flat."""
        return cls._expand([f.name for f in fields(cls) if f.name not in cls.FIXED])  # type: ignore[arg-type]

    def _values(self, carried_only: bool = False) -> list[Tensor]:
        out: list[Tensor] = []
        for f in fields(self):  # type: ignore[arg-type]
            if carried_only and f.name in self.FIXED:
                continue
            value = getattr(self, f.name)
            out.extend(getattr(value, p) for p in POSE_PARTS) if f.name in self.POSES else out.append(value)
        return out

    def flat(self) -> tuple[Tensor, ...]:
        """The tensors in :meth:`flat_names` order."""
        return tuple(self._values())

    def carried(self) -> tuple[Tensor, ...]:
        """The tensors in :meth:`carried_names` order."""
        return tuple(self._values(carried_only=True))

    @classmethod
    def _build(cls: type[R], names: Sequence[str], tensors: Sequence[Tensor], base: R | None = None) -> R:
        given = iter(tensors)
        values: dict[str, Any] = {}
        for f in fields(cls):  # type: ignore[arg-type]
            if f.name not in names:
                values[f.name] = getattr(base, f.name)
            elif f.name in cls.POSES:
                values[f.name] = PoseState(*(next(given) for _ in POSE_PARTS))
            else:
                values[f.name] = next(given)
        return cls(**values)

    @classmethod
    def from_flat(cls: type[R], tensors: Sequence[Tensor]) -> R:
        """The record of tensors in :meth:`flat_names` order."""
        names = [f.name for f in fields(cls)]  # type: ignore[arg-type]
        return cls._build(names, tensors)

    def with_carried(self: R, tensors: Sequence[Tensor]) -> R:
        """This record with the carried tensors replaced (``tensors`` in :meth:`carried_names` order)."""
        names = [f.name for f in fields(self) if f.name not in self.FIXED]  # type: ignore[arg-type]
        return type(self)._build(names, tensors, self)

    def index(self: R, idx: Any) -> R:
        """The rows ``idx`` of every field."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}  # type: ignore[arg-type]
        return type(self)(**{k: v.index(idx) if k in self.POSES else v[idx] for k, v in values.items()})

    @classmethod
    def stack(cls: type[R], items: Sequence[R]) -> R:
        """Join records along the batch, padding fields with a time axis (``TIME_AXES``) to the longest."""
        values: dict[str, Any] = {}
        for f in fields(cls):  # type: ignore[arg-type]
            parts = [getattr(i, f.name) for i in items]
            if f.name in cls.POSES:
                values[f.name] = PoseState.cat(parts)
                continue
            axis = cls.TIME_AXES.get(f.name)
            if axis is not None:
                longest = max(p.shape[axis] for p in parts)
                parts = [_padded(p, axis, longest) for p in parts]
            values[f.name] = torch.cat(parts)
        return cls(**values)

    @property
    def nbytes(self) -> int:
        """Memory of its tensors (what a style cache holds per style)."""
        return sum(t.numel() * t.element_size() for t in self._values())


def _padded(t: Tensor, axis: int, length: int) -> Tensor:
    if t.shape[axis] == length:
        return t
    shape = list(t.shape)
    shape[axis] = length - t.shape[axis]
    return torch.cat([t, t.new_zeros(shape)], dim=axis)
