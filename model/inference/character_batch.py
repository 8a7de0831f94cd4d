"""A batch of live characters whose states are stacked so that one step of each weight set advances them all."""

from __future__ import annotations

from typing import Any, Protocol

import torch

from model.inference.character import Character, EncodedStyle, StepOutput, WeightSet
from model.inference.output.pipeline import OutputPipeline
from model.inference.output.speed_cap import speed_capped
from model.inference.traced_step import CompiledFrameOutput
from model.motion.features import CanonicalFrame
from model.nets.transition_net import NetState

Tensor = torch.Tensor


@torch.inference_mode()
def restyle_held(ch: Character, style: EncodedStyle, ws: WeightSet) -> None:
    """Switch the style of a character outside a batch; ``ws``: the new style's weights. A row it holds is
    re-encoded by them when they change (one not begun yet is encoded by :meth:`Engine.begin`)."""
    if style.weights != ch.style.weights and ch.row is not None:
        for name, value in ws.net.reencoded(ch.row).items():
            setattr(ch.row, name, value)
    ch.style = style


class BatchEngine(Protocol):
    """What a batch needs of its engine (:class:`model.inference.engine.Engine`)."""

    output_fn: CompiledFrameOutput
    pipeline: OutputPipeline

    def begin(self, characters: list[Character]) -> NetState: ...

    def weights(self, name: str = "") -> WeightSet: ...

    def context_of(self, style: EncodedStyle, strength: float | None = None) -> Any: ...


def by_weights(characters: list[Character]) -> list[tuple[str, Tensor]]:
    """The characters' rows grouped by the weight set of their style, in order of first appearance."""
    rows: dict[str, list[int]] = {}
    for i, c in enumerate(characters):
        rows.setdefault(c.style.weights, []).append(i)
    return [(w, torch.tensor(r)) for w, r in rows.items()]


def inverse_of(groups: list[tuple[str, Tensor]]) -> Tensor:
    """The index that puts rows stacked group after group back in the characters' order."""
    order = torch.cat([idx for _, idx in groups])
    inverse = torch.empty_like(order)
    inverse[order] = torch.arange(len(order))
    return inverse


