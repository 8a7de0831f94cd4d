"""``start`` with ``retargeted`` through a real uvicorn: what a client sends when it resumes, on another
replica, a character whose target changed mid-motion. On a bundle with a retarget facing window the
character turns by that window from its first frame; otherwise the flag changes nothing."""

from __future__ import annotations

import httpx
import numpy as np
import pytest

from model.data.synthetic import synthetic_skeleton
from model.inference.bundle import Bundle
from model.inference.output.settings import OutputConfig
from model.inference.output.steering import SteeringConfig
from tests.service.conftest import bvh, target_clip, walk
from tests.service.server import Server
from tests.service.wsclient import Ws, poses_of, start_message

pytestmark = pytest.mark.slow  # packages a bundle and starts a server for it

USUAL = SteeringConfig(window=20, turn_window=3, max_turn_deg=4.0, height_window=3)


def _server(tmp_path_factory: pytest.TempPathFactory, steering: SteeringConfig):
    bundle = Bundle.create(synthetic_skeleton(), seed=0)
    bundle.output = OutputConfig(0.0, False, steering=steering)
    return Server(bundle.save(tmp_path_factory.mktemp("bundle") / "rsmt")).start()


@pytest.fixture(scope="module")
def servers(tmp_path_factory):
    late = SteeringConfig(**{**USUAL.to_dict(), "retarget_turn_window": 8, "retarget_max_turn_deg": 30.0})
    out = {"usual": _server(tmp_path_factory, USUAL), "late": _server(tmp_path_factory, late)}
    yield out
    for srv in out.values():
        srv.stop()


def _style(server: Server) -> str:
    r = httpx.post(server.url + "/v1/styles", json={"name": "walk", "motion": bvh(walk(120))}, timeout=30)
    return str(r.json()["style_id"])


def _last_rotations(server: Server, retargeted: bool) -> np.ndarray:
    target = bvh(target_clip(yaw=135.0, shift=60.0))  # turned and moved: much facing left to finish
    with Ws(server.ws) as ws:
        ws.send(start_message("r", 12, deterministic=True, style_id=_style(server), target=target,
                              retargeted=retargeted))
        got = ws.run({"r"})["r"]
    assert got["end"]["reason"] == "arrived" and got["end"]["frames"] == 12
    return poses_of(got["frames"])[1][-1]


def test_a_start_marked_retargeted_takes_the_retarget_window_where_the_bundle_has_one(servers):
    usual = {flag: _last_rotations(servers["usual"], flag) for flag in (False, True)}
    late = {flag: _last_rotations(servers["late"], flag) for flag in (False, True)}
    assert np.allclose(usual[False], usual[True], atol=1e-5)
    assert np.allclose(usual[False], late[False], atol=1e-5)
    assert not np.allclose(late[False], late[True], atol=1e-3)


def test_retargeted_must_be_a_boolean(servers):
    with Ws(servers["late"].ws) as ws:
        ws.send(start_message("x", 10, style_id=_style(servers["late"]), retargeted="yes", request_id="q"))
        err = ws.recv()
    assert err["type"] == "error" and err["code"] == "validation_error" and err["request_id"] == "q"
