"""``rsmt finetune-style``: 1 to 5 clips; the bundle gains the new style built in, on an adapter of its own, and
keeps everything else as it was."""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys

import pytest
import torch

from model.data.synthetic import synthetic_skeleton, synthetic_walk, write_synthetic_dataset
from model.inference.bundle import Bundle
from model.inference.bundle_styles import StyleClip
from model.inference.engine import Engine
from model.inference.style_packing import write_builtin_styles
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
    write_builtin_styles(tmp_path / "base", [StyleClip(n, synthetic_walk(60, speed_cm_s=v), f"{n}.bvh")
                                             for n, v in (("brisk", 160.0), ("slow", 60.0))])
    data = tmp_path / "data"
    paths = write_synthetic_dataset(data, takes_per_pair=2, frames=200)
    return tmp_path, data, sorted(p for p in paths if "_bouncy_" in str(p))


def _report(out: str) -> dict:
    return json.loads(out[out.index("\n{") + 1:])  # after the training loop's step lines


def _args(tmp_path, clips, *extra):
    return ["finetune-style", "--model", str(tmp_path / "base"), "--clips", *map(str, clips), "--name", "bouncy",
            "--out", str(tmp_path / "tuned"), "--iterations", "2", "--quiet", *extra]


def _files(folder) -> dict[str, str]:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.slow  # fine-tunes a bundle
def test_the_new_style_is_built_in_on_its_own_weights_and_the_rest_is_kept(setup, capsys):
    tmp_path, _, bouncy = setup
    assert main(_args(tmp_path, bouncy[:3])) == 0
    report = _report(capsys.readouterr().out)
    assert report["styles"] == ["builtin:bouncy", "builtin:brisk", "builtin:slow"] and report["adapter_mb"] > 0
    # Where the time went, and the work: what a shared machine's wall time alone does not tell.
    times = report["timings_s"]
    assert set(times) == {"startup", "preparing", "training", "saving", "total"} and report["cpu_s"] > 0
    assert times["training"] == report["seconds"] and times["total"] >= times["training"] + times["saving"]
    base, tuned = _files(tmp_path / "base"), _files(tmp_path / "tuned")
    assert {k: v for k, v in tuned.items() if not k.startswith("adapters/")} == base  # weights and styles untouched
    bundle = Bundle.load(tmp_path / "tuned")
    new = bundle.styles["bouncy"]
    assert new.weights == "bouncy" and new.version == bundle.adapters["bouncy"].version != bundle.version
    assert bundle.styles["brisk"].weights == "" and "fine-tuning clip" in new.source
    assert "2 steps" in bundle.adapters["bouncy"].notes and "blend 0.5" in bundle.adapters["bouncy"].notes
    # The stored code is the adapted weights' encoding of the clip's middle, as the server would compute it.
    engine = Engine(bundle, threads=1)
    longest = max((load_clip(p) for p in bouncy[:3]), key=lambda c: c.num_frames)
    start = (longest.num_frames - new.frames) // 2
    fresh, _ = engine.encode_style(longest.window(start, start + new.frames), weights="bouncy")
    assert torch.allclose(fresh.context.keys1, new.context.keys1, atol=1e-5)


@pytest.mark.slow  # fine-tunes a bundle
def test_a_style_is_added_in_place_once(setup, capsys):
    tmp_path, _, bouncy = setup
    args = _args(tmp_path, bouncy[:2])
    args[args.index(str(tmp_path / "tuned"))] = str(tmp_path / "base")
    assert main(args) == 0
    assert sorted(Bundle.load(tmp_path / "base").styles) == ["bouncy", "brisk", "slow"]
    capsys.readouterr()
    assert main(args) == 2
    assert "already has a built-in style 'bouncy'" in capsys.readouterr().err


def test_clips_name_and_out_folder_are_checked_before_training(setup, capsys):
    tmp_path, _, bouncy = setup
    six = (bouncy * 3)[:6]
    assert main(_args(tmp_path, six)) == 2
    assert "--clips takes 1 to 5 clips" in capsys.readouterr().err
    args = _args(tmp_path, bouncy[:3])
    args[args.index("bouncy")] = "no spaces allowed"
    assert main(args) == 2
    assert not (tmp_path / "tuned").exists() and not (tmp_path / ".finetune-bouncy").exists()
    (tmp_path / "tuned").mkdir()
    (tmp_path / "tuned" / "mine.txt").write_text("keep")
    assert main(_args(tmp_path, bouncy[:3])) == 2
    assert "--out" in capsys.readouterr().err and not (tmp_path / ".finetune-bouncy").exists()
    (tmp_path / "tuned" / "mine.txt").unlink()  # an empty folder is fine
    args = _args(tmp_path, bouncy[:3])
    args[args.index("2")] = "0"
    assert main(args) == 2
    assert "--iterations must be at least 1" in capsys.readouterr().err
    assert main(_args(tmp_path, bouncy[:3], "--blend", "0")) == 2
    assert "--blend must be in (0, 1]" in capsys.readouterr().err
    args = _args(tmp_path, bouncy[:3])
    args[args.index("bouncy")] = "slow"  # a style the bundle has
    assert main(args) == 2
    assert "already has a built-in style 'slow'" in capsys.readouterr().err