class CharacterBatch:
    """Live characters whose states are stacked so one sampler step advances them all.

    Stacking happens only when membership or a style changes, not every frame.
    """

    def __init__(self, engine: BatchEngine) -> None:
        self.engine = engine
        self.members: list[Character] = []
        self._state: NetState | None = None
        self._style: Any = None  # the members' stacked style contexts
        self._yaw: Tensor | None = None
        self._origin: Tensor | None = None
        # The output pipeline's memory, a row per member (model.inference.output.pipeline.FrameSteps.keys).
        self._memory: dict[str, Tensor] | None = None
        self._pending: list[Character] = []
        self._style_dirty = False
        # The members by weight set: (weights, their rows, their style context); with several sets, the
        # index that puts the rows stepped set after set back in member order.
        self._groups: list[tuple[WeightSet, Tensor, Any]] = []
        self._inverse: Tensor | None = None

    def __len__(self) -> int:
        return len(self.members) + len(self._pending)

    def add(self, ch: Character) -> None:
        if ch.row is None and ch.prepared is None:
            raise ValueError("character was not prepared by Engine.prepare")
        self._pending.append(ch)

    def _sync(self) -> None:
        """Bring the stacked tensors up to date: characters waiting to join joined, the style contexts restacked
        after a membership or style change."""
        if self._pending:
            self._join(self._pending)
            self._pending = []
            self._style_dirty = True
        if self._style_dirty and self.members:
            self._restyle()

    def _join(self, waiting: list[Character]) -> None:
        """Stack ``waiting`` under the members: newcomers warmed up in one batch, resumed ones with the rows they
        hold; each hands its canonical frame and output memory to the batch."""
        fresh = [c for c in waiting if c.row is None]
        resumed = [c for c in waiting if c.row is not None]
        joined = fresh + resumed
        if any(c.memory is None for c in joined):
            raise ValueError("character was not prepared by Engine.prepare")
        rows = [] if self._state is None else [self._state]
        if fresh:
            rows.append(self.engine.begin(fresh))  # one batched warm-up for every newcomer
        rows += [c.row for c in resumed]  # type: ignore[misc]  # resumed ones hold a row
        self._state = type(rows[0]).stack(rows)
        self._take_frames_and_memory(joined)
        self.members.extend(joined)

    def _take_frames_and_memory(self, joined: list[Character]) -> None:
        """The canonical frames and output memories of ``joined`` stacked under the members' (the characters
        hold neither afterwards)."""
        frames = [c.canonical_frame() for c in joined]
        memories = [c.memory for c in joined]
        if self._yaw is not None and self._origin is not None:
            frames.insert(0, CanonicalFrame(self._yaw, self._origin))
        if self._memory is not None:
            memories.insert(0, self._memory)
        self._yaw = torch.cat([f.yaw for f in frames])
        self._origin = torch.cat([f.origin for f in frames])
        held = [m for m in memories if m is not None]
        self._memory = {k: torch.cat([m[k] for m in held]) for k in held[0]}
        for c in joined:
            c.row = None
            c.memory = None

    def _restyle(self) -> None:
        """The members' style contexts stacked (at each one's strength) and grouped by weight set."""
        contexts = [self.engine.context_of(m.style, m.style_strength) for m in self.members]
        self._style = type(contexts[0]).stack(contexts)
        groups = by_weights(self.members)
        whole = len(groups) == 1  # the usual case: the batch's style context as it is, no copy
        self._groups = [(self.engine.weights(w), idx, self._style if whole else self._style.index(idx))
                        for w, idx in groups]
        self._inverse = inverse_of(groups) if len(groups) > 1 else None
        self._style_dirty = False

    @torch.inference_mode()
    def set_style(self, ch: Character, style: EncodedStyle) -> None:
        """Switch a member's style from the next frame; a style on other weights re-encodes its target by them."""
        ws = self.engine.weights(style.weights)
        if ch in self.members and style.weights != ch.style.weights:
            self.update_row(ch, ws.net.reencoded(self.row_of(ch)))
            ch.style = style
        else:  # waiting to join or resume
            restyle_held(ch, style, ws)
        self._style_dirty = True

    def stacked(self) -> tuple[NetState, Any, Tensor, Tensor, dict[str, Tensor]]:
        """The members' stacked sampler state and style context, canonical frames (``yaw [N]``, ``origin [N, 3]``)
        and output-step memory, as the next :meth:`step` reads them (characters waiting to join joined first)."""
        self._sync()
        if self._state is None or self._style is None or self._yaw is None or self._origin is None \
                or self._memory is None:
            raise ValueError("no live characters in the batch")
        return self._state, self._style, self._yaw, self._origin, self._memory

    def row_of(self, ch: Character) -> NetState:
        self._sync()
        i = self.members.index(ch)
        assert self._state is not None
        return self._state.index(slice(i, i + 1))

    @torch.inference_mode()
    def update_row(self, ch: Character, updates: dict[str, Tensor]) -> None:
        self._sync()
        i = self.members.index(ch)
        assert self._state is not None
        for k, v in updates.items():
            getattr(self._state, k)[i : i + 1] = v

    @torch.inference_mode()
    def set_memory(self, ch: Character, key: str, value: Tensor) -> None:
        """Set a row ``key`` of a character's output memory (``value [1, ...]``), in the batch or on the character
        (a key the output steps do not keep is left alone)."""
        self._sync()
        if ch in self.members:
            assert self._memory is not None
            if key in self._memory:
                i = self.members.index(ch)
                self._memory[key][i : i + 1] = value
        elif ch.memory is not None and key in ch.memory:
            ch.memory[key] = value

    def remove(self, ch: Character) -> None:
        if ch in self._pending:
            self._pending.remove(ch)
            return
        self._keep([m for m in self.members if m is not ch])

    def detach(self, ch: Character) -> None:
        """Take a live character out of the batch but keep its state on it, so :meth:`add` resumes it.

        :meth:`remove` discards the state; this lets a scheduler pause one character (its client is
        not reading, say) while the others keep stepping. Costs one restack, like ``remove``.
        """
        if ch in self._pending:
            self._pending.remove(ch)
            return
        self._sync()
        i = self.members.index(ch)
        assert self._state is not None and self._yaw is not None and self._origin is not None
        row = torch.tensor([i])
        ch.row = self._state.index(row)  # a copy: later steps never write into it
        ch.frame = CanonicalFrame(self._yaw[row], self._origin[row])
        assert self._memory is not None
        ch.memory = {k: v[i : i + 1].clone() for k, v in self._memory.items()}
        self._keep([m for m in self.members if m is not ch])

    def drop_finished(self) -> list[Character]:
        done = [m for m in self.members if m.done] + [p for p in self._pending if p.cancelled]
        if done:
            self._pending = [p for p in self._pending if not p.cancelled]
            self._keep([m for m in self.members if not m.done])
        return done

    def _keep(self, keep: list[Character]) -> None:
        if len(keep) == len(self.members):
            return
        if not keep:
            self.members, self._state, self._style, self._yaw, self._origin = [], None, None, None, None
            self._memory = None
            return
        idx = torch.tensor([self.members.index(k) for k in keep])
        assert self._state is not None and self._yaw is not None and self._origin is not None
        self._state = self._state.index(idx)
        self._yaw, self._origin = self._yaw[idx], self._origin[idx]
        assert self._memory is not None
        self._memory = {k: v[idx] for k, v in self._memory.items()}
        self.members = keep
        self._style_dirty = True

    @torch.inference_mode()
    def step(self) -> StepOutput:
        """Advance every member by one frame and return their world-space poses."""
        self._sync()
        if not self.members:
            raise ValueError("no live characters to step")
        assert self._state is not None and self._style is not None
        flags = [m.retargeted for m in self.members]  # which rows steer their facing by the retarget window
        late = torch.tensor(flags) if any(flags) else None
        caps = [m.speed_cap for m in self.members]
        before = self._state.pose.root_xz.clone() if min(caps) < float("inf") else None
        if self._inverse is None:  # one weight set: the whole batch in one step
            self._state, shift = self._groups[0][0].step_fn(self._state, self._style, late)  # steering included
        else:
            parts = [ws.step_fn(self._state.index(idx), style, None if late is None else late[idx])
                     for ws, idx, style in self._groups]
            self._state = type(parts[0][0]).stack([p[0] for p in parts]).index(self._inverse)
            shifts = [p[1] for p in parts]
            shift = None if shifts[0] is None else torch.cat([s for s in shifts if s is not None])[self._inverse]
        if before is not None:  # each row's root within its style's capture speed (model.inference.output.speed_cap)
            self._state, shift = speed_capped(before, self._state, shift, torch.tensor(caps))
        memory = self._memory
        assert memory is not None and self._yaw is not None and self._origin is not None
        remaining = torch.tensor([m.remaining - 1 for m in self.members])
        local, root, new = self.engine.output_fn(self._state.pose, self._yaw, self._origin, remaining, memory, shift)
        memory.update(new)
        local, root = self.engine.pipeline.arrival(local, root, remaining, [m.arrival for m in self.members])
        seq = []
        for m in self.members:
            seq.append(m.seq)
            m.seq += 1
        return StepOutput(list(self.members), local, root, seq)
