"""The clients cut a whole take to what the model reads, the same way: the Python client (``rsmt_client.motion_cuts``),
the Unity core (``RsmtMotionCutter``, through the C# harness, compiled with mcs) and the Unreal core
(``rsmt::MotionCutter``, compiled with g++): a context to its last ``context_frames``, a target to its last two
frames, a style clip longer than the maximum to its middle, with one notice. Synthetic takes at 30 and 60 fps,
and a dataset take when the motion data is there. Skipped with a reason without Mono or g++."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
from rsmt_client.bvh import BvhFile
from rsmt_client.motion_cuts import Cutter, ModelLimits

from model.data.synthetic import synthetic_walk
from model.motion.bvh_clip import dump_clip
from tests.clients.helpers import build_core_test, run, run_harness

pytestmark = pytest.mark.slow  # builds the C# harness and the C++ tool
LIMITS = ModelLimits(fps=30.0, context_frames=10, style_min=16, style_max=240)
REAL_TAKE = "dataset-2_walk_elderly_001.bvh"


@pytest.fixture(scope="module")
def cut_tool(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_core_test(tmp_path_factory.mktemp("unreal-cut"), program="rsmt_cut_tool")


@pytest.fixture(scope="module")
def takes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("takes")
    out = {}
    for name, clip in (("walk30", synthetic_walk(300)), ("walk60", synthetic_walk(300).resample(60.0)),
                       ("short", synthetic_walk(8))):
        out[name] = d / f"{name}.bvh"
        out[name].write_text(dump_clip(clip))
    return out


def python_cut(what: str, path: Path, caplog: pytest.LogCaptureFixture) -> tuple[str, list[str]]:
    cutter = Cutter(LIMITS)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="rsmt_client"):
        payload = {"bvh": path.read_text()}
        if what == "style":
            cutter.style(payload)  # twice: said once
        cut = getattr(cutter, what)(payload)["bvh"]
    return cut, [r.getMessage() for r in caplog.records]


def same_motion(a: str, b: str) -> None:
    fa, fb = BvhFile.parse(a), BvhFile.parse(b)
    assert fa.names == fb.names and fa.frame_time == fb.frame_time and fa.num_frames == fb.num_frames
    np.testing.assert_array_equal(fa.motion, fb.motion)


def check_all_three(what: str, path: Path, harness_exe: Path, cut_tool: Path, tmp_path: Path,
                    caplog: pytest.LogCaptureFixture) -> str:
    expected, said = python_cut(what, path, caplog)
    unity, unreal = tmp_path / f"{path.stem}-{what}-unity.bvh", tmp_path / f"{path.stem}-{what}-unreal.bvh"
    cs = run_harness(harness_exe, "cut", "--what", what, "--fps", "30", "--context-frames", str(LIMITS.context_frames),
                     "--style-max", str(LIMITS.style_max), "--in", str(path), "--out", str(unity))
    assert cs.returncode == 0, cs.stderr[-2000:]
    cpp = run([str(cut_tool), what, "30", str(LIMITS.context_frames), str(LIMITS.style_max), str(path), str(unreal)],
              timeout=60, check=False)
    assert cpp.returncode == 0, cpp.stderr[-2000:]
    same_motion(expected, unity.read_text())
    same_motion(expected, unreal.read_text())
    frames = BvhFile.parse(expected).num_frames
    assert json.loads(cs.stdout)["frames"] == frames == json.loads(cpp.stdout)["frames"]
    cut_style = what == "style" and BvhFile.read(path).num_frames != frames
    for notices in (said, [line for line in cs.stderr.splitlines() if line.startswith("notice:")],
                    [line for line in cpp.stderr.splitlines() if line.startswith("notice:")]):
        assert len(notices) == (1 if cut_style else 0), notices
        if cut_style:
            assert "sending the middle" in notices[0]
    return expected


@pytest.mark.parametrize("what", ["context", "target", "style"])
def test_the_three_clients_cut_alike(what, takes, harness_exe, cut_tool, tmp_path, caplog) -> None:
    walk30 = BvhFile.read(takes["walk30"])
    cut = BvhFile.parse(check_all_three(what, takes["walk30"], harness_exe, cut_tool, tmp_path, caplog))
    want = {"context": (290, 10), "target": (298, 2), "style": (30, 240)}[what]
    np.testing.assert_array_equal(cut.motion, walk30.window(*want).motion)
    # At 60 fps the model's frames are every other one: the cuts keep what resamples to them.
    cut60 = BvhFile.parse(check_all_three(what, takes["walk60"], harness_exe, cut_tool, tmp_path, caplog))
    assert cut60.num_frames == {"context": 19, "target": 3, "style": 480}[what]


@pytest.mark.parametrize("what", ["context", "style"])
def test_what_the_model_reads_whole_is_sent_as_it_is(what, takes, harness_exe, cut_tool, tmp_path, caplog) -> None:
    text = check_all_three(what, takes["short"], harness_exe, cut_tool, tmp_path, caplog)  # 8 frames
    assert text == takes["short"].read_text()


@pytest.mark.real_data
def test_a_dataset_take_is_cut_alike(shared_data, harness_exe, cut_tool, tmp_path, caplog) -> None:
    folder = shared_data / "data" if (shared_data / "data").is_dir() else shared_data
    take = folder / REAL_TAKE
    if not take.is_file():
        pytest.skip(f"{take} is not in the motion data")
    for what in ("context", "target", "style"):
        cut = check_all_three(what, take, harness_exe, cut_tool, tmp_path, caplog)
        print(f"\n{REAL_TAKE} as {what}: {BvhFile.read(take).num_frames} frames, {take.stat().st_size} bytes -> "
              f"{BvhFile.parse(cut).num_frames} frames, {len(cut.encode())} bytes")
