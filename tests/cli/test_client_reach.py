"""``rsmt client transition`` and ``rsmt client stream`` say whether the target was within reach, through a real
server of the default model (its bundle has gait limits): the notice in the JSON summary and a line on stderr, and a
stream's last line "arrived" or "stopped short ... cm short". The context is the model's own demo walk; the targets
are places ahead of it (``--target-at``), in the slowest built-in style (elderly: 213 cm/s at most in its capture)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from rsmt_client import Client

from model.inference.bundle import DEFAULT_BUNDLE
from model.motion.bvh_clip import load_clip
from model.motion.skeleton import Skeleton
from rsmt_cli.main import main as rsmt_main
from tests.clients.arrival import place_from
from tests.service.server import Server

pytestmark = pytest.mark.slow  # a server of the default model
STYLE = "builtin:elderly"
FAR = (600.0, 40)  # cm ahead, frames: 2.8 m reachable at 213 cm/s in 40 frames
NEAR = (150.0, 60)  # 4.3 m reachable in 60 frames


@pytest.fixture(scope="module")
def walk(default_model_eager_server: Server, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Skeleton, dict]:
    """The demo walk as a BVH file (a whole take: the CLI sends its last context frames) and its last pose."""
    path = tmp_path_factory.mktemp("reach") / "walk.bvh"
    with Client(default_model_eager_server.url) as c:
        demo = c.demo("walk-normal")
        demo.save_bvh(path, c.model())
    return path, Skeleton.load(DEFAULT_BUNDLE / "skeleton.json"), {"roots": demo.root_positions[-1:],
                                                                  "rotations": demo.rotations[-1:]}


def _run(server: Server, walk: tuple[Path, Skeleton, dict], command: str, ahead: float, frames: int,
         capsys: pytest.CaptureFixture[str], *extra: str) -> tuple[list[dict], list[str], float]:
    """One command to a place ``ahead`` cm along the walk's facing: its JSON lines, its stderr lines and how far
    from that place the last frame's root ends (cm)."""
    path, skeleton, last = walk
    place = place_from(skeleton, np.asarray(last["roots"]), np.asarray(last["rotations"]), ahead, 0.0, 0.0)
    out = path.parent / f"{command}-{ahead:.0f}.bvh"
    code = rsmt_main(["client", command, "--url", server.url, "--context", str(path),
                      f"--target-at={place.x},{place.z},{place.yaw}", "--frames", str(frames), "--style", STYLE,
                      "--seed", "4", "-o", str(out), *extra])
    got = capsys.readouterr()
    assert code == 0, got.err
    end = load_clip(out).root_positions[-1].numpy()
    return ([json.loads(line) for line in got.out.splitlines()], got.err.strip().splitlines(),
            math.hypot(float(end[0]) - place.x, float(end[2]) - place.z))


def _say(capsys: pytest.CaptureFixture[str], text: str) -> None:
    with capsys.disabled():  # a figure for the log, not part of what the command printed
        print(text)


def test_transition_prints_the_reach(default_model_eager_server: Server, walk, capsys) -> None:
    (far,), err, short = _run(default_model_eager_server, walk, "transition", *FAR, capsys)
    reach = far["reach"]
    assert reach["feasible"] is False and reach["distance_cm"] == pytest.approx(FAR[0], abs=1.0)
    assert reach["frames"] == FAR[1] and reach["needed_frames"] > FAR[1] and reach["reachable_cm"] < FAR[0]
    assert err[-1].startswith("reach: out of reach: 600.0 cm away, ") and f"({reach['needed_frames']} frames" in err[-1]
    _say(capsys, f"transition {FAR[0]:.0f} cm in {FAR[1]} frames: ends {short:.1f} cm from the place "
          f"(the notice: {reach['distance_cm'] - reach['reachable_cm']:.1f} cm short); {err[-1]}")
    assert short > 100.0  # it stops short rather than glide there
    (near,), err, miss = _run(default_model_eager_server, walk, "transition", *NEAR, capsys)
    assert near["reach"]["feasible"] is True and err[-1].startswith("reach: within reach: 150.0 cm away")
    _say(capsys, f"transition {NEAR[0]:.0f} cm in {NEAR[1]} frames: ends {miss:.2f} cm from the place; {err[-1]}")


def test_stream_ends_saying_arrived_or_stopped_short(default_model_eager_server: Server, walk, capsys) -> None:
    lines, err, short = _run(default_model_eager_server, walk, "stream", *FAR, capsys, "--pace", "asap", "--quiet")
    end = lines[-1]
    assert end["type"] == "end" and end["reason"] == "arrived" and end["stopped_short"] is True
    reach = end["reach"]
    assert reach["feasible"] is False and err[-2].startswith("reach: out of reach")
    assert err[-1].startswith(f"stopped short: {reach['distance_cm'] - reach['reachable_cm']:.1f} cm short of the "
                              f"target ({reach['distance_cm']:.1f} cm away"), err
    _say(capsys, f"stream {FAR[0]:.0f} cm in {FAR[1]} frames: ends {short:.1f} cm from the place; {err[-1]}")
    lines, err, miss = _run(default_model_eager_server, walk, "stream", *NEAR, capsys, "--pace", "asap", "--quiet")
    assert lines[-1]["stopped_short"] is False and lines[-1]["reach"]["feasible"] is True and err[-1] == "arrived"
    _say(capsys, f"stream {NEAR[0]:.0f} cm in {NEAR[1]} frames: ends {miss:.2f} cm from the place; {err[-1]}")
