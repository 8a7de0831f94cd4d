"""Errors that say what to do, through a real server on 127.0.0.1: a bare built-in style name suggests its
``builtin:`` id, a body that is not sent as JSON says so (415), and a style clip longer than the model reads
names the client option that cuts it."""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import pytest

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.bundle import Bundle
from model.inference.bundle_styles import StyleClip
from model.inference.style_packing import write_builtin_styles
from tests.service.conftest import bvh, transition_body, walk
from tests.service.server import Server
from tests.service.wsclient import Ws, start_message

pytestmark = pytest.mark.slow  # a server of its own (about 20 s to start on 2 cores)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory):
    path: Path = Bundle.create(synthetic_skeleton(), seed=0).save(tmp_path_factory.mktemp("hints") / "rsmt")
    write_builtin_styles(path, [StyleClip("brisk", synthetic_walk(40, speed_cm_s=160.0), "brisk.bvh")])
    srv = Server(path).start()
    yield srv
    srv.stop()


@pytest.mark.parametrize("name", ["brisk", "Brisk"])
def test_a_bare_builtin_name_suggests_its_id(server, name: str) -> None:
    r = httpx.post(server.url + "/v1/transition", json=transition_body(10, style_id=name), timeout=30)
    assert r.status_code == 404 and r.json()["error"]["code"] == "unknown_style"
    assert "Did you mean builtin:brisk?" in r.json()["error"]["message"], r.json()
    got = httpx.get(f"{server.url}/v1/styles/{name}", timeout=30)
    assert got.status_code == 404 and "Did you mean builtin:brisk?" in got.json()["error"]["message"]
    with Ws(server.ws) as ws:  # it has read hello
        ws.send(start_message("c", 10, style_id=name))
        err = ws.recv()
    assert err["type"] == "error" and err["code"] == "unknown_style" and "builtin:brisk" in err["message"], err


def test_another_unknown_name_suggests_nothing(server) -> None:
    r = httpx.post(server.url + "/v1/transition", json=transition_body(10, style_id="briskly"), timeout=30)
    assert r.status_code == 404 and "Did you mean" not in r.json()["error"]["message"]


@pytest.mark.parametrize("content_type", [None, "text/plain", "application/x-www-form-urlencoded"])
def test_a_body_not_sent_as_json_says_so(server, content_type: str | None) -> None:
    body = json.dumps(transition_body(10)).encode()
    headers = {"content-type": content_type} if content_type else {}
    with httpx.Client(timeout=30) as c:
        request = c.build_request("POST", server.url + "/v1/transition", content=body, headers=headers)
        assert request.headers.get("content-type") == content_type  # httpx adds none to raw content
        r = c.send(request)
    err = r.json()["error"]
    assert r.status_code == 415 and err["code"] == "unsupported_media_type", err
    assert "Content-Type: application/json" in err["message"]
    assert (content_type or "no Content-Type") in err["message"], err


def test_a_json_body_of_the_wrong_shape_is_still_a_validation_error(server) -> None:
    r = httpx.post(server.url + "/v1/transition", content=b"[]", headers={"content-type": "application/json"}, timeout=30)
    assert r.status_code == 422 and r.json()["error"]["code"] == "validation_error"
    ok = httpx.post(server.url + "/v1/transition", content=json.dumps(transition_body(5)).encode(),
                    headers={"content-type": "application/json; charset=utf-8"}, timeout=30)
    assert ok.status_code == 200, ok.text


def test_a_too_long_style_clip_names_the_option_that_cuts_it(server) -> None:
    most = httpx.get(server.url + "/v1/model").json()["style_clip_frames"]["max"]
    r = httpx.post(server.url + "/v1/styles", json={"name": "long", "motion": bvh(walk(most + 1))}, timeout=60)
    err = r.json()["error"]
    assert r.status_code == 422 and err["code"] == "too_many_frames", err
    assert f"--start S --frames {most}" in err["message"] and "middle" in err["message"], err
    inline = httpx.post(server.url + "/v1/transition", json=transition_body(10, style=bvh(walk(most + 1))), timeout=60)
    assert inline.status_code == 422 and "--start S --frames" in inline.json()["error"]["message"]
