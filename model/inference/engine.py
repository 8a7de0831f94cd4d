"""The inference engine: style encoding with a cache, transitions as explicit per-character state
(:mod:`model.inference.character`), one weight set per style adapter beside the bundle's own, and a
batch that advances every live character in one step per weight set (:mod:`model.inference.character_batch`).

Motion comes in and goes out in the caller's world frame on the model's rig: local x,y,z,w
rotations and the root position. Inside, each transition works in its own canonical frame (the
last context frame facing +Z over the origin), fixed when it starts.
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import torch

from model.inference.bundle import Bundle
from model.inference.character import (
    Aim,
    Character,
    CharacterRequest,
    EncodedStyle,
    Limits,
    Parked,
    PreparedStart,
    StepOutput,
    WeightSet,
)
from model.inference.character_batch import CharacterBatch, by_weights, inverse_of, restate_held
from model.inference.controls import Controls
from model.inference.errors import (
    EngineError,
    FramesOutOfRange,
    NoNeutralStyle,
    SkeletonMismatch,
    TooFewFrames,
    TooManyFrames,
)
from model.inference.int8_step import int8_lstm_sampler
from model.inference.output.arrival import ArrivalState
from model.inference.output.pipeline import OutputPipeline
from model.inference.overrides import Overrides
from model.inference.reach import Reach, ground_distance, reach_of
from model.inference.style_codes import LRUCache, clip_content_hash
from model.inference.style_strength import NeutralStyle
from model.inference.traced_step import CompiledFrameOutput, CompiledStep
from model.motion.clip import Clip
from model.motion.features import CanonicalFrame, FacingChains, local_frame_features
from model.motion.kinematics import forward_kinematics, global_to_local_rotations
from model.motion.rotations import quat_normalize, quat_to_sixd
from model.motion.skeleton import Skeleton
from model.nets.hybrid_net import MATCH_COST_LIMIT, HybridNet
from model.nets.matching_net import MatchingNet
from model.nets.pose_state import PoseState, state_from_positions
from model.nets.transition_net import NetState, TransitionNet

Tensor = torch.Tensor
log = logging.getLogger(__name__)
SOURCES = ("network", "matching", "hybrid")
RAW_OUTPUT = Overrides(steering=0, foot_lock=False, stride_warp=0.0, smoothing=0.0, root_smoothing=0.0)
__all__ = ["Character", "CharacterBatch", "CharacterRequest", "EncodedStyle", "Engine", "StepOutput", "WeightSet"]


class Engine:
    """Serves one bundle. Thread settings are process-wide torch settings, applied here once."""

    def __init__(self, bundle: Bundle, threads: int | None = None, cache_entries: int = 1024,
                 cache_bytes: int = 256 << 20, compiled: bool = True, overrides: Overrides | None = None,
                 source: str = "network", max_frames: int | None = None) -> None:
        """``overrides``: a caller's changes to the bundle's output steps and inference settings
        (:class:`model.inference.overrides.Overrides`; None keeps them all).
        ``compiled=False`` runs the per-frame step and the output steps in eager PyTorch instead of
        their traced graphs (:mod:`model.inference.traced_step`): slower, for debugging.
        ``source``: what makes the motion, one of :data:`SOURCES`: ``network`` (the bundle's network, and its style
        adapters), ``matching`` (windows of the bundle's motion database, :mod:`model.nets.matching_net`) or
        ``hybrid`` (those windows where they match the request, the network elsewhere: :mod:`model.nets.hybrid_net`).
        ``max_frames``: a caller's cap on a transition's frames below the model's own (:attr:`max_frames`)."""
        overrides = overrides or Overrides()
        self._frames_cap = max_frames
        # Played capture is real motion already blended onto its target: the matching source's frames leave as
        # played unless the caller asks for an output step (on val its joint error was 1.36 against 2.00 cm with them).
        self.output = overrides.output(RAW_OUTPUT.output(bundle.output) if source == "matching" else bundle.output)
        self.inference = overrides.inference(bundle.inference)
        if threads:
            torch.set_num_threads(threads)
        self.bundle = bundle
        self.source = source
        self.net: TransitionNet = self._source_net(bundle, source)  # behind the seam (model.nets.transition_net)
        for p in self.net.parameters():
            p.requires_grad_(False)
        self.skeleton: Skeleton = bundle.skeleton
        self.config = bundle.config
        self.styles: LRUCache[EncodedStyle] = LRUCache(cache_entries, cache_bytes, size_of=lambda s: s.nbytes)
        self._offsets = self.skeleton.offsets_tensor()
        # Every step a frame goes through before it leaves (model.inference.output.pipeline): steering in the
        # per-frame step, the frame steps in one traced graph, exact arrival after it.
        self.pipeline = OutputPipeline(self.skeleton, self.config.fps, self.output)
        # One weight set per style adapter beside the bundle's own; a character runs on its style's.
        self._compiled = compiled
        self.facing = FacingChains.of(self.skeleton)  # the skeleton's facing chains, for steering the facing
        self.weight_sets = {"": self._weight_set("", self.net, bundle.version)}
        for name, adapter in sorted(bundle.adapters.items() if source == "network" else ()):
            self.weight_sets[name] = self._weight_set(name, adapter.apply(self.net), adapter.version)
        self.step_fn = self.weight_sets[""].step_fn
        self.output_fn = CompiledFrameOutput(self.pipeline.frame, traced=compiled)
        self._ids = itertools.count()
        self.gait_limits = bundle.gait_limits  # the capture's speed per style (None: the root is not capped)
        if self.output.foot_plant and (self.gait_limits is None or not any(
                math.isfinite(s.planted_rise_cm) for s in self.gait_limits.styles.values())):
            log.warning("the foot plant is on but %s's gait limits give no style a planted rise: it moves no foot "
                        "(rsmt bundle gait-limits measures them)", bundle.meta.name)
        # Style strength moves every style from the mean of the bundle's own built-in styles: their network contexts,
        # so under another source (whose style contexts are of another kind) there is no neutral style.
        own = [s.context for s in bundle.styles.values()
               if not s.weights and isinstance(s.context, self.net.style_type)]
        self.neutral_style = NeutralStyle.of(own) if own else None
        self._usable_strength(self.inference.style_strength)
        self.aim_within_reach = True  # the network aims at the nearest point in reach of a target out of reach

    @staticmethod
    def _source_net(bundle: Bundle, source: str) -> TransitionNet:
        if source == "network":
            return bundle.net.eval()
        if source not in SOURCES:
            raise EngineError(f"unknown motion source {source!r}; one of {', '.join(SOURCES)}")
        if bundle.database is None:
            raise EngineError(f"model {bundle.meta.name!r} has no motion database for the {source} source: build one "
                              "with `rsmt bundle database BUNDLE --from-data DATA`")
        matching = MatchingNet(bundle.config, bundle.database)
        if source == "matching":
            return matching.eval()
        return HybridNet(bundle.sampler, matching, MATCH_COST_LIMIT).eval()

    def _weight_set(self, name: str, net: TransitionNet, version: str) -> WeightSet:
        """The per-frame step: traced (measured twice as fast at batch 1) unless asked for eager, with int8
        recurrent cells where the bundle asks for them (the float32 network still warms up on the context)."""
        stepper = net
        if self.inference.int8_lstm:
            quantized = int8_lstm_sampler(net)
            if quantized is None:  # this torch cannot: say so in self.inference
                self.inference = self.inference.with_overrides(int8_lstm=False)
            else:
                stepper = quantized
        step = CompiledStep(stepper, self.skeleton.roles.root, self.pipeline.steering, traced=self._compiled,
                            facing=self.facing)
        return WeightSet(name, net, step, version)

    def _usable_strength(self, strength: float) -> None:
        """A :class:`NoNeutralStyle` where ``strength`` is not 1 and there is no neutral style: the bundle has no
        built-in styles, or the engine runs another motion source than the network."""
        if strength != 1.0 and self.neutral_style is None:
            if self.source != "network":
                raise NoNeutralStyle(f"style_strength moves the network's style codes; model {self.bundle.meta.name!r} "
                                     f"runs the {self.source} source here, which plays capture (send 1 or leave it out, "
                                     "or serve the network source)")
            raise NoNeutralStyle(f"style_strength needs built-in styles to find the neutral style; model "
                                 f"{self.bundle.meta.name!r} has none (send 1 or leave it out)")

    def context_of(self, request: CharacterRequest) -> Any:
        """The context of ``request``'s style as this engine runs it: at the request's ``style_strength``, or the
        inference settings' where it set none."""
        if self.neutral_style is None:  # only strength 1 is accepted then
            return request.style.context
        strength = request.controls.get("style_strength")
        return self.neutral_style.scaled(request.style.context,
                                         self.inference.style_strength if strength is None else float(strength))

    def check_controls(self, given: Mapping[str, Any] | None) -> Controls:
        """The settings a request set for itself (:class:`Controls`), checked against their declarations and
        against what this engine can do with them; an :class:`EngineError` names the one that is not."""
        try:
            controls = Controls.of(given)
        except ValueError as exc:
            raise EngineError(str(exc)) from None
        strength = controls.get("style_strength")
        if strength is not None:
            self._usable_strength(float(strength))
        return controls

    def weights(self, name: str = "") -> WeightSet:
        """The weight set ``name`` (``""``: the bundle's own); an unknown name is a ValueError naming the sets."""
        found = self.weight_sets.get(name)
        if found is None:
            raise ValueError(f"model {self.name!r} has no weights {name!r}; its style adapters: "
                             f"{', '.join(n for n in self.weight_sets if n) or 'none'}")
        return found

    # ------------------------------------------------------------------ description
    @property
    def name(self) -> str:
        return self.bundle.meta.name

    @property
    def max_frames(self) -> int:
        """Longest transition accepted: twice the training horizon. Beyond the horizon the
        time-to-arrival code saturates (as RSMT's does), so the model walks on as if far from the
        target until the remaining frames fall inside what it was trained on. A cap given to the engine
        (the service's ``RSMT_MAX_TRANSITION_FRAMES``) lowers it."""
        own = 2 * self.config.max_transition
        return own if self._frames_cap is None else min(own, self._frames_cap)

    def check_frames(self, frames: int) -> None:
        """The one check of a transition's length: 1 to :attr:`max_frames` (:class:`TooManyFrames` above it,
        :class:`FramesOutOfRange` below 1), the message naming the model and the range."""
        if not 1 <= frames <= self.max_frames:
            error = TooManyFrames if frames > self.max_frames else FramesOutOfRange
            raise error(f"frames must be between 1 and {self.max_frames} for model {self.name!r}; got {frames}")

    @property
    def version(self) -> str:
        return self.bundle.version

    def max_speed(self, style: EncodedStyle) -> float | None:
        """The most the root of a character of ``style`` moves on the ground (cm/s): its built-in style's capture
        maximum, the largest of them for a style registered from a clip; None where the bundle has no gait limits."""
        return None if self.gait_limits is None else self.gait_limits.max_speed(style.gait or None)

    def limits_of(self, style: EncodedStyle) -> Limits:
        """The caps of a character of ``style``: its root's ground step (cm a frame) at its capture's top speed, its
        feet's lift off the floor and its planted feet's rise at its capture's; none where the bundle has no gait
        limits. The batch hands them to the steps that read them as columns."""
        if self.gait_limits is None:
            return Limits()
        gait = style.gait or None
        return Limits(self.gait_limits.max_speed(gait) / self.config.fps, self.gait_limits.foot_lift(gait),
                      self.gait_limits.planted_rise(gait))

    def _within_reach(self, style: EncodedStyle, root_xz: Tensor, goal: PoseState,
                      frames: int) -> tuple[PoseState, Reach | None]:
        """The reach notice of a character of ``style`` for the target state ``goal`` (canonical frame) ``frames``
        frames away from a root at ``root_xz [1, 2]``, and the target the network is to aim at: ``goal``, or where it
        is out of reach (and :attr:`aim_within_reach`), ``goal`` moved toward the root until the capture's speed
        covers it, so the network walks there at a gait it knows and arrives short instead of hurrying (the notice
        still names the true target; exact arrival does not bend the frames of one out of reach, :attr:`Aim.bent_to`)."""
        speed = self.max_speed(style)
        if speed is None:
            return goal, None
        root = self.skeleton.roles.root
        reach = reach_of(ground_distance(root_xz, goal.positions(), root), frames, speed, self.config.fps)
        if reach.feasible or not self.aim_within_reach:
            return goal, reach
        ahead = goal.root_xz - root_xz
        aim = root_xz + ahead * (reach.reachable_cm / max(reach.distance_cm, 1e-6))
        return PoseState(goal.rel, goal.vel, goal.rot, aim), reach

    # ------------------------------------------------------------------ input
    def conform(self, clip: Clip, what: str = "motion") -> Clip:
        """Map a clip onto the model's rig by joint name and resample it to the model's fps.

        Joint rotations are matched in world space, so extra joints in the input's hierarchy
        are ignored without bending the pose; missing joints are an error naming them.
        """
        sk = self.skeleton
        src = clip.skeleton
        if src.names == sk.names and src.parents == sk.parents:
            out = clip
        else:
            lookup = {n.rsplit(":", 1)[-1].lower(): i for i, n in enumerate(src.names)}
            idx, missing = [], []
            for n in sk.names:
                i = lookup.get(n.lower())
                (missing.append(n) if i is None else idx.append(i))
            if missing:
                raise SkeletonMismatch(f"{what} lacks joint(s) of the model's skeleton: {', '.join(missing)}")
            _, grot = clip.global_transforms()
            local = global_to_local_rotations(grot[:, idx], sk.parents)
            root = forward_kinematics(clip.rotations, clip.root_positions, src.offsets_tensor(clip.rotations.dtype),
                                      src.parents)[0][:, idx[0]]
            out = Clip(sk, local, root, clip.fps, clip.name)
        out = out.to(torch.float32)
        if abs(out.fps - self.config.fps) > 1e-6:
            out = out.resample(self.config.fps)
        return out

    def _global(self, clip: Clip) -> tuple[Tensor, Tensor]:
        return forward_kinematics(quat_normalize(clip.rotations), clip.root_positions, self._offsets, self.skeleton.parents)

    # ------------------------------------------------------------------ styles
    def style_id(self, clip: Clip, weights: str = "") -> str:
        return clip_content_hash(self.conform(clip, "style clip"), self.weights(weights).version)

    def style_code(self, clip: Clip, weights: str = "") -> Tensor:
        """The style encoder's code ``[1, T', C]`` of a clip already on this model's rig (see :meth:`conform`),
        by the weight set ``weights`` (the bundle's own by default)."""
        pos, rot = self._global(clip)
        with torch.inference_mode():
            return self.weights(weights).net.encode_style(local_frame_features(pos, rot, self.skeleton).unsqueeze(0))

    def style_clip(self, clip: Clip) -> Clip:
        """A style clip on this model's rig (:meth:`conform`), refused when its length is outside what the model reads."""
        clip = self.conform(clip, "style clip")
        c = self.config
        if not c.style_frames_min <= clip.num_frames <= c.style_frames_max:
            error = TooFewFrames if clip.num_frames < c.style_frames_min else TooManyFrames
            raise error(f"a style clip needs {c.style_frames_min} to {c.style_frames_max} frames at {c.fps:g} fps; "
                        f"got {clip.num_frames}")
        return clip

    def encode_style(self, clip: Clip, name: str = "", weights: str = "") -> tuple[EncodedStyle, bool]:
        """Encode a style clip, or return the cached encoding; the bool says whether it was cached.
        ``weights``: the weight set that encodes it and that its transitions run on (the bundle's own by
        default; a style adapter's name for that adapter's)."""
        clip = self.style_clip(clip)
        ws = self.weights(weights)
        sid = clip_content_hash(clip, ws.version)
        cached = self.styles.get(sid)
        if cached is not None:
            return cached, True
        code = self.style_code(clip, weights)
        with torch.inference_mode():
            ctx = ws.net.style_context(code)
        style = EncodedStyle(sid, name or sid, clip.num_frames, ctx, ctx.nbytes, weights)
        self.styles.put(sid, style)
        return style, False

    # ------------------------------------------------------------------ transitions
    def prepare(self, context: Clip, target: Clip, frames: int, style: EncodedStyle, seed: int | None = None,
                deterministic: bool = False, character_id: str | None = None, exact_arrival: bool = False,
                retargeted: bool = False, controls: Mapping[str, Any] | None = None) -> Character:
        """Validate a transition request and build its (unbatched) initial state.

        With ``exact_arrival`` the last frames are bent so the arrival frame equals the target pose
        exactly (:mod:`model.inference.output.arrival`); otherwise the network's own arrival is returned.
        ``retargeted`` starts the character as one retargeted mid-stream (its facing is finished by the
        retarget window): a stream resumed on another server after a retarget, from the frames received.
        ``controls``: the settings the request set for itself by name (``per_request`` in
        :mod:`model.inference.declared_settings`, e.g. ``{"style_strength": 1.5}``; one left out: the engine's).
        """
        c = self.config
        checked = self.check_controls(controls)
        self.check_frames(frames)
        context = self.conform(context, "context")
        target = self.conform(target, "target")
        if context.num_frames < c.context:
            raise TooFewFrames(f"the context needs at least {c.context} frames at {c.fps:g} fps; got {context.num_frames}")
        context = context.window(context.num_frames - c.context, context.num_frames)
        cpos, crot = self._global(context)
        frame = CanonicalFrame.at_frame(cpos.unsqueeze(0), self.skeleton, c.context - 1)
        cstate = state_from_positions(frame.positions_to(cpos.unsqueeze(0)),
                                      quat_to_sixd(frame.rotations_to(crot.unsqueeze(0))), self.skeleton.roles.root)
        tstate, known = self._target_state(target, frame)
        gen = None if deterministic else torch.Generator().manual_seed(
            int(seed) if seed is not None else int(time.time_ns() % (2**62)))
        noise = self.net.noise(gen)
        arrival = (self.pipeline.arrival.start(quat_normalize(target.rotations[-1]), target.root_positions[-1])
                   if exact_arrival else None)
        request = CharacterRequest(character_id or f"c{next(self._ids)}", style, frames, retargeted, checked)
        steer, reach = self._within_reach(style, cstate.root_xz[:, -1], tstate, frames)
        memory = self.pipeline.frame.start(quat_normalize(context.rotations), context.root_positions)
        return Character(request, Aim(tstate, known, reach, arrival), self.limits_of(style),
                         parked=Parked(frame, memory, PreparedStart(cstate, steer, frames, noise, known),
                                       ArrivalState(root=context.root_positions[-1].clone())))

    @torch.inference_mode()
    def begin(self, characters: list[Character], contexts: list[Any] | None = None) -> NetState:
        """Warm the recurrent core of prepared characters on their contexts, all in one batch; ``contexts``: their
        style contexts as the batch runs them (by default from their requests, :meth:`context_of`). Returns their
        rows and changes nothing of theirs (whoever takes the rows replaces their :class:`Parked` parts)."""
        inits = [None if c.parked is None else c.parked.prepared for c in characters]
        if any(i is None for i in inits):
            raise ValueError("character was not prepared by Engine.prepare, or has begun already")
        starts = [i for i in inits if i is not None]
        ctx = PoseState.cat([i.context for i in starts])
        tgt = PoseState.cat([i.target for i in starts])
        frames = torch.tensor([i.frames for i in starts])
        noise = torch.cat([i.noise for i in starts])
        known = torch.tensor([i.velocity_known for i in starts])
        if contexts is None:
            contexts = [self.context_of(c.request) for c in characters]
        style = self.net.style_type.stack(contexts)
        groups = by_weights(characters)
        if len(groups) == 1:
            return self.weights(groups[0][0]).net.begin(ctx, tgt, frames, noise, style, velocity_known=known)
        parts = [self.weights(w).net.begin(ctx.index(idx), tgt.index(idx), frames[idx], noise[idx], style.index(idx),
                                               velocity_known=known[idx]) for w, idx in groups]
        return type(parts[0]).stack(parts).index(inverse_of(groups))

    def _target_state(self, target: Clip, frame: CanonicalFrame) -> tuple[PoseState, bool]:
        """The target's state in the transition's frame, and whether its velocity is known (a frame before it
        was given). Without one, models trained with the velocity flag are told so; older ones get a
        zero velocity (arrive at rest)."""
        tail = target.window(max(0, target.num_frames - 2), target.num_frames)
        pos, rot = self._global(tail)
        pos = frame.positions_to(pos.unsqueeze(0))
        rot6 = quat_to_sixd(frame.rotations_to(rot.unsqueeze(0)))
        known = tail.num_frames > 1
        if not known:
            pos, rot6 = torch.cat([pos, pos], dim=1), torch.cat([rot6, rot6], dim=1)
        return state_from_positions(pos, rot6, self.skeleton.roles.root).index((slice(None), 1)), known

    def retarget(self, ch: Character, batch: CharacterBatch | None = None, target: Clip | None = None,
                 frames: int | None = None) -> Reach | None:
        """Change where and/or when a live character arrives, from its next frame on (``batch``: the batch it is
        live in or waits to join, if any; one waiting joins it first); returns its reach notice from where it now
        stands (also kept in ``ch.aim``; None where the bundle has no gait limits)."""
        if frames is not None:
            self.check_frames(frames)
        self._row(ch, batch)  # one waiting joins, one not begun is warmed up
        request, aim = ch.request, ch.aim
        if target is not None:
            target = self.conform(target, "target")
            goal, known = self._target_state(target, self._begun(ch).frame if batch is None else batch.frame_of(ch))
            arrival = None if aim.arrival is None else self.pipeline.arrival.start(
                quat_normalize(target.rotations[-1]), target.root_positions[-1])
            aim = Aim(goal, known, aim.reach, arrival)
            request = replace(request, retargeted=True)
        if frames is not None:
            request = replace(request, frames=ch.seq + frames)
        if request is not ch.request:
            self._restate(ch, request, batch)
        return self._reaim(ch, batch, aim, frames, rewrite=target is not None or frames is not None)

    def _row(self, ch: Character, batch: CharacterBatch | None) -> NetState:
        """A live character's network row (a copy in a batch), warmed up first if it has not begun: with the others
        waiting to join ``batch``, as its first step would, or on its own out of one."""
        if batch is not None:
            batch.admit()
            return batch.row_of(ch)
        row = self._begun(ch).row
        assert row is not None
        return row

    def _reaim(self, ch: Character, batch: CharacterBatch | None, aim: Aim, frames: int | None,
               rewrite: bool) -> Reach | None:
        """Work out ``ch``'s reach for ``aim`` from where it now stands, with the frames it has left and its style's
        capture speed, hand it the new :class:`Aim` whole, and write the target fields of its row (a new ``frames``
        left: its ``tta`` too) where ``rewrite`` says its target or time changed or the network is to aim nearer (out
        of reach). Returns the reach notice."""
        row = self._row(ch, batch)
        steer, reach = self._within_reach(ch.style, row.pose.root_xz, aim.goal, ch.remaining)
        ch.aim = replace(aim, reach=reach)  # the engine's view of the target, handed over whole
        updates: dict[str, Tensor] = {} if frames is None else {"tta": torch.tensor([frames])}
        if rewrite or steer is not aim.goal:
            with torch.inference_mode():
                updates.update(self.weights(ch.style.weights).net.target_fields(
                    row, steer, torch.tensor([aim.velocity_known]), torch.tensor([ch.remaining])))
        if batch is not None:
            batch.update_row(ch, updates)
        else:
            ch.update_row(updates)
        return reach

    def _begun(self, ch: Character) -> Parked:
        """The live part of a character out of a batch, warmed up on its context first if it has not begun."""
        if ch.parked is None:
            raise ValueError(f"character {ch.id!r} is in a batch: retarget it with that batch")
        if ch.parked.row is None:
            ch.parked = replace(ch.parked, state=self.begin([ch]))
        return ch.parked

    def _restate(self, ch: Character, request: CharacterRequest, batch: CharacterBatch | None) -> None:
        """Hand ``ch`` its new request: to the batch it is in, or to the character itself out of one."""
        if batch is not None:
            batch.restate(ch, request)
        else:  # an unknown weight set fails before anything changes
            restate_held(ch, request, self.limits_of(request.style), self.weights(request.style.weights))

    def set_style(self, ch: Character, style: EncodedStyle, batch: CharacterBatch | None = None) -> Reach | None:
        """Switch a character's style from its next frame (``batch``: the batch it is live in or waits to join, if
        any), with its style's caps. A style on other weights re-encodes the target by them; the recurrent state
        carries over. Its reach is worked out again at the new style's capture speed from where it now stands
        (exact arrival follows the new verdict); returns that notice (None where the bundle has no gait limits)."""
        if batch is None and ch.parked is None:
            raise ValueError(f"character {ch.id!r} is in a batch: switch its style with that batch")
        was_short = ch.reach is not None and not ch.reach.feasible and self.aim_within_reach  # its row aims nearer
        self._restate(ch, replace(ch.request, style=style), batch)
        if self.max_speed(style) is None:
            return None  # the bundle has no gait limits: no reach to work out
        return self._reaim(ch, batch, ch.aim, None, rewrite=was_short)

    def generate(self, characters: list[Character]) -> list[tuple[Tensor, Tensor]]:
        """Run prepared characters to their end in one batch; ``(rotations [N,J,4], roots [N,3])`` each."""
        batch = CharacterBatch(self)
        for ch in characters:
            batch.add(ch)
        rots: dict[str, list[Tensor]] = {ch.id: [] for ch in characters}
        roots: dict[str, list[Tensor]] = {ch.id: [] for ch in characters}
        while len(batch):
            out = batch.step()
            for i, ch in enumerate(out.characters):
                rots[ch.id].append(out.rotations[i])
                roots[ch.id].append(out.root_positions[i])
            batch.drop_finished()
        return [(torch.stack(rots[ch.id]), torch.stack(roots[ch.id])) for ch in characters]
