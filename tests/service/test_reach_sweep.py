"""The reach sweep through a real server (issue 50 item 4): 200 far starts and mid-stream retargets of the default
model, 2-8 m in 1-3 s, every built-in style, streamed over ``/v1/stream`` on 127.0.0.1.

Each case's frames are read back and checked: the root never moves faster on the ground than its style's capture
maximum (the bundle's ``gait_limits.json``), every ``started`` / ``retargeted`` carries the reach notice and it
says a target is out of reach exactly where the capture's speed does not cover the distance in the frames asked
(cases within a few per cent of that line are not judged either way), and no run of more than 10 frames has both
toes more than 15 cm above their rest height and the hips stay within the style's capture range (3 cm slack). The
last is not met by the shipped network: its test is a strict xfail that names the figures, on that model's version
only (a retrained bundle is judged plainly).
A POST /v1/transition whose target is 9.3 m away in 40 frames answers with the notice and keeps the speed too.
Skipped without the shared motion data.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from model.data.preprocessed import load_motion_cache
from model.inference.bundle import DEFAULT_BUNDLE, Bundle
from model.motion.clip import Clip
from model.motion.gait_limits import GaitLimits
from tests.service.conftest import poses
from tests.service.reach_sweep import (
    NATURAL_FRAMES,
    SweepCase,
    facing_deg,
    far_target,
    gait_figures,
    positions,
    sweep_cases,
)
from tests.service.server import Server
from tests.service.wsclient import Ws

pytestmark = [pytest.mark.real_data, pytest.mark.slow]

CASES = 200
PER_CONNECTION = 20  # characters streamed at once on one connection (one batch on the server)
AIRBORNE_RUN = 10
SPEED_SLACK = 1.005  # float32 frames and the emitted root's few-mm lag behind the capped state
BOUNDARY = 0.04  # a case within 4% of the reach line is not judged (the emitted root trails the state a little)
HIPS_SLACK_CM = 3.0  # a generated gait may dip or rise a little past the takes' extremes
SHIPPED_VERSION = "037dc42a2119cf86"  # the default model when the cap came in; it still lifts its feet


def _run_group(server: Server, group: list[tuple[int, SweepCase]], skeleton: Any) -> dict[int, dict]:
    """The cases of ``group`` streamed at once on one connection; per case its frames, messages and far target."""
    names = {f"k{n}": (n, case) for n, case in group}
    sent: dict[str, Clip] = {}
    with Ws(server.ws, encoding="binary") as ws:
        for cid, (n, case) in names.items():
            if case.retarget_at is None:
                here = case.context.root_positions[-1, ::2].numpy()
                facing = facing_deg(skeleton, case.context.root_positions[-1].numpy(), case.context.rotations[-1].numpy())
                sent[cid] = far_target(case.context, here, facing, case.distance_cm, case.angle_deg)
                target, frames = sent[cid], case.frames
            else:
                target, frames = case.natural, NATURAL_FRAMES
            ws.send({"type": "start", "character": cid, "context": poses(case.context), "target": poses(target),
                     "frames": frames, "style_id": f"builtin:{case.style}", "seed": n, "pace": "asap"})

        def on_frame(w: Ws, frame: dict) -> None:
            n, case = names[frame["character"]]
            if case.retarget_at is not None and frame["seq"] == case.retarget_at - 1:
                root, rot = frame["pose"]["root_position"], frame["pose"]["rotations"]
                facing = facing_deg(skeleton, np.asarray(root), np.asarray(rot))
                cid = frame["character"]
                sent[cid] = far_target(case.context, np.asarray(root)[::2], facing, case.distance_cm, case.angle_deg)
                w.send(json.dumps({"type": "retarget", "character": cid, "target": poses(sent[cid]),
                                   "frames": case.frames}))

        got = ws.run(set(names), timeout=300.0, on_frame=on_frame)
    return {names[cid][0]: {**result, "target": sent[cid]} for cid, result in got.items()}


def _hips_range(limits: GaitLimits, style: str) -> tuple[float, float]:
    """The style's hips height range over every gait of its capture (walks and runs: the loosest bound)."""
    ranges = limits.styles[style].hips_cm.values()
    return min(lo for lo, _ in ranges), max(hi for _, hi in ranges)


