"""The style-conditioned motion sampler: style encoder, FiLM and attention, the recurrent core, one step.

Per transition, the style clip is encoded once into a code that keeps its time axis, and turned
into a :class:`StyleContext` (FiLM scales and shifts, attention keys and values). Per character,
everything that changes frame to frame lives in a :class:`SamplerState`. Modules keep nothing
between calls, so any set of characters (with any styles) can be stacked into one batch, and
interleaved calls cannot leak state into each other (the reference code's FiLM and attention
blocks cache per-sequence tensors on themselves).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import ClassVar

import torch
from torch import nn

from model.motion.rotations import sixd_normalize
from model.nets.manifold import ManifoldDecoder
from model.nets.phase import PhaseEstimator, advance_phase, blend_phase
from model.nets.pose_state import PoseState, state_dim
from model.nets.tensor_record import TensorRecord

Tensor = torch.Tensor


@dataclass
class SamplerConfig:
    """Shapes and schedules of the sampler.

    Attributes:
        joints, phases, latent: must match the manifold's.
        context: context frames given before a transition (the last is the current pose).
        max_transition: most frames a transition may last; the time-to-arrival code saturates there.
        style_frames_min / style_frames_max: accepted style clip lengths (frames at the model fps).
        style_channels: width of the style code.
        width: width of the state, offset and target encoders and of the style blocks.
        rnn: LSTM hidden size.
        head: width of the output head.
        noise_std: scale of the per-transition target noise (RSMT: 0.5).
        noise_full_tta / noise_zero_tta: noise weight is 1 at or above the first, 0 below the second.
        fps: model frame rate.
        target_velocity_flag: the target encoder reads one more input, 1 when the target's velocity
            is known (a frame before the target was given) and 0 when it is not (its velocity is then
            zeroed): a game usually has the target frame alone. Off in models trained before it.
    """

    joints: int = 22
    phases: int = 8
    latent: int = 32
    context: int = 10
    max_transition: int = 60
    style_frames_min: int = 16
    style_frames_max: int = 240
    style_channels: int = 256
    width: int = 256
    rnn: int = 384
    head: int = 256
    noise_std: float = 0.5
    noise_full_tta: int = 30
    noise_zero_tta: int = 5
    fps: float = 30.0
    root: int = 0
    target_velocity_flag: bool = False

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> SamplerConfig:
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in names})

    @property
    def outputs(self) -> int:
        # phase (2M), amplitude (M), frequency (M), root velocity (3), root 6D delta (6), z
        return 4 * self.phases + 9 + self.latent


def style_input_dim(joints: int) -> int:
    return joints * 12


class StyleEncoder(nn.Module):
    """Style clip features ``[B, T, J*12]`` (normalised) to a code ``[B, T', C]`` that keeps time.

    Two stride-2 layers shorten the code about fourfold (120 frames give 27 steps): attention
    then reads a quarter of the keys every frame, which is what bounds throughput with hundreds
    of characters, while the code still spans the clip's rhythm.
    """

    def __init__(self, inputs: int, channels: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv1d(inputs, channels, 1), nn.ReLU(),
            nn.Conv1d(channels, channels, 3, stride=2), nn.ReLU(),
            nn.Conv1d(channels, channels, 3, stride=2), nn.ReLU(),
            nn.Conv1d(channels, channels, 3), nn.ReLU(),
        )

    def forward(self, features: Tensor) -> Tensor:
        return self.net(features.transpose(1, 2)).transpose(1, 2)


class FiLM(nn.Module):
    """Feature-wise modulation from the time-mean style code: ``y = (1 + g) * norm(x) + b``."""

    def __init__(self, style_channels: int, width: int) -> None:
        super().__init__()
        self.gen = nn.Sequential(nn.Linear(style_channels, width), nn.ELU(), nn.Linear(width, 2 * width))

    def context(self, code: Tensor) -> tuple[Tensor, Tensor]:
        gamma, beta = self.gen(code.mean(dim=1)).chunk(2, dim=-1)
        return gamma, beta

    @staticmethod
    def modulate(x: Tensor, gamma: Tensor, beta: Tensor) -> Tensor:
        return (1 + gamma) * nn.functional.layer_norm(x, x.shape[-1:]) + beta


class StyleAttention(nn.Module):
    """Single-head cross-attention from a frame's features to the style code's time steps."""

    def __init__(self, style_channels: int, width: int) -> None:
        super().__init__()
        self.query = nn.Linear(width, width)
        self.key = nn.Linear(style_channels, width)
        self.value = nn.Linear(style_channels, width)
        self.out = nn.Linear(width, width)
        self.scale = 1.0 / math.sqrt(width)

    def context(self, code: Tensor) -> tuple[Tensor, Tensor]:
        """``(keys [B, width, T'], values [B, T', width])``.

        Keys are stored transposed, once per style: the per-frame product ``q [B, 1, w] @ keys``
        then runs 4-6x faster at 128-512 characters than ``keys [B, T', w] @ q`` (measured on
        the development CPU: 0.15 against 0.58 ms at 128), and as fast at batch 1.
        """
        keys = self.key(nn.functional.layer_norm(code, code.shape[-1:]))
        return keys.transpose(1, 2).contiguous(), self.value(code)

    def attend(self, x: Tensor, keys: Tensor, values: Tensor, mask: Tensor) -> Tensor:
        q = self.query(nn.functional.layer_norm(x, x.shape[-1:]))
        scores = torch.bmm(q.unsqueeze(1), keys).squeeze(1) * self.scale
        attn = torch.softmax(scores.masked_fill(~mask, float("-inf")), dim=-1)
        return x + self.out(torch.bmm(attn.unsqueeze(1), values).squeeze(1))


@dataclass
class StyleContext(TensorRecord):
    """Everything a style contributes to every frame, computed once per style clip.

    All tensors have a leading batch dimension. Codes of different lengths share a batch by
    padding: ``mask [B, T']`` marks the real time steps, and attention ignores the rest. Keys are
    ``[B, width, T']`` (see :meth:`StyleAttention.context`), values ``[B, T', width]``.
    """

    TIME_AXES: ClassVar[dict[str, int]] = {"keys1": 2, "values1": 1, "keys2": 2, "values2": 1, "mask": 1}

    gamma1: Tensor
    beta1: Tensor
    keys1: Tensor
    values1: Tensor
    gamma2: Tensor
    beta2: Tensor
    keys2: Tensor
    values2: Tensor
    mask: Tensor


@dataclass
class SamplerState(TensorRecord):
    """Per-character state of a transition in progress (leading dim = characters)."""

    POSES: ClassVar[tuple[str, ...]] = ("pose",)
    FIXED: ClassVar[tuple[str, ...]] = ("target_vec", "target_pos", "target_rot", "target_emb", "noise")

    h: Tensor  # [B, rnn]
    c: Tensor  # [B, rnn]
    pose: PoseState
    phase: Tensor  # [B, M, 2]
    target_vec: Tensor  # [B, D] target state vector
    target_pos: Tensor  # [B, J, 3] target positions (canonical frame)
    target_rot: Tensor  # [B, J, 6]
    target_emb: Tensor  # [B, width] encoded target, computed once
    tta: Tensor  # [B] frames left, including the next one
    noise: Tensor  # [B, 2*width]


def sinusoidal_table(rows: int, width: int) -> Tensor:
    """Transformer-style positional code for integers ``0..rows-1``: ``[rows, width]``."""
    pos = torch.arange(rows, dtype=torch.float32).unsqueeze(1)
    div = torch.exp(torch.arange(0, width, 2, dtype=torch.float32) * (-math.log(10000.0) / width))
    table = torch.zeros(rows, width)
    table[:, 0::2] = torch.sin(pos * div)
    table[:, 1::2] = torch.cos(pos * div)
    return table


def _mlp(inputs: int, hidden: int, outputs: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(inputs, hidden), nn.ELU(), nn.Linear(hidden, outputs))


class TransitionSampler(nn.Module):
    """The per-frame generator; the manifold decoder is attached frozen (``decoder``)."""

    state_type = SamplerState
    style_type = StyleContext
    # Buffers (registered in __init__).
    pe: Tensor
    style_mean: Tensor
    style_std: Tensor

    def __init__(self, config: SamplerConfig, decoder: ManifoldDecoder) -> None:
        super().__init__()
        c = config
        self.config = c
        d = state_dim(c.joints)
        w = c.width
        self.style_encoder = StyleEncoder(style_input_dim(c.joints), c.style_channels)
        self.state_encoder = _mlp(d, w, w)
        self.offset_encoder = _mlp(c.joints * 9, w, w)
        self.target_encoder = _mlp(d + int(c.target_velocity_flag), w, w)
        self.state_in = nn.Linear(w, w)
        self.film1 = FiLM(c.style_channels, w)
        self.attn1 = StyleAttention(c.style_channels, w)
        self.film2 = FiLM(c.style_channels, c.head)
        self.attn2 = StyleAttention(c.style_channels, c.head)
        self.lstm = nn.LSTMCell(3 * w, c.rnn)
        self.head_in = nn.Sequential(nn.Linear(c.rnn + 2 * c.phases + 2 * w, c.head), nn.ELU(), nn.Linear(c.head, c.head))
        self.head_out = nn.Sequential(nn.Linear(c.head, c.head), nn.ELU(), nn.Linear(c.head, c.outputs))
        self.phase_estimator = PhaseEstimator(d, c.context, c.phases)
        self.decoder = decoder
        self.register_buffer("pe", sinusoidal_table(c.max_transition + c.context + 1, w), persistent=False)
        # Normalisation of style clip features, filled from training statistics.
        self.register_buffer("style_mean", torch.zeros(style_input_dim(c.joints)))
        self.register_buffer("style_std", torch.ones(style_input_dim(c.joints)))
        self.act = nn.ELU()

    # ------------------------------------------------------------------ style
    def encode_style(self, features: Tensor) -> Tensor:
        """Style clip features ``[B, T, J*12]`` (unnormalised) to the code ``[B, T', C]``."""
        return self.style_encoder((features - self.style_mean) / self.style_std)

    def style_context(self, code: Tensor) -> StyleContext:
        g1, b1 = self.film1.context(code)
        k1, v1 = self.attn1.context(code)
        g2, b2 = self.film2.context(code)
        k2, v2 = self.attn2.context(code)
        mask = torch.ones(code.shape[:2], dtype=torch.bool, device=code.device)
        return StyleContext(g1, b1, k1, v1, g2, b2, k2, v2, mask)

    # ------------------------------------------------------------------ schedule
    def noise_weight(self, tta: Tensor) -> Tensor:
        c = self.config
        lam = (tta.float() - c.noise_zero_tta) / float(c.noise_full_tta - c.noise_zero_tta)
        return lam.clamp(0.0, 1.0)

    def time_code(self, tta: Tensor) -> Tensor:
        return self.pe.index_select(0, tta.clamp(0, self.pe.shape[0] - 1))

    # ------------------------------------------------------------------ transition
    def noise(self, generator: torch.Generator | None) -> Tensor:
        """One transition's target noise ``[1, 2*width]`` (zeros without a generator: deterministic output)."""
        c = self.config
        if generator is None:
            return torch.zeros(1, 2 * c.width)
        return torch.randn(1, 2 * c.width, generator=generator) * c.noise_std

    def target_fields(self, state: SamplerState, target: PoseState, velocity_known: Tensor,
                      frames: Tensor) -> dict[str, Tensor]:
        """The state's fields that hold a target ``[B, J, *]``, encoded by these weights (the state and the frames
        left do not change them: ``tta`` carries the frames)."""
        vec = self.target_input(target, velocity_known)
        return {"target_vec": vec, "target_pos": target.positions(), "target_rot": target.rot,
                "target_emb": self.target_encoder(vec)}

    def reencoded(self, state: SamplerState) -> dict[str, Tensor]:
        """The encoded target, by these weights (a style switch onto them)."""
        return {"target_emb": self.target_encoder(state.target_vec)}

    def target_input(self, target: PoseState, velocity_known: Tensor | None = None) -> Tensor:
        """The target encoder's input ``[B, D(+1)]`` for targets ``[B, J, *]``.

        ``velocity_known [B]`` (bool; None: all known) says which targets came with the frame before
        them. With ``target_velocity_flag`` an unknown velocity is zeroed and flagged 0; without it
        (older models) the vector is passed as it is.
        """
        vec = target.vector()
        if not self.config.target_velocity_flag:
            return vec
        if velocity_known is None:
            known = vec.new_ones(vec.shape[0], 1)
        else:
            known = velocity_known.to(vec.dtype).view(-1, 1)
        j = self.config.joints
        vel = vec[:, 3 * j : 6 * j] * known
        return torch.cat([vec[:, : 3 * j], vel, vec[:, 6 * j :], known], dim=-1)

    def begin(
        self,
        context: PoseState,
        target: PoseState,
        frames: Tensor,
        noise: Tensor,
        style: StyleContext,
        phase: tuple[Tensor, Tensor, Tensor] | None = None,
        velocity_known: Tensor | None = None,
    ) -> SamplerState:
        """Warm the recurrent core on the context and return the state before the first new frame.

        Args:
            context: ``[B, K, J, *]`` context frames in the transition's canonical frame.
            target: ``[B, J, *]`` the target frame (its velocity from the frame before it).
            frames: ``[B]`` frames to generate; the last one should reach the target.
            noise: ``[B, 2*width]`` per-transition noise (zeros for deterministic output).
            style: the batch's style contexts.
            phase: ``(phase [B, M, 2], amplitude [B, M], frequency [B, M])`` of the last context
                frame; estimated from the context (as in a live game) when None.
            velocity_known: ``[B]`` whether each target's velocity is known (:meth:`target_input`).
        """
        c = self.config
        b, k = context.rel.shape[0], context.rel.shape[1]
        ctx_vec = context.vector()  # [B, K, D]
        if phase is None:
            current, _, freq = self.phase_estimator(ctx_vec[:, -c.context :])
        else:
            current, _, freq = phase
        target_vec = self.target_input(target, velocity_known)
        state = SamplerState(
            h=ctx_vec.new_zeros(b, c.rnn), c=ctx_vec.new_zeros(b, c.rnn), pose=context.index((slice(None), k - 1)),
            phase=current, target_vec=target_vec, target_pos=target.positions(), target_rot=target.rot,
            target_emb=self.target_encoder(target_vec), tta=frames.long(), noise=noise,
        )
        # Warm-up: feed context frames 1..K-2 with phases rotated back from the current estimate.
        for i in range(1, k - 1):
            back = k - 1 - i
            ph = advance_phase(current, current.norm(dim=-1), -freq, back / c.fps)
            warm = SamplerState(
                h=state.h, c=state.c, pose=context.index((slice(None), i)), phase=ph, target_vec=target_vec,
                target_pos=state.target_pos, target_rot=state.target_rot, target_emb=state.target_emb,
                tta=state.tta + back, noise=noise,
            )
            state.h, state.c = self._core(warm, style)[:2]
        return state

    def _core(self, state: SamplerState, style: StyleContext) -> tuple[Tensor, Tensor, Tensor]:
        pe = self.time_code(state.tta)
        s = self.state_in(self.state_encoder(state.pose.vector()))
        s = self.act(FiLM.modulate(s, style.gamma1, style.beta1))
        s = self.act(self.attn1.attend(s, style.keys1, style.values1, style.mask)) + pe
        pos = state.pose.positions()
        offset = torch.cat([(state.target_pos - pos).flatten(1), (state.target_rot - state.pose.rot).flatten(1)], dim=-1)
        off = self.offset_encoder(offset) + pe
        tar = state.target_emb + pe
        ht = torch.cat([off, tar], dim=-1) + self.noise_weight(state.tta).unsqueeze(-1) * state.noise
        h, cell = self.lstm(torch.cat([s, ht], dim=-1), (state.h, state.c))
        return h, cell, ht

    def step(self, state: SamplerState, style: StyleContext) -> tuple[SamplerState, dict[str, Tensor]]:
        """Advance every character by one frame; returns the new state and the raw predictions."""
        c = self.config
        m = c.phases
        h, cell, ht = self._core(state, style)
        y = self.head_in(torch.cat([h, state.phase.flatten(1), ht], dim=-1))
        y = self.act(FiLM.modulate(y, style.gamma2, style.beta2))
        y = self.act(self.attn2.attend(y, style.keys2, style.values2, style.mask))
        out = self.head_out(y)
        p_hat = out[:, : 2 * m].view(-1, m, 2)
        amp = out[:, 2 * m : 3 * m]
        freq = out[:, 3 * m : 4 * m]
        root_vel = out[:, 4 * m : 4 * m + 3]
        root_drot = out[:, 4 * m + 3 : 4 * m + 9]
        z = out[:, 4 * m + 9 :]
        p_next = blend_phase(advance_phase(state.phase, amp, freq, 1.0 / c.fps), p_hat)
        root_rot = sixd_normalize(state.pose.rot[:, c.root] + root_drot)
        pose = self.decoder.step(state.pose, root_vel, root_rot, z, p_next)
        new = SamplerState(
            h=h, c=cell, pose=pose, phase=p_next, target_vec=state.target_vec, target_pos=state.target_pos,
            target_rot=state.target_rot, target_emb=state.target_emb, tta=state.tta - 1, noise=state.noise,
        )
        return new, {"phase_hat": p_hat, "amplitude": amp, "frequency": freq, "phase": p_next}