@pytest.mark.slow  # fine-tunes a bundle
def test_a_run_folder_of_other_settings_is_refused_not_mixed_in(setup, capsys):
    tmp_path, _, bouncy = setup
    run = tmp_path / "run"
    assert main(_args(tmp_path, bouncy[:2], "--run", str(run))) == 0
    shutil.rmtree(tmp_path / "tuned")
    assert main(_args(tmp_path, bouncy[:2], "--run", str(run))) == 0  # the same request: resumed (already finished)
    capsys.readouterr()
    shutil.rmtree(tmp_path / "tuned")
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


def test_bad_clips_and_bundles_are_told_before_any_run_folder_is_made(setup, capsys):
    tmp_path, _, bouncy = setup
    assert main(_args(tmp_path, [*bouncy[:2], tmp_path / "missing.bvh"])) == 2
    assert "--clips " + str(tmp_path / "missing.bvh") + ": no such file" in capsys.readouterr().err
    assert main(_args(tmp_path, [bouncy[0], bouncy[1], bouncy[0]])) == 2
    assert "names the same file twice" in capsys.readouterr().err
    args = _args(tmp_path, bouncy[:3])
    args[args.index(str(tmp_path / "base"))] = str(tmp_path / "nowhere")
    assert main(args) == 2
    assert "--model " + str(tmp_path / "nowhere") + ": no such folder" in capsys.readouterr().err
    args[args.index(str(tmp_path / "nowhere"))] = str(tmp_path / "data")  # a folder, but no bundle
    assert main(args) == 2
    assert "is not a model bundle" in capsys.readouterr().err
    short = tmp_path / "short.bvh"  # 12 frames: too short for a style clip or a transition
    text = bouncy[0].read_text().splitlines()
    at = next(i for i, line in enumerate(text) if line.startswith("Frames:"))
    short.write_text("\n".join([*text[:at], "Frames: 12", text[at + 1], *text[at + 2:at + 14]]) + "\n")
    assert main(_args(tmp_path, [bouncy[0], bouncy[1], short])) == 2
    err = capsys.readouterr().err
    assert "short is too short: 12 frames at 30 fps; each clip needs at least 16" in err and "Traceback" not in err
    assert not (tmp_path / "tuned").exists() and not (tmp_path / ".finetune-bouncy").exists()


def _with_frame_time(text: str, frame_time: str) -> str:
    lines = text.splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("Frame Time:"))
    return "\n".join([*lines[:at], f"Frame Time: {frame_time}", *lines[at + 1:]]) + "\n"


def test_clips_the_service_refuses_are_refused_in_its_words_without_a_traceback(setup, capsys):
    """Issue 64: a Frame Time of 1e-310 gave an OverflowError traceback; non-ASCII digits were read as numbers."""
    tmp_path, _, bouncy = setup
    tiny = tmp_path / "tiny.bvh"
    tiny.write_text(_with_frame_time(bouncy[0].read_text(), "1e-310"))
    # As a user runs it: a process of its own, whose stderr must hold the message and no traceback.
    done = subprocess.run([sys.executable, "-m", "rsmt_cli", *_args(tmp_path, [tiny])], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 2, done.stderr[-2000:]
    assert f"rsmt: error: {tiny}:" in done.stderr and "Traceback" not in done.stderr
    assert "Frame Time 1e-310 s gives inf fps; accepted: 1 to 1000 fps (Frame Time 0.001 to 1 s)" in done.stderr
    arabic = tmp_path / "arabic.bvh"  # "93" in Arabic-Indic digits, which float() reads as 93.0
    lines = bouncy[0].read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("Frame Time:")) + 1
    values = lines[first].split()
    lines[first] = " ".join(["\u0669\u0663", *values[1:]])
    arabic.write_text("\n".join(lines) + "\n")
    assert main(_args(tmp_path, [bouncy[1], arabic])) == 2
    err = capsys.readouterr().err
    assert f"{arabic}:{first + 1}: '\u0669\u0663' is not a number" in err and "Traceback" not in err
    assert not (tmp_path / "tuned").exists() and not (tmp_path / ".finetune-bouncy").exists()