@pytest.fixture(scope="module")
def limits() -> GaitLimits:
    found = Bundle.load(DEFAULT_BUNDLE, styles=False).gait_limits
    assert found is not None, "the default bundle carries no gait_limits.json"
    return found


@pytest.fixture(scope="module")
def server(default_model_server: Server) -> Server:
    return default_model_server  # tests/service/conftest.py: shared with the other read-only streams of the default model


@pytest.fixture(scope="module")
def sweep(shared_data: Path, server: Server, limits: GaitLimits) -> list[dict[str, Any]]:
    """Every case's figures: style, kind, longest airborne run, airborne frames, top speed, the notice and
    whether the notice was expected (None: too near the line to judge)."""
    cache = load_motion_cache(shared_data, progress=False)
    bundle = Bundle.load(DEFAULT_BUNDLE, styles=False)
    skeleton = bundle.skeleton
    cases = sweep_cases(cache, CASES, seed=0)
    assert {c.style for c in cases} == set(limits.styles)  # every built-in style
    fps = bundle.config.fps
    rows = []
    for first in range(0, len(cases), PER_CONNECTION):
        group = list(enumerate(cases))[first:first + PER_CONNECTION]
        results = _run_group(server, group, skeleton)
        for n, case in group:
            r = results[n]
            frames = r["frames"]
            roots = np.array([f["pose"]["root_position"] for f in frames], np.float64)
            rots = np.array([f["pose"]["rotations"] for f in frames], np.float64)
            roots = np.concatenate([case.context.root_positions[-1:].numpy(), roots])
            rots = np.concatenate([case.context.rotations[-1:].numpy(), rots])
            figures = gait_figures(skeleton, positions(skeleton, roots, rots), fps)
            kind = "started" if case.retarget_at is None else "retargeted"
            (notice,) = [m for m in r["messages"] if m["type"] == kind]
            start = 0 if kind == "started" else notice["from_seq"]  # the root the server measured from
            here = roots[start]
            distance = float(np.linalg.norm(r["target"].root_positions[-1, ::2].numpy() - here[::2]))
            covered = limits.max_speed(case.style) * case.frames / fps
            expected = None if abs(distance - covered) <= BOUNDARY * covered else distance <= covered
            rows.append({"style": case.style, "kind": kind, "longest": figures.longest_airborne,
                         "airborne": figures.airborne, "frames": figures.frames, "speeds": figures.speeds,
                         "top": float(figures.speeds.max()), "cap": limits.max_speed(case.style),
                         "hips": figures.hips_cm, "hips_range": _hips_range(limits, case.style),
                         "reach": notice.get("reach"), "expected": expected, "ended": r["end"]["reason"]})
    return rows


def test_every_case_ran_to_its_end(sweep: list[dict[str, Any]]) -> None:
    assert len(sweep) == CASES and all(r["ended"] == "arrived" for r in sweep)
    assert sum(r["kind"] == "retargeted" for r in sweep) == CASES // 2


def test_the_root_never_outruns_the_capture(sweep: list[dict[str, Any]]) -> None:
    over = [f"{r['style']} {r['kind']}: {r['top']:.0f} cm/s (capture {r['cap']:.0f})" for r in sweep
            if r["top"] > r["cap"] * SPEED_SLACK]
    assert not over, f"{len(over)} of {len(sweep)} runs faster than their style's capture: {'; '.join(over[:8])}"


def test_a_target_out_of_reach_is_said_to_be(sweep: list[dict[str, Any]]) -> None:
    assert all(r["reach"] is not None for r in sweep), "a start or retarget came without its reach notice"
    judged = [r for r in sweep if r["expected"] is not None]
    wrong = [r for r in judged if r["reach"]["feasible"] != r["expected"]]
    assert not wrong, f"{len(wrong)} notices disagree with the capture's speed: {wrong[:3]}"
    out = [r for r in judged if not r["expected"]]
    assert len(out) >= 20 and len(judged) - len(out) >= 20  # the sweep holds both kinds
    for r in out:
        reach = r["reach"]
        assert reach["needed_frames"] > reach["frames"] and reach["reachable_cm"] < reach["distance_cm"]


