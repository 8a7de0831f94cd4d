"""``rsmt finetune-style``: 1 to 5 clips, and the adapted bundle carries the new style built in."""

from __future__ import annotations

import json

import pytest
import torch

from model.data.synthetic import synthetic_skeleton, write_synthetic_dataset
from model.inference.bundle import Bundle
from model.inference.engine import Engine
from model.motion.bvh_clip import load_clip
from model.nets.manifold import ManifoldConfig
from model.nets.phase import PhaseConfig
from model.nets.sampler import SamplerConfig
from rsmt_cli.main import main

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture()
def setup(tmp_path, monkeypatch):
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    cfg = SamplerConfig(joints=21, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=20)
    man = ManifoldConfig(joints=21, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    Bundle.create(synthetic_skeleton(), cfg, man, PhaseConfig(channels=63, phases=4, window=15, hidden=8)).save(tmp_path / "base")
    data = tmp_path / "data"
    paths = write_synthetic_dataset(data, takes_per_pair=2, frames=200)
    return tmp_path, data, sorted(p for p in paths if "_bouncy_" in str(p))


def _report(out: str) -> dict:
    return json.loads(out[out.index("\n{") + 1:])  # after the training loop's step lines


def _args(tmp_path, clips, *extra):
    return ["finetune-style", "--model", str(tmp_path / "base"), "--clips", *map(str, clips), "--name", "bouncy",
            "--out", str(tmp_path / "tuned"), "--iterations", "2", "--quiet", *extra]


def test_the_new_style_is_built_in_and_served_like_the_others(setup, capsys):
    tmp_path, data, bouncy = setup
    assert main(_args(tmp_path, bouncy[:3], "--data", str(data))) == 0
    captured = capsys.readouterr()
    report = _report(captured.out)
    assert "serve the two side by side" in captured.err  # the known styles are weaker in the adapted copy
    assert sorted(report["styles"]) == ["builtin:bouncy", "builtin:brisk", "builtin:slow"]
    tuned = Bundle.load(tmp_path / "tuned")
    assert sorted(tuned.styles) == ["bouncy", "brisk", "slow"]
    new = tuned.styles["bouncy"]
    assert new.version == tuned.version != Bundle.load(tmp_path / "base").version
    assert "fine-tuning clip" in new.source
    # The stored code is the adapted engine's encoding of the clip's middle, as the server would compute it.
    engine = Engine(Bundle.load(tmp_path / "tuned", styles=False), threads=1)
    longest = max((load_clip(p) for p in bouncy[:3]), key=lambda c: c.num_frames)
    start = (longest.num_frames - new.frames) // 2
    fresh, _ = engine.encode_style(longest.window(start, start + new.frames))
    assert torch.allclose(fresh.context.keys1, new.context.keys1, atol=1e-5)


def test_without_data_only_the_new_style_is_built_in(setup, capsys):
    tmp_path, _, bouncy = setup
    assert main(_args(tmp_path, bouncy[:1])) == 0
    captured = capsys.readouterr()
    assert _report(captured.out)["styles"] == ["builtin:bouncy"]
    assert "give --data DATA" in captured.err
    assert sorted(Bundle.load(tmp_path / "tuned").styles) == ["bouncy"]


def test_clip_count_and_name_are_checked_before_training(setup, capsys):
    tmp_path, _, bouncy = setup
    six = (bouncy * 3)[:6]
    assert main(_args(tmp_path, six)) == 2
    assert "--clips takes 1 to 5 clips" in capsys.readouterr().err
    args = _args(tmp_path, bouncy[:3])
    args[args.index("bouncy")] = "no spaces allowed"
    assert main(args) == 2
    assert not (tmp_path / "tuned").exists() and not (tmp_path / ".finetune-bouncy").exists()


def test_rehearsal_of_the_known_styles_is_asked_for_and_needs_the_data(setup, capsys):
    tmp_path, data, bouncy = setup
    assert main(_args(tmp_path, bouncy[:3], "--data", str(data))) == 0  # the default: --data builds styles in, no rehearsal
    notes = Bundle.load(tmp_path / "tuned").meta.notes
    assert "rehearsing" not in notes and "every sampler weight" in notes
    capsys.readouterr()
    args = _args(tmp_path, bouncy[:3], "--data", str(data), "--rehearsal", "--scope", "style")
    args[args.index(str(tmp_path / "tuned"))] = str(tmp_path / "tuned2")
    assert main(args) == 0
    assert "a run with other settings (rehearsal, scope) is replaced" in capsys.readouterr().err  # the default folder
    notes = Bundle.load(tmp_path / "tuned2").meta.notes
    assert "rehearsing brisk, slow" in notes and "FiLM/attention linears only" in notes
    args = _args(tmp_path, bouncy[:3], "--rehearsal")
    args[args.index(str(tmp_path / "tuned"))] = str(tmp_path / "tuned3")
    assert main(args) == 2
    assert "--rehearsal trains on the bundle's training data" in capsys.readouterr().err
    assert not (tmp_path / "tuned3").exists()


def test_a_run_folder_of_other_settings_is_refused_not_mixed_in(setup, capsys):
    tmp_path, _, bouncy = setup
    run = tmp_path / "run"
    assert main(_args(tmp_path, bouncy[:2], "--run", str(run))) == 0
    assert main(_args(tmp_path, bouncy[:2], "--run", str(run))) == 0  # the same request: resumed (already finished)
    capsys.readouterr()
    assert main(_args(tmp_path, bouncy[:2], "--run", str(run), "--scope", "style")) == 2
    assert "other settings (scope)" in capsys.readouterr().err
    stray = tmp_path / "stray"
    stray.mkdir()
    (stray / "notes.txt").write_text("mine")
    assert main(_args(tmp_path, bouncy[:2], "--run", str(stray))) == 2
    assert "holds no fine-tuning request" in capsys.readouterr().err
    # The default folder is ours: an earlier run there without a request is replaced, not refused.
    default = tmp_path / ".finetune-bouncy"
    default.mkdir()
    (default / "checkpoint.json").write_text("{}")
    assert main(_args(tmp_path, bouncy[:2])) == 0
    assert "an earlier run without a request is replaced" in capsys.readouterr().err
