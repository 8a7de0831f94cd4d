"""Stage 3: train the style-conditioned sampler on top of the frozen manifold decoder.

Each batch holds windows of one style: ``context`` frames, then a transition of ``L`` frames whose
last frame is the target; every window is paired with a style clip from another window of the
same style. ``L`` follows a curriculum from short to long transitions. The settings are in
:mod:`model.train.sampler_config`, the rollouts in :mod:`model.train.sampler_rollout` and the
losses in :mod:`model.train.sampler_losses`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from model.evaluation.metrics import ground_levels
from model.motion.features import local_frame_features
from model.nets.sampler import TransitionSampler
from model.nets.style_classifier import StyleClassifier
from model.train.batches import WindowBatch, make_batch, make_warped_batch
from model.train.loop import LoopResult, resolve_device, step_generator, train_loop
from model.train.motion_tensors import MotionTensors
from model.train.sampler_config import CRITIC_INPUTS, SamplerStageConfig, cross_style_weights, curriculum_length
from model.train.sampler_losses import acceleration_profile, score_rollout, transition_losses, weighted_sum
from model.train.sampler_rollout import Rollout, concat_batches, rollout
from model.train.step_compiler import compiled_steps
from model.train.style_code_loss import supervised_contrastive, time_mean_code
from model.train.time_warp import draw_factors, source_span

Tensor = torch.Tensor

# The losses a training step reports (progress bar, history), and those validation reports.
SHOWN_TRAIN = ("pos", "fk_error_cm", "last_fk_error_cm", "foot", "phase", "acc", "style_acc", "foot_height", "spectrum")
SHOWN_VALIDATION = ("fk_error_cm", "last_fk_error_cm", "foot", "phase", "estimator", "acc", "style_acc", "foot_height",
                    "spectrum")


def style_statistics(tensors: MotionTensors, frames: int, samples: int = 2048, seed: int = 0) -> tuple[Tensor, Tensor]:
    """Per-channel mean and std of style-clip features over random training windows."""
    starts, _ = tensors.window_starts(frames, max(1, frames // 4))
    gen = torch.Generator().manual_seed(seed)
    pick = starts[torch.randperm(len(starts), generator=gen)[:samples]]
    feats = []
    for chunk in pick.split(256):
        pos, rot = tensors.gather(chunk, frames)
        feats.append(local_frame_features(pos, rot, tensors.skeleton).flatten(0, 1))
    x = torch.cat(feats)
    return x.mean(0), x.std(0).clamp_min(1e-2)


class StylePairs:
    """Windows grouped by style, for content windows and for style clips."""

    def __init__(self, tensors: MotionTensors, length: int, style_frames: int, step: int = 5,
                 contents: Sequence[str] = ()) -> None:
        starts, owners = tensors.window_starts(length, step)
        sstarts, sowners = tensors.window_starts(style_frames, max(1, style_frames // 4))
        if contents:  # content windows of these contents only (style clips still from every take)
            ids = [k for k, c in enumerate(tensors.contents) if c in set(contents)]
            keep = torch.isin(tensors.content[owners], torch.tensor(ids, dtype=tensors.content.dtype))
            starts, owners = starts[keep], owners[keep]
        self.by_style: dict[int, tuple[Tensor, Tensor]] = {}
        self.clips_by_style: dict[int, tuple[Tensor, Tensor]] = {}
        for s in tensors.style.unique().tolist():
            m = tensors.style[owners] == s
            ms = tensors.style[sowners] == s
            if m.any() and ms.any():
                self.by_style[s] = (starts[m], owners[m])
                self.clips_by_style[s] = (sstarts[ms], sowners[ms])
        if not self.by_style:
            raise ValueError(f"no take is long enough for {length}-frame windows and {style_frames}-frame style clips")
        self.styles = sorted(self.by_style)

    def sample_cross(self, batch: int, gen: torch.Generator) -> tuple[Tensor, Tensor, Tensor, int]:
        """Content windows of one style with style clips of another: ``(starts, owners, clip starts, clip style)``."""
        if len(self.styles) < 2:
            raise ValueError("cross-style pairs need at least two styles")
        s = self.styles[int(torch.randint(len(self.styles), (1,), generator=gen))]
        others = [o for o in self.styles if o != s]
        o = others[int(torch.randint(len(others), (1,), generator=gen))]
        starts, owners = self.by_style[s]
        pick = torch.randint(len(starts), (batch,), generator=gen)
        cs, _ = self.clips_by_style[o]
        return starts[pick], owners[pick], cs[torch.randint(len(cs), (batch,), generator=gen)], o

    def sample(self, batch: int, gen: torch.Generator) -> tuple[Tensor, Tensor, Tensor]:
        s = self.styles[int(torch.randint(len(self.styles), (1,), generator=gen))]
        starts, owners = self.by_style[s]
        pick = torch.randint(len(starts), (batch,), generator=gen)
        cs, co = self.clips_by_style[s]
        # Prefer style clips from another take than the content window's, so style cannot be copied.
        cpick = torch.randint(len(cs), (batch,), generator=gen)
        same = co[cpick] == owners[pick]
        if same.any() and (co != co[0]).any():
            cpick[same] = torch.randint(len(cs), (int(same.sum()),), generator=gen)
        return starts[pick], owners[pick], cs[cpick]

    def sample_clip_sets(self, styles: int, clips: int, gen: torch.Generator) -> tuple[Tensor, Tensor]:
        """``clips`` style-clip starts of each of ``styles`` distinct styles (all when fewer): ``(starts, style ids)``."""
        chosen = torch.randperm(len(self.styles), generator=gen)[:styles].tolist()
        starts, ids = [], []
        for k in chosen:
            s = self.styles[k]
            cs, _ = self.clips_by_style[s]
            starts.append(cs[torch.randint(len(cs), (clips,), generator=gen)])
            ids.append(torch.full((clips,), s, dtype=torch.long))
        return torch.cat(starts), torch.cat(ids)


@dataclass
class CrossWindows:
    """The other-style windows of a step, generated in the batch's rollout after its own windows."""

    labels: Tensor | None  # the critics' class of the clips' style, per window
    clip_positions: Tensor  # [B, style_frames, J, 3] the style clips' joint positions


