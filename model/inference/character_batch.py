"""A batch of live characters whose states are stacked so that one step of each weight set advances them all.

While a character is a member, the batch owns its live part (:class:`model.inference.character.Parked`, taken whole
when it joins and given back whole when it is detached): its network state, canonical frame, output memory rows and
exact arrival's memory; besides them, its style context and its columns (the per-character inputs the steps declare:
its caps, whether it was retargeted). A retarget or a style switch hands the batch the character's new request
(:meth:`CharacterBatch.restate`), and the engine the character its new :class:`model.inference.character.Aim`;
nothing else writes the batch's rows."""

from __future__ import annotations

import copy
from dataclasses import replace
from typing import Any, Protocol

import torch

from model.inference.character import (
    Character,
    CharacterRequest,
    EncodedStyle,
    Limits,
    Parked,
    StepOutput,
    WeightSet,
)
from model.inference.output.arrival import ArrivalState
from model.inference.output.pipeline import OutputPipeline
from model.inference.output.smoothing import SPEED_CAP
from model.inference.output.speed_cap import kept_in_reach, speed_capped
from model.inference.output.steering import RETARGETED
from model.inference.traced_step import CompiledFrameOutput
from model.motion.features import CanonicalFrame
from model.motion.skeleton import Skeleton
from model.nets.transition_net import NetState

Tensor = torch.Tensor


@torch.inference_mode()
def restate_held(ch: Character, request: CharacterRequest, limits: Limits, ws: WeightSet) -> None:
    """Hand a character outside a batch its new request (a retarget or a style switch) and the caps of its style;
    ``ws``: its style's weights. A row it holds is re-encoded by them when they change (one not begun yet is encoded
    by :meth:`Engine.begin`)."""
    row = None if ch.parked is None else ch.parked.row
    if request.style.weights != ch.style.weights and row is not None:
        ch.update_row(ws.net.reencoded(row))
    ch.request, ch.limits = request, limits


