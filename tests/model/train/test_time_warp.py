"""Time-warped training windows (model/train/time_warp.py): the warp's arithmetic, the fractional
gather, and warped windows in a sampler run."""

from __future__ import annotations

import json
import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.data.synthetic import synthetic_walk, write_synthetic_dataset
from model.train import sampler_stage
from model.train.batches import make_batch, make_warped_batch
from model.train.motion_tensors import MotionTensors
from model.train.sampler_config import SamplerStageConfig
from model.train.time_warp import MAX_FACTOR, draw_factors, source_span, warp_times, warped_rows
from rsmt_cli.main import main
from tests.model.train.test_control_windows import smoke_config

pytestmark = pytest.mark.usefixtures("one_thread")


@settings(max_examples=60, deadline=None)
@given(length=st.integers(1, 60), factor=st.floats(1 / MAX_FACTOR, MAX_FACTOR), ramp=st.integers(0, 20))
def test_a_warp_covers_its_factor_of_frames_moving_forward_from_the_context_speed(length, factor, ramp):
    tau, speed = warp_times(length, torch.tensor([factor], dtype=torch.float64), ramp)
    assert tau[0, -1].item() == pytest.approx(factor * length, rel=1e-9)
    steps = torch.diff(torch.cat([torch.zeros(1, 1, dtype=tau.dtype), tau], 1), dim=1)
    assert bool((steps >= -1e-12).all())  # the replay never runs backwards
    r = min(ramp, length / 2)
    # The speed leaves the context's (1) gradually: no frame changes it by more than the ramp allows.
    change = torch.diff(torch.cat([torch.ones(1, 1, dtype=speed.dtype), speed], 1), dim=1).abs()
    v = speed[0, -1].item()
    assert change.max().item() <= abs(v - 1) / max(r, 1) + 1e-9 if r >= 1 else True
    # Each frame's advance is the speed integrated over it: between the speeds at its two ends.
    ends = torch.cat([torch.ones(1, 1, dtype=speed.dtype), speed], 1)
    lo, hi = torch.minimum(ends[:, :-1], ends[:, 1:]), torch.maximum(ends[:, :-1], ends[:, 1:])
    assert bool(((steps >= lo - 1e-9) & (steps <= hi + 1e-9)).all())


def test_factor_one_is_the_capture_itself_and_factors_stay_in_range():
    tau, speed = warp_times(12, torch.tensor([1.0, 1.0]), 5)
    assert torch.equal(tau, torch.arange(1, 13, dtype=torch.float64).expand(2, 12)) and bool((speed == 1).all())
    rows, speed = warped_rows(torch.tensor([100, 7]), 4, 3, torch.tensor([1.0, 2.0]), 0)
    assert rows[0].tolist() == [100, 101, 102, 103, 104, 105, 106]
    assert rows[1].tolist() == [7, 8, 9, 10, 12, 14, 16] and speed[1].tolist() == [1, 1, 1, 1, 2, 2, 2]
    f = draw_factors(500, 2.0, torch.Generator().manual_seed(0))
    assert 0.5 <= f.min().item() < 0.6 and 1.8 < f.max().item() <= 2.0
    assert source_span(10, 40, 2.0) == 91
    for bad in (0.9, MAX_FACTOR + 1):
        with pytest.raises(ValueError, match="warp"):
            draw_factors(2, bad, torch.Generator())
    with pytest.raises(ValueError, match="positive"):
        warp_times(4, torch.tensor([0.0]), 2)
    for bad_cfg in ({"warp_batch": -1}, {"warp_factor": 0.5}, {"warp_ramp": -2}, {"w_warp_foot": -1.0}):
        with pytest.raises(ValueError, match="warp"):
            SamplerStageConfig(**bad_cfg)


@pytest.fixture(scope="module")
def walk_tensors() -> MotionTensors:
    walk = synthetic_walk(frames=120, turn_deg_s=20.0)
    tensors = MotionTensors.from_clips([(walk, 0, "walk")], ["normal"], walk.skeleton, None, False, 0, False)
    n, m = tensors.positions.shape[0], 3
    angle = torch.arange(n, dtype=torch.float32).unsqueeze(1) * 0.2 + torch.arange(m)
    tensors.amplitude = 1.0 + 0.01 * torch.arange(n, dtype=torch.float32).unsqueeze(1).expand(n, m)
    tensors.phase = torch.stack([angle.cos(), angle.sin()], -1) * tensors.amplitude.unsqueeze(-1)
    tensors.frequency = torch.full((n, m), 0.2 / (2 * math.pi))
    return tensors