def frozen_critics(critics: Sequence[StyleClassifier], stage: SamplerStageConfig,
                   device: torch.device) -> tuple[StyleClassifier, ...]:
    """The style critics of the stage's style loss, checked, frozen and moved to ``device`` (none when ``w_style`` is 0)."""
    if stage.w_style <= 0:
        return ()
    if not critics:
        raise ValueError("w_style > 0 needs a style critic")
    for critic in critics:
        if critic.config.inputs not in CRITIC_INPUTS:
            raise ValueError(f"a style critic must read velocities only ({', '.join(CRITIC_INPUTS)}), "
                             f"not {critic.config.inputs!r}")
        if critic.styles != critics[0].styles:
            raise ValueError("the style critics must share one list of styles")
        critic.to(device).eval()
        for p in critic.parameters():
            p.requires_grad_(False)
    return tuple(critics)


class SamplerSteps:
    """The sampler stage's training step and validation, over the windows of one training run.

    Each step draws a transition length and a batch of same-style windows, and, once the later
    losses apply (``extra_losses_from``), other-style windows (generated in the same rollout) and
    changed-control windows; it scores them, weighs the losses and back-propagates their sum.
    Every random draw of a step comes from that step's own generator, in a fixed order, so a
    resumed run draws what it would have.
    """

    def __init__(self, model: TransitionSampler, train: MotionTensors, val: MotionTensors, stage: SamplerStageConfig,
                 critics: tuple[StyleClassifier, ...], device: torch.device) -> None:
        c = model.config
        self.model, self.train, self.val, self.stage, self.device = model, train, val, stage, device
        self.context, self.max_transition = c.context, c.max_transition
        self.pairs = StylePairs(train, c.context + stage.max_transition, stage.style_frames)
        # Changed-control windows from the takes of stage.control_contents (real backward, angled, dash gaits).
        self.control_pairs = (StylePairs(train, c.context + stage.max_transition, stage.style_frames,
                                         contents=stage.control_contents)
                              if stage.control_contents and stage.control_batch > 0 else self.pairs)
        # Warped windows read up to warp_factor times the transition's frames of the capture.
        self.warp_pairs = StylePairs(train, source_span(c.context, stage.max_transition, stage.warp_factor),
                                     stage.style_frames) if stage.warp_batch > 0 else None
        vpairs = StylePairs(val, c.context + stage.validation_transition, stage.style_frames, step=20)
        vgen = torch.Generator().manual_seed(stage.loop.seed + 1)
        self.val_sets = [vpairs.sample(16, vgen) for _ in range(4)]
        self.critics = critics
        self.class_of: Tensor | None = None
        if critics:
            # The critics' class of each of the data's style ids (-1: a style they were not trained on).
            known_styles = critics[0].styles
            self.class_of = torch.tensor([known_styles.index(n) if n in known_styles else -1 for n in train.styles])
        self.ground = ground_levels(train.positions, list(train.skeleton.feet)).to(device) if stage.w_foot_height > 0 else None
        # Loss weights by name; a loss a step did not compute (no critic, no ground truth) is skipped.
        self.base_weights = {"pos": stage.w_pos, "rot": stage.w_rot, "last_pos": stage.w_last_pos,
                             "last_rot": stage.w_last_rot, "phase": stage.w_phase, "foot": stage.w_foot, "fk": stage.w_fk,
                             "estimator": stage.w_estimator}
        self.weights = {**self.base_weights, "vel": stage.w_vel, "acc": stage.w_acc, "spectrum": stage.w_spectrum,
                        "foot_height": stage.w_foot_height, "style": stage.w_style, "clip_acc": stage.w_clip_acc}
        self.cross_weights = cross_style_weights(self.weights, stage)

    def labels_of(self, style_ids: Tensor) -> Tensor | None:
        """The critics' class of each style id (None without critics)."""
        return None if self.class_of is None else self.class_of[style_ids.cpu()].to(self.device)

    def features_of(self, style_starts: Tensor, tensors: MotionTensors) -> Tensor:
        """Style-clip features of the clips starting at ``style_starts``."""
        pos, rot = tensors.gather(style_starts, self.stage.style_frames)
        return local_frame_features(pos, rot, tensors.skeleton)

    def windows(self, starts: Tensor, owners: Tensor, length: int, tensors: MotionTensors | None = None) -> WindowBatch:
        """Windows of ``context + length`` frames, each in the frame of its last context frame."""
        return make_batch(self.train if tensors is None else tensors, starts, owners, self.context + length, self.context - 1)

    def train_step(self, i: int) -> dict[str, float]:
        """Step ``i``: draw, generate and score its windows, back-propagate the weighted losses; returns those shown."""
        stage, train = self.stage, self.train
        gen = step_generator(stage.loop.seed, i)
        longest = curriculum_length(i, stage)
        length = int(torch.randint(stage.min_transition, max(stage.min_transition, longest) + 1, (1,), generator=gen))
        starts, owners, style_starts = self.pairs.sample(stage.batch, gen)
        batch = self.windows(starts, owners, length)
        extra = i >= stage.extra_losses_from
        styled = bool(self.critics) and extra
        labels = self.labels_of(train.style[owners])
        feats = self.features_of(style_starts, train)
        scored = stage.batch  # the windows scored against their ground truth come first
        if extra and self.warp_pairs is not None:
            # Drawn after the batch's own, so runs without warped windows draw what they did.
            batch, feats, labels = self.add_warped_windows(batch, feats, labels, length, gen)
            scored += stage.warp_batch
        cross = None
        if styled and stage.cross_batch > 0 and length >= stage.style_loss_min_frames:
            # Windows with a style clip of another style, generated in the same rollout as the batch's own:
            # the recurrent loop's cost is mostly per operation, not per window (about 0.2 s a step saved).
            batch, feats, cross = self.add_cross_windows(batch, feats, length, gen)
        r = rollout(self.model, train, batch, feats, length, stage, gen, True)
        losses = score_rollout(r, train, stage, slice(0, scored), self.critics if styled else (), labels,
                               ground=self.ground if extra else None)
        total = weighted_sum(losses, self.weights if extra else self.base_weights)
        shown = {k: v.item() for k, v in losses.items() if k in SHOWN_TRAIN}
        if scored > stage.batch:
            total = total + self.warp_terms(r, slice(stage.batch, scored), shown)
        if cross is not None:
            total = total + self.cross_terms(r, cross, shown, scored)
        if (extra or stage.control_from_start) and stage.control_batch > 0:
            total = total + self.control_terms(length, gen, shown)
        if stage.w_code_contrast > 0 and len(self.pairs.styles) > 1:
            total = total + stage.w_code_contrast * self.code_term(gen, shown)
        total.backward()
        return shown

    def code_term(self, gen: torch.Generator, shown: dict[str, float]) -> Tensor:
        """The style code's contrastive term (:mod:`model.train.style_code_loss`) on clips of several styles."""
        stage = self.stage
        starts, ids = self.pairs.sample_clip_sets(stage.code_contrast_styles, stage.code_contrast_clips, gen)
        code = self.model.encode_style(self.features_of(starts, self.train))
        loss = supervised_contrastive(time_mean_code(code), ids.to(code.device), stage.code_contrast_temperature)
        shown["code_contrast"] = loss.item()
        return loss

    def add_warped_windows(self, batch: WindowBatch, feats: Tensor, labels: Tensor | None, length: int,
                           gen: torch.Generator) -> tuple[WindowBatch, Tensor, Tensor | None]:
        """``batch``, its clips' features and critic labels followed by ``warp_batch`` time-warped windows
        (:mod:`model.train.time_warp`) of one style, with clips of that style at the capture's own speed."""
        stage = self.stage
        assert self.warp_pairs is not None
        ws, wo, wclips = self.warp_pairs.sample(stage.warp_batch, gen)
        factor = draw_factors(stage.warp_batch, stage.warp_factor, gen)
        warped = make_warped_batch(self.train, ws, wo, self.context, length, factor, stage.warp_ramp)
        wlabels = self.labels_of(self.train.style[wo])
        if labels is not None and wlabels is not None:
            labels = torch.cat([labels, wlabels])
        return concat_batches(batch, warped), torch.cat([feats, self.features_of(wclips, self.train)]), labels

    def warp_terms(self, r: Rollout, rows: slice, shown: dict[str, float]) -> Tensor:
        """The warped windows' extra foot term (``w_warp_foot`` times their own foot-slide loss, which the
        batch's mean weighs at ``w_foot`` only), and their joint error shown apart from the batch's."""
        with torch.set_grad_enabled(self.stage.w_warp_foot > 0):
            wl = score_rollout(r, self.train, self.stage, rows)
        shown["warp_fk_cm"] = wl["fk_error_cm"].item()
        shown["warp_foot"] = wl["foot"].item()
        return self.stage.w_warp_foot * wl["foot"] if self.stage.w_warp_foot > 0 else torch.zeros((), device=self.device)

    def add_cross_windows(self, batch: WindowBatch, feats: Tensor, length: int,
                          gen: torch.Generator) -> tuple[WindowBatch, Tensor, CrossWindows]:
        """``batch`` and its clips' features followed by ``cross_batch`` windows with clips of another style."""
        xs, xo, xclips, xstyle = self.pairs.sample_cross(self.stage.cross_batch, gen)
        xlabels = self.labels_of(torch.full((len(xs),), xstyle))
        batch = concat_batches(batch, self.windows(xs, xo, length))
        xpos, xrot = self.train.gather(xclips, self.stage.style_frames)
        feats = torch.cat([feats, local_frame_features(xpos, xrot, self.train.skeleton)])
        return batch, feats, CrossWindows(xlabels, xpos)

    def cross_terms(self, r: Rollout, cross: CrossWindows, shown: dict[str, float], first: int) -> Tensor:
        """The weighted losses of the other-style windows of ``r`` (no ground truth; its rows from ``first``
        on), scaled to the batch's."""
        stage = self.stage
        clip_acc = acceleration_profile(torch.diff(cross.clip_positions, dim=1)) if stage.w_clip_acc > 0 else None
        xl = score_rollout(r, self.train, stage, slice(first, None), self.critics, cross.labels, ground_truth=False,
                           ground=self.ground, clip_acc=clip_acc)
        if "style_acc" in xl:
            shown["cross_acc"] = xl["style_acc"].item()
        if "clip_acc" in xl:
            shown["clip_acc"] = xl["clip_acc"].item()
        return weighted_sum(xl, self.cross_weights) * (stage.cross_batch / stage.batch)

    def control_terms(self, length: int, gen: torch.Generator, shown: dict[str, float]) -> Tensor:
        """The weighted losses of the changed-control windows, scaled to the batch's."""
        cl = self.control_losses(length, gen)
        if "style_acc" in cl:
            shown["control_acc"] = cl["style_acc"].item()
        shown["control_last"] = cl["last_pos"].item()
        return weighted_sum(cl, self.weights) * (self.stage.control_batch / self.stage.batch)

    def control_losses(self, length: int, gen: torch.Generator) -> dict[str, Tensor]:
        """Windows of ``length`` frames with a scaled duration, a moved target or (with ``control_turn``) a
        turned target, in equal groups."""
        stage, train, k = self.stage, self.train, self.context
        n = stage.control_batch
        cs, co, cclips = self.control_pairs.sample(n, gen)
        scale = math.exp((2 * float(torch.rand(1, generator=gen)) - 1) * math.log(stage.control_dt))
        duration = max(stage.min_transition, min(self.max_transition, round(length * scale)))
        x = (2 * torch.rand(n, 1, generator=gen) - 1) * stage.control_shift
        side = (2 * torch.rand(n, 1, generator=gen) - 1) * stage.control_side if stage.control_side > 0 else None
        turn = (2 * torch.rand(n, generator=gen) - 1) * math.radians(stage.control_turn) if stage.control_turn > 0 else None
        groups = 2 if turn is None else 3
        bounds = [n * g // groups for g in range(groups + 1)]
        out: dict[str, list[Tensor]] = {}
        for g, kind in enumerate(("duration", "moved", "turned")[:groups]):
            rows = slice(bounds[g], bounds[g + 1])
            if rows.stop <= rows.start:
                continue
            cb = self.windows(cs[rows], co[rows], length)
            kw: dict = {}
            if kind == "moved":
                # The window's own root travel over the gap, scaled: the evaluation's "location" control;
                # and, with control_side, an offset across that travel.
                travel = cb.states.root_xz[:, k + length - 1] - cb.states.root_xz[:, k - 1]
                shift = travel * x[rows].to(travel.device)
                if side is not None:
                    across = torch.stack([-travel[:, 1], travel[:, 0]], -1)
                    across = across / across.norm(dim=-1, keepdim=True).clamp_min(1e-6)
                    shift = shift + across * side[rows].to(travel.device)
                kw["target_shift"] = shift
            elif kind == "turned":
                assert turn is not None
                kw["target_turn"] = turn[rows].to(self.device)
            else:
                kw["duration"] = duration
            losses = transition_losses(self.model, train, cb, self.features_of(cclips[rows], train), length, stage, gen,
                                       True, self.critics, self.labels_of(train.style[co[rows]]), ground_truth=False,
                                       ground=self.ground, **kw)
            for key, v in losses.items():
                out.setdefault(key, []).append(v)
        return {key: torch.stack(v).mean() for key, v in out.items()}

    def validate(self) -> dict[str, float]:
        """Mean validation losses over the fixed validation windows, ``validation_transition`` frames each."""
        sums: dict[str, float] = {}
        length = self.stage.validation_transition
        for starts, owners, style_starts in self.val_sets:
            batch = self.windows(starts, owners, length, self.val)
            out = transition_losses(self.model, self.val, batch, self.features_of(style_starts, self.val), length,
                                    self.stage, None, False, self.critics, self.labels_of(self.val.style[owners]),
                                    ground=self.ground)
            for k, v in out.items():
                sums[k] = sums.get(k, 0.0) + v.item() / len(self.val_sets)
        return {k: sums[k] for k in SHOWN_VALIDATION if k in sums}


def trained_parameters(model: TransitionSampler, decoder: bool = False) -> list[tuple[str, torch.nn.Parameter]]:
    """The parameters the sampler stage trains, in the optimiser's input order: all but the frozen decoder's
    (with ``decoder``, the decoder's too: ``SamplerStageConfig.train_decoder``)."""
    return [(n, p) for n, p in model.named_parameters() if decoder or not n.startswith("decoder.")]


def train_sampler(train: MotionTensors, val: MotionTensors, model: TransitionSampler, stage: SamplerStageConfig,
                  folder: Path, progress: bool = True, device: torch.device | str = "auto",
                  critics: Sequence[StyleClassifier] = (), compile: bool = False) -> tuple[TransitionSampler, LoopResult]:
    """Train every sampler module except the decoder, which stays frozen (gradients flow through it)
    unless ``stage.train_decoder``.

    ``model`` is moved to ``device`` (in place) and stays there. With ``stage.w_style`` above 0,
    ``critics`` (style classifiers trained on the training split, frozen) add a style loss on the
    generated frames, and ``stage.cross_batch`` windows per step get a style clip of another style
    (no ground truth: only the target and the critic's loss apply to them). ``compile`` runs the
    per-frame functions through ``torch.compile`` (:mod:`model.train.step_compiler`).
    """
    if stage.max_transition > model.config.max_transition:
        raise ValueError("the stage's max_transition exceeds the model's")
    dev = resolve_device(device)
    model.to(dev)
    train, val = train.to(dev), val.to(dev)
    mean, std = style_statistics(train, stage.style_frames, seed=stage.loop.seed)
    model.style_mean.copy_(mean)
    model.style_std.copy_(std)
    for p in model.decoder.parameters():
        p.requires_grad_(stage.train_decoder)
    params = trained_parameters(model, stage.train_decoder)
    steps = SamplerSteps(model, train, val, stage, frozen_critics(critics, stage, dev), dev)
    with compiled_steps(model, compile):
        result = train_loop("sampler", folder, model, params, stage.loop, steps.train_step, steps.validate, progress,
                            stage.lr_scales)
    model.eval()
    return model, result
