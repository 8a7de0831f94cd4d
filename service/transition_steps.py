"""A whole transition generated a slice at a time: the frames of ``Engine.generate`` for one character (the same
batch of one, stepped the same way), in as many calls as the work queue gives it turns, so that a long transition
holds a work thread for a slice and another key's job can run in between (:class:`service.work_queue.Continue`)."""

from __future__ import annotations

import time

import torch

from model.inference.engine import Character, CharacterBatch, Engine

SLICE_S = 0.02  # about how long one slice steps before the thread is handed on


class TransitionSteps:
    """One prepared character stepped to its end in a batch of its own, a slice at a time (work threads only)."""

    def __init__(self, engine: Engine, ch: Character) -> None:
        self.batch = CharacterBatch(engine)
        self.batch.add(ch)
        self._rotations: list[torch.Tensor] = []
        self._roots: list[torch.Tensor] = []
        self.seconds = 0.0  # spent stepping, over every slice

    def advance(self, budget_s: float = SLICE_S) -> bool:
        """Step for about ``budget_s`` (at least one frame); True once the character has ended."""
        began = time.perf_counter()
        while len(self.batch):
            out = self.batch.step()
            self._rotations.append(out.rotations[0])
            self._roots.append(out.root_positions[0])
            self.batch.drop_finished()
            if time.perf_counter() - began >= budget_s:
                break
        self.seconds += time.perf_counter() - began
        return not len(self.batch)

    def frames(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(rotations [F, J, 4], roots [F, 3])`` once :meth:`advance` has returned True."""
        return torch.stack(self._rotations), torch.stack(self._roots)