class BatchEngine(Protocol):
    """What a batch needs of its engine (:class:`model.inference.engine.Engine`)."""

    output_fn: CompiledFrameOutput
    pipeline: OutputPipeline
    skeleton: Skeleton

    def begin(self, characters: list[Character], contexts: list[Any] | None = None) -> NetState: ...

    def weights(self, name: str = "") -> WeightSet: ...

    def context_of(self, request: CharacterRequest) -> Any: ...

    def limits_of(self, style: EncodedStyle) -> Limits: ...


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

    Characters added wait until :meth:`admit` joins them (the start of each :meth:`step`: one batched warm-up for
    every newcomer). Style contexts and columns are restacked there too, only when membership, a style or a request
    changed, not every frame.
    """

    def __init__(self, engine: BatchEngine) -> None:
        self.engine = engine
        self.members: list[Character] = []
        self._state: NetState | None = None
        self._contexts: list[Any] = []  # each member's style context, from its request as handed in
        self._style: Any = None  # the members' stacked style contexts
        self._yaw: Tensor | None = None
        self._origin: Tensor | None = None
        # The output pipeline's memory, a row per member (model.inference.output.pipeline.FrameSteps.memory_keys).
        self._memory: dict[str, Tensor] | None = None
        self._arrivals: list[ArrivalState] = []  # each member's exact arrival memory (model.inference.output.arrival)
        # The steps' columns (their declared per-character inputs, model.inference.output.pipeline), a row per member.
        self._names = tuple(dict.fromkeys((*engine.pipeline.loop_columns, *engine.pipeline.frame.columns)))
        self._columns: dict[str, Tensor] = {}
        self._pending: list[Character] = []
        self._changed = False  # membership, a style or a request changed since the last restack
        # The members by weight set: (weights, their rows, their style context); with several sets, the
        # index that puts the rows stepped set after set back in member order.
        self._groups: list[tuple[WeightSet, Tensor, Any]] = []
        self._inverse: Tensor | None = None

    def __len__(self) -> int:
        return len(self.members) + len(self._pending)

    def add(self, ch: Character) -> None:
        """Queue a prepared (or detached) character; it joins at the next :meth:`admit`."""
        if ch.parked is None:
            raise ValueError(f"character {ch.id!r} holds no live part: it was not prepared by Engine.prepare, or a "
                             "batch holds it (detach it from that one first)")
        self._pending.append(ch)

    def admit(self) -> None:
        """Join the characters waiting (newcomers warmed up in one batch, resumed ones with the rows they hold), and
        restack the style contexts and columns where membership, a style or a request changed. :meth:`step` starts
        with it; a caller that must read or change a waiting character's row before then calls it first."""
        if self._pending:
            waiting, self._pending = self._pending, []
            self._join(waiting)
        if self._changed and self.members:
            self._restack()

    def _join(self, waiting: list[Character]) -> None:
        """Stack ``waiting`` under the members; each hands its live part (:class:`Parked`) to the batch whole."""
        parts = [self._parked(c) for c in waiting]
        fresh = [c for c, p in zip(waiting, parts) if p.row is None]
        resumed = [p.row for p in parts if p.row is not None]
        joined = fresh + [c for c, p in zip(waiting, parts) if p.row is not None]
        contexts = [self.engine.context_of(c.request) for c in joined]
        rows = [] if self._state is None else [self._state]
        if fresh:
            rows.append(self.engine.begin(fresh, contexts[:len(fresh)]))  # one batched warm-up for every newcomer
        rows += resumed
        self._state = type(rows[0]).stack(rows)
        self._take_parts(joined)
        self.members.extend(joined)
        self._contexts.extend(contexts)
        self._changed = True

    @staticmethod
    def _parked(ch: Character) -> Parked:
        if ch.parked is None:
            raise ValueError(f"character {ch.id!r} holds no live part: a batch holds it")
        return ch.parked

    def _take_parts(self, joined: list[Character]) -> None:
        """The canonical frames, output memories and exact arrival memories of ``joined`` stacked under the
        members' (the characters hold no live part afterwards)."""
        parts = [self._parked(c) for c in joined]
        frames = [p.frame for p in parts]
        memories = [p.memory for p in parts]
        if self._yaw is not None and self._origin is not None:
            frames.insert(0, CanonicalFrame(self._yaw, self._origin))
        if self._memory is not None:
            memories.insert(0, self._memory)
        self._yaw = torch.cat([f.yaw for f in frames])
        self._origin = torch.cat([f.origin for f in frames])
        self._memory = {k: torch.cat([m[k] for m in memories]) for k in memories[0]}
        self._arrivals.extend(copy.copy(p.arrival) for p in parts)  # a replica's shared memory stays as it was
        for c in joined:
            c.parked = None

    def _restack(self) -> None:
        """The members' style contexts stacked and grouped by weight set, and their columns stacked."""
        self._style = type(self._contexts[0]).stack(self._contexts)
        groups = by_weights(self.members)
        whole = len(groups) == 1  # the usual case: the batch's style context as it is, no copy
        self._groups = [(self.engine.weights(w), idx, self._style if whole else self._style.index(idx))
                        for w, idx in groups]
        self._inverse = inverse_of(groups) if len(groups) > 1 else None
        self._columns = {k: torch.tensor([m.column(k) for m in self.members]) for k in self._names}
        self._changed = False

    @torch.inference_mode()
    def restate(self, ch: Character, request: CharacterRequest) -> None:
        """Hand a member (or a character waiting to join) its new request from the next frame: a retarget's or a
        style switch's. Its style's context and caps are taken from it; a style on other weights re-encodes its
        target by them."""
        ws = self.engine.weights(request.style.weights)  # an unknown weight set fails before anything changes
        limits = self.engine.limits_of(request.style)
        if ch not in self.members:  # waiting to join or resume
            restate_held(ch, request, limits, ws)
            return
        i = self.members.index(ch)
        if request.style.weights != ch.style.weights:
            self.update_row(ch, ws.net.reencoded(self.row_of(ch)))
        self._contexts[i] = self.engine.context_of(request)
        ch.request, ch.limits = request, limits
        self._changed = True

    def set_style(self, ch: Character, style: EncodedStyle) -> None:
        """Switch a member's style from the next frame (:meth:`restate` with its request in that style)."""
        self.restate(ch, replace(ch.request, style=style))

    def stacked(self) -> tuple[NetState, Any, Tensor, Tensor, dict[str, Tensor]]:
        """The members' stacked sampler state and style context, canonical frames (``yaw [N]``, ``origin [N, 3]``)
        and output steps' memory with their columns, as the next :meth:`step` reads them (after :meth:`admit`)."""
        self.admit()
        if self._state is None or self._style is None or self._yaw is None or self._origin is None \
                or self._memory is None:
            raise ValueError("no live characters in the batch")
        return self._state, self._style, self._yaw, self._origin, self._frame_inputs(self._memory)

    def _frame_inputs(self, memory: dict[str, Tensor]) -> dict[str, Tensor]:
        """The output steps' memory and their columns, as the frame steps read them."""
        return {**memory, **{k: self._columns[k] for k in self.engine.output_fn.fn.columns}}

    def _index(self, ch: Character) -> int:
        if ch not in self.members:
            raise ValueError(f"character {ch.id!r} is not a member of this batch (one waiting joins at admit())")
        return self.members.index(ch)

    def frame_of(self, ch: Character) -> CanonicalFrame:
        """A member's canonical frame (``yaw [1]``, ``origin [1, 3]``)."""
        i = self._index(ch)
        assert self._yaw is not None and self._origin is not None
        return CanonicalFrame(self._yaw[i : i + 1], self._origin[i : i + 1])

    def row_of(self, ch: Character) -> NetState:
        """A member's network state ``[1]`` (a copy)."""
        i = self._index(ch)
        assert self._state is not None
        return self._state.index(slice(i, i + 1))

    @torch.inference_mode()
    def update_row(self, ch: Character, updates: dict[str, Tensor]) -> None:
        """Set fields of a member's network state (``updates``: name -> ``[1, ...]``)."""
        i = self._index(ch)
        assert self._state is not None
        for k, v in updates.items():
            getattr(self._state, k)[i : i + 1] = v

    def remove(self, ch: Character) -> None:
        if ch in self._pending:
            self._pending.remove(ch)
            return
        self._keep([m for m in self.members if m is not ch])

    def detach(self, ch: Character) -> None:
        """Take a live character out of the batch, handing it back its live part (:class:`Parked`), so :meth:`add`
        resumes it.

        :meth:`remove` discards the state; this lets a scheduler pause one character (its client is
        not reading, say) while the others keep stepping. Costs one restack, like ``remove``.
        """
        if ch in self._pending:
            self._pending.remove(ch)
            return
        i = self._index(ch)
        assert self._state is not None and self._yaw is not None and self._origin is not None
        row = torch.tensor([i])
        assert self._memory is not None
        ch.parked = Parked(CanonicalFrame(self._yaw[row], self._origin[row]),
                           {k: v[i : i + 1].clone() for k, v in self._memory.items()},
                           self._state.index(row), self._arrivals[i])  # copies, and its arrival memory leaves with it
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
            self._memory, self._contexts, self._columns, self._arrivals = None, [], {}, []
            return
        rows = [self.members.index(k) for k in keep]
        idx = torch.tensor(rows)
        assert self._state is not None and self._yaw is not None and self._origin is not None
        self._state = self._state.index(idx)
        self._yaw, self._origin = self._yaw[idx], self._origin[idx]
        assert self._memory is not None
        self._memory = {k: v[idx] for k, v in self._memory.items()}
        self._contexts = [self._contexts[i] for i in rows]
        self._arrivals = [self._arrivals[i] for i in rows]
        self.members = keep
        self._changed = True

    @torch.inference_mode()
    def step(self) -> StepOutput:
        """Advance every member by one frame (after :meth:`admit`) and return their world-space poses."""
        self.admit()
        if not self.members:
            raise ValueError("no live characters to step")
        assert self._state is not None and self._style is not None
        retargeted = self._columns[RETARGETED]  # the rows that steer their facing by the retarget window
        late = retargeted if bool(retargeted.any()) else None
        caps = self._columns[SPEED_CAP]
        before = self._state.pose.root_xz.clone() if bool((caps < float("inf")).any()) else None
        if self._inverse is None:  # one weight set: the whole batch in one step
            self._state, shift = self._groups[0][0].step_fn(self._state, self._style, late)  # steering included
        else:
            parts = [ws.step_fn(self._state.index(idx), style, None if late is None else late[idx])
                     for ws, idx, style in self._groups]
            self._state = type(parts[0][0]).stack([p[0] for p in parts]).index(self._inverse)
            shifts = [p[1] for p in parts]
            shift = None if shifts[0] is None else torch.cat([s for s in shifts if s is not None])[self._inverse]
        if before is not None:  # each row's root within its style's capture speed (model.inference.output.speed_cap)
            self._state, shift = speed_capped(before, self._state, shift, caps)
            if self.engine.pipeline.steering.window > 0:  # ground steering on: its target kept within reach too
                self._state, shift = kept_in_reach(before, self._state, shift, caps, self.engine.skeleton.roles.root)
        memory = self._memory
        assert memory is not None and self._yaw is not None and self._origin is not None
        remaining = torch.tensor([m.remaining - 1 for m in self.members])
        local, root, new = self.engine.output_fn(self._state.pose, self._yaw, self._origin, remaining,
                                                 self._frame_inputs(memory), shift)
        memory.update({k: new[k] for k in memory})
        local, root = self.engine.pipeline.arrival(local, root, remaining, [m.aim.bent_to for m in self.members],
                                                   self._arrivals, caps)
        seq = []
        for m in self.members:
            seq.append(m.seq)
            m.seq += 1
        return StepOutput(list(self.members), local, root, seq)