def _gait_figures(sweep: list[dict[str, Any]]) -> str:
    frames = sum(r["frames"] for r in sweep)
    speeds = np.concatenate([r["speeds"] for r in sweep])
    worst = [r for r in sweep if r["longest"] > AIRBORNE_RUN]
    low = [r for r in sweep if not r["hips_range"][0] - HIPS_SLACK_CM <= r["hips"][0]]
    high = [r for r in sweep if not r["hips"][1] <= r["hips_range"][1] + HIPS_SLACK_CM]
    return (f"{len(worst)} of {len(sweep)} runs airborne over {AIRBORNE_RUN} frames (longest "
            f"{max(r['longest'] for r in sweep)}), airborne share {sum(r['airborne'] for r in sweep) / frames:.3f}; "
            f"hips under the style's capture range in {len(low)} (lowest "
            f"{min(r['hips'][0] - r['hips_range'][0] for r in sweep):.0f} cm under it), over it in {len(high)}; "
            f"root speed max {speeds.max():.0f} cm/s, p95 {np.percentile(speeds, 95):.0f}")


def test_the_toes_stay_down_and_the_hips_within_the_capture(sweep: list[dict[str, Any]]) -> None:
    worst = [r for r in sweep if r["longest"] > AIRBORNE_RUN]
    out = [r for r in sweep if not r["hips_range"][0] - HIPS_SLACK_CM <= r["hips"][0] <= r["hips"][1]
           <= r["hips_range"][1] + HIPS_SLACK_CM]
    figures = _gait_figures(sweep)
    shipped = Bundle.load(DEFAULT_BUNDLE, styles=False).version == SHIPPED_VERSION
    if shipped and (worst or out):  # known and measured: the model retrained with dataset 1 (issue 50 item 2) is to fix it
        pytest.xfail(f"the shipped network (version {SHIPPED_VERSION}) folds its legs in far starts and retargets: "
                     f"{figures}")
    assert not worst and not out, figures
    assert not shipped, f"the shipped network now keeps its feet down and its hips up ({figures}): drop its expected failure"


def test_a_request_out_of_reach_says_so_and_keeps_the_speed(shared_data: Path, server: Server,
                                                           limits: GaitLimits) -> None:
    cache = load_motion_cache(shared_data, progress=False)
    case = sweep_cases(cache, 1, seed=3)[0]
    bundle = Bundle.load(DEFAULT_BUNDLE, styles=False)
    here = case.context.root_positions[-1, ::2].numpy()
    facing = facing_deg(bundle.skeleton, case.context.root_positions[-1].numpy(), case.context.rotations[-1].numpy())
    target = far_target(case.context, here, facing, 930.0, 0.0)
    body = {"context": poses(case.context), "target": poses(target), "frames": 40,
            "style_id": f"builtin:{case.style}", "seed": 1}
    answer = httpx.post(server.url + "/v1/transition", json=body, timeout=60.0)
    assert answer.status_code == 200, answer.text
    data = answer.json()
    speed = limits.max_speed(case.style)
    assert data["reach"] == {"feasible": False, "distance_cm": pytest.approx(930.0, abs=0.2), "frames": 40,
                             "needed_frames": math.ceil(929.0 * bundle.config.fps / speed),
                             "reachable_cm": pytest.approx(speed * 40 / bundle.config.fps, abs=0.1),
                             "max_speed_cm_s": pytest.approx(speed, abs=0.1)}
    from rsmt_client import Client

    with Client(server.url) as client:  # the Python client hands the notice on
        got = client.transition(body["context"], body["target"], 40, style_id=f"builtin:{case.style}", seed=1)
    assert got.reach is not None and not got.reach.feasible and got.reach.needed_frames == data["reach"]["needed_frames"]
    roots = np.array([case.context.root_positions[-1].tolist()] + [f["root_position"] for f in data["frames"]])
    assert float((np.linalg.norm(np.diff(roots[:, ::2], axis=0), axis=-1) * bundle.config.fps).max()) <= speed * SPEED_SLACK