def test_the_fractional_gather_agrees_with_the_capture_on_its_frames_and_between_them(walk_tensors):
    t = walk_tensors
    starts = torch.tensor([3, 40])
    pos, rot = t.gather(starts, 20)
    rows = starts.unsqueeze(1).double() + torch.arange(20, dtype=torch.float64)
    fpos, frot = t.gather_at(rows)
    torch.testing.assert_close(fpos, pos)
    torch.testing.assert_close(frot, rot / rot.norm(dim=-1, keepdim=True))
    half, _ = t.gather_at(rows[:, :-1] + 0.5)
    torch.testing.assert_close(half, 0.5 * (pos[:, :-1] + pos[:, 1:]))
    phase, amp, freq = t.gather_phase_at(rows[:, :-1] + 0.5, torch.full((2, 19), 2.0))
    torch.testing.assert_close(phase.norm(dim=-1), amp)
    torch.testing.assert_close(freq, torch.full_like(freq, 2 * 0.2 / (2 * math.pi)))


def test_a_warped_window_is_the_plain_window_at_factor_one_and_ends_on_the_capture_k_times_further(walk_tensors):
    t = walk_tensors
    starts, owners = torch.tensor([5, 30]), torch.tensor([0, 0])
    plain = make_batch(t, starts, owners, 4 + 10, 3)
    same = make_warped_batch(t, starts, owners, 4, 10, torch.tensor([1.0, 1.0]), 3)
    torch.testing.assert_close(same.states.vector(), plain.states.vector(), atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(same.phase, plain.phase)
    fast = make_warped_batch(t, starts, owners, 4, 10, torch.tensor([2.0, 2.0]), 3)
    far = make_batch(t, starts, owners, 4 + 20, 3)  # the capture 20 frames on, in the same canonical frame
    end, want = fast.states.index((slice(None), -1)), far.states.index((slice(None), -1))
    for a, b in ((end.rel, want.rel), (end.rot, want.rot), (end.root_xz, want.root_xz)):  # the pose; its speed doubled
        torch.testing.assert_close(a, b, atol=1e-3, rtol=1e-4)
    torch.testing.assert_close(fast.states.index((slice(None), slice(0, 4))).vector(),
                               plain.states.index((slice(None), slice(0, 4))).vector())
    # Twice the ground in the same frames: the root's travel over the transition about doubles.
    travel = (fast.states.root_xz[:, -1] - fast.states.root_xz[:, 3]).norm(dim=-1)
    base = (plain.states.root_xz[:, -1] - plain.states.root_xz[:, 3]).norm(dim=-1)
    assert bool((travel > 1.7 * base).all())


@pytest.mark.slow  # trains every stage
def test_a_sampler_run_trains_on_warped_windows(tmp_path, monkeypatch):
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    data = tmp_path / "data"
    write_synthetic_dataset(data)
    drawn: list[torch.Tensor] = []
    real = sampler_stage.make_warped_batch

    def spy(tensors, starts, owners, context, length, factor, ramp, with_phase=True):
        drawn.append(factor)
        return real(tensors, starts, owners, context, length, factor, ramp, with_phase)

    monkeypatch.setattr(sampler_stage, "make_warped_batch", spy)
    path = tmp_path / "warp.json"
    cfg = smoke_config(target_velocity_drop=0.5, warp_batch=3, warp_factor=2.0, warp_ramp=4, w_warp_foot=0.5)
    path.write_text(json.dumps(cfg))
    assert main(["train", "all", "--config", str(path), "--data", str(data), "--out", str(tmp_path / "out"),
                 "--run", str(tmp_path / "run"), "--quiet"]) == 0
    assert len(drawn) == 8 and all(len(f) == 3 and bool(((f >= 0.5) & (f <= 2.0)).all()) for f in drawn)
    saved = json.loads((tmp_path / "run" / "train_config.json").read_text())
    assert saved["sampler_stage"]["warp_batch"] == 3
    history = json.loads((tmp_path / "run" / "sampler" / "checkpoint.json").read_text())["history"]
    assert history[-1]["train_warp_fk_cm"] > 0 and history[-1]["train_warp_foot"] >= 0


@pytest.mark.slow  # trains every stage twice
def test_the_decoder_trains_with_the_sampler_only_when_asked(tmp_path, monkeypatch):
    from model.inference.bundle import Bundle
    from model.nets.manifold import ManifoldDecoder
    from model.train.pipeline import TrainConfig, load_stage_weights

    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    data = tmp_path / "data"
    write_synthetic_dataset(data)
    moved = {}
    for train_decoder in (False, True):
        run, out = tmp_path / f"run-{train_decoder}", tmp_path / f"out-{train_decoder}"
        path = tmp_path / f"cfg-{train_decoder}.json"
        path.write_text(json.dumps(smoke_config(warp_batch=2, train_decoder=train_decoder)))
        assert main(["train", "all", "--config", str(path), "--data", str(data), "--out", str(out), "--run", str(run),
                     "--quiet"]) == 0
        manifold = ManifoldDecoder(TrainConfig.load(run / "train_config.json").manifold)
        load_stage_weights(manifold, run / "manifold", "manifold")  # the decoder its own stage trained
        shipped = Bundle.load(out).sampler.decoder.state_dict()
        moved[train_decoder] = max(float((shipped[k] - v).abs().max()) for k, v in manifold.state_dict().items())
    assert moved[False] == 0.0 and moved[True] > 0.0
