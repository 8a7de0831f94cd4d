"""The sampler stage's settings: its schedule, the transitions it draws, and the weight of every loss."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from model.train.loop import LoopConfig
from model.train.time_warp import MAX_FACTOR

CRITIC_INPUTS = ("velocity", "dynamics", "acceleration")  # input selections that depend on positions only


@dataclass
class SamplerStageConfig:
    """Schedule, drawn transitions and loss weights of the sampler stage (saved in every ``train_config.json``)."""

    loop: LoopConfig = field(default_factory=lambda: LoopConfig(iterations=3000, epoch_iterations=300, lr=1e-3,
                                                                weight_decay=1e-4))
    batch: int = 32
    min_transition: int = 5
    max_transition: int = 60
    curriculum: float = 0.3  # fraction of training after which any length up to the maximum is drawn
    style_frames: int = 120
    gt_phase_probability: float = 0.5
    w_pos: float = 1.0
    w_rot: float = 1.0
    w_last_pos: float = 1.0
    w_last_rot: float = 0.5
    w_phase: float = 0.5
    w_foot: float = 0.05
    w_fk: float = 0.5
    w_estimator: float = 0.5
    w_vel: float = 0.0  # joint velocities against the ground truth's
    w_acc: float = 0.0  # each joint's mean acceleration against the ground truth's (acceleration_profile)
    w_spectrum: float = 0.0  # log power spectrum of joint velocities against the ground truth's (velocity_spectrum)
    w_foot_height: float = 0.0  # horizontal speed of generated feet at their ground height (planted_foot_speed)
    w_style: float = 0.0  # cross-entropy of the style critic on generated frames (0: no critic)
    cross_batch: int = 0  # windows per step with a style clip of another style (need w_style)
    # Those windows have no ground truth: this weighs each joint's mean acceleration over the transition
    # against the style clip's own (acceleration_profile), the clip being the only example of its style at hand.
    w_clip_acc: float = 0.0
    # The critics' loss on those other-style windows (None: w_style). They are the only windows that ask
    # the sampler to follow a clip against its context, and they are scored on little else.
    w_cross_style: float | None = None
    # Windows per step with changed controls, scored without ground truth (reaching the target, feet,
    # critics): half get a duration scaled by a factor in [1/control_dt, control_dt], half a target
    # moved by x times the window's own root travel, x in [-control_shift, control_shift] (the
    # evaluation's d = 2 and d = -1 are x = 1 and x = -2). Natural windows alone never ask for either.
    control_batch: int = 0
    control_dt: float = 2.0
    control_shift: float = 2.0
    # With control_turn above 0 (degrees) the changed-control windows come in three groups: the third
    # gets its target turned by an angle in [-control_turn, control_turn] about its own vertical axis.
    control_turn: float = 0.0
    # Moved targets also move up to this far (cm) across the window's travel (the evaluation's 1 m sideways).
    control_side: float = 0.0
    # Contents whose takes the changed-control windows come from (e.g. dataset 1's walk-back, walk-left,
    # walk-right, dash: real backward, angled and fast gaits to change the controls of); empty: every take.
    # Only the styles that have such takes then give changed-control windows. control_from_start: from step 0
    # on, not only once the extra losses apply (extra_losses_from).
    control_contents: tuple[str, ...] = ()
    control_from_start: bool = False
    # With steering_window above 0, the changed-control windows are steered as the engine steers a bundle
    # with that window (model.inference.output.steering): the shift carries no gradient, so their losses (feet,
    # target, critics) train the gait that goes with being carried toward the target.
    steering_window: int = 0
    # Time-warped windows per step (model.train.time_warp), scored against their ground truth like the batch's
    # own: the capture replayed from the last context frame at a speed that ramps over warp_ramp frames to
    # cover a factor in [1/warp_factor, warp_factor] of the transition's frames, so a request for twice the
    # distance or half the time has real feet and poses to learn from. Drawn only once the extra losses apply.
    warp_batch: int = 0
    warp_factor: float = 2.0
    warp_ramp: int = 10
    # The warped windows' own foot-slide loss (feet that the replay keeps planted), added with this weight on
    # top of the batch's mean: without it a sampler reaches further by gliding (docs/experiments/archive/2026-11-26-time-warp.md).
    w_warp_foot: float = 0.0
    # Train the manifold's decoder with the sampler (the paper freezes it after its own stage): whether a
    # decoder fitted to natural speeds is what keeps warped windows sliding (docs/experiments/archive/2026-11-26-time-warp.md).
    train_decoder: bool = False
    # The decoder's learning rate as a fraction of the stage's (with train_decoder): trained at the full rate from
    # stage F it cost pose accuracy and style (G6); a gentler rate keeps it near the manifold it was fitted as.
    decoder_lr_scale: float = 1.0
    # The fraction of training windows whose target comes without its velocity (the sampler's
    # target_velocity_flag tells it so): a game usually sends the target frame alone.
    target_velocity_drop: float = 0.0
    # Each critic's input selection (model.nets.style_classifier.INPUTS, velocity-based); the style loss is
    # their mean, so generated motion has to satisfy critics that read it differently, not one net's blind spots.
    critic_inputs: tuple[str, ...] = ("dynamics",)
    critic_epochs: int = 6
    critic_iterations: int = 150
    style_loss_min_frames: int = 16  # shorter transitions get no style loss: too short to show a style
    extra_losses_from: int = 0  # step from which w_vel, w_acc, w_spectrum, w_foot_height, w_style and cross pairs apply
    validation_transition: int = 40
    # The style code's own term (model.train.style_code_loss): each step, code_contrast_clips clips of each of
    # code_contrast_styles styles (all styles when fewer) are encoded and their time-mean codes scored by a
    # supervised contrastive loss at code_contrast_temperature, from step 0; 0: off. Against a code that
    # collapses or encodes content more than style, for styles the encoder never saw.
    w_code_contrast: float = 0.0
    code_contrast_styles: int = 8
    code_contrast_clips: int = 4
    code_contrast_temperature: float = 0.1

    def __post_init__(self) -> None:
        self.control_contents = tuple(self.control_contents)
        self._check_critic_inputs()
        self._check_extra_batches()
        self._check_control_and_warp()
        self._check_rates()

    def _check_critic_inputs(self) -> None:
        """Turn ``critic_inputs`` into a tuple and check it names distinct position-only selections."""
        if isinstance(self.critic_inputs, str):  # configs written before critics became a list
            self.critic_inputs = (self.critic_inputs,)
        self.critic_inputs = tuple(self.critic_inputs)
        bad = [c for c in self.critic_inputs if c not in CRITIC_INPUTS]
        if bad or not self.critic_inputs or len(set(self.critic_inputs)) != len(self.critic_inputs):
            # Critics read positions only (critic_logits): no gradient through 6D-to-quaternion conversions.
            raise ValueError(f"critic_inputs must be distinct selections among {', '.join(CRITIC_INPUTS)}, "
                             f"got {list(self.critic_inputs)!r}")

    def _check_extra_batches(self) -> None:
        """The other-style and changed-control window counts, and the other-style critics' weight."""
        if self.cross_batch < 0 or self.control_batch < 0:
            raise ValueError("cross_batch and control_batch must be 0 or more")
        if self.w_cross_style is not None and self.w_cross_style < 0:
            raise ValueError(f"w_cross_style must be 0 or more (or null: w_style), got {self.w_cross_style}")

    def _check_control_and_warp(self) -> None:
        """The ranges of the changed controls, the time-warped windows and the steering window."""
        if self.control_dt < 1.0 or self.control_shift < 0.0 or self.control_turn < 0.0 or self.control_side < 0.0:
            raise ValueError("control_dt must be at least 1, and control_shift, control_turn and control_side at least 0")
        if self.warp_batch < 0 or self.warp_ramp < 0 or self.w_warp_foot < 0 or not 1.0 <= self.warp_factor <= MAX_FACTOR:
            raise ValueError(f"warp_batch, warp_ramp and w_warp_foot must be 0 or more and warp_factor in [1, {MAX_FACTOR:g}]")
        if self.steering_window < 0:
            raise ValueError(f"steering_window must be 0 (off) or more frames, got {self.steering_window}")

    def _check_rates(self) -> None:
        """The target-velocity drop rate, the style code's contrastive term and the decoder's rate scale."""
        if not 0.0 <= self.target_velocity_drop <= 1.0:
            raise ValueError(f"target_velocity_drop must be in [0, 1], got {self.target_velocity_drop}")
        if self.w_code_contrast < 0 or self.code_contrast_styles < 2 or self.code_contrast_clips < 2:
            raise ValueError("w_code_contrast must be 0 or more, code_contrast_styles and code_contrast_clips 2 or more")
        if self.code_contrast_temperature <= 0:
            raise ValueError(f"code_contrast_temperature must be above 0, got {self.code_contrast_temperature}")
        if not 0.0 < self.decoder_lr_scale <= 1.0:
            raise ValueError(f"decoder_lr_scale must be in (0, 1], got {self.decoder_lr_scale}")

    @property
    def lr_scales(self) -> dict[str, float]:
        """The optimiser's rate multipliers by parameter-name prefix (the decoder's, when it trains)."""
        return {"decoder.": self.decoder_lr_scale} if self.train_decoder else {}


def cross_style_weights(weights: dict[str, float], stage: SamplerStageConfig) -> dict[str, float]:
    """The loss weights of the other-style windows: ``weights`` with the critics' at ``w_cross_style``."""
    return dict(weights) if stage.w_cross_style is None else {**weights, "style": stage.w_cross_style}


def curriculum_length(step: int, stage: SamplerStageConfig) -> int:
    """The longest transition drawn at ``step``: rises linearly from the shortest to the longest over
    the first ``curriculum`` fraction of training."""
    frac = min(1.0, step / max(1, stage.loop.iterations * stage.curriculum))
    return int(stage.min_transition + math.floor(frac * (stage.max_transition - stage.min_transition)))
