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


@pytest.mark.parametrize(("style", "wanted"), [
    ("brisk", '"style_id": "builtin:brisk" instead of "style"'),
    ("Brisk", '"style_id": "builtin:brisk" instead of "style"'),
    ("walk-1", '"style_id": "<id>" instead of "style": an id from POST /v1/styles or builtin:NAME (the models have '
               'builtin:brisk; GET /v1/styles lists them)'),
])
def test_a_name_in_style_says_to_send_style_id(server, style: str, wanted: str) -> None:
    """Issue 64: {"style": "elderly"} answered pydantic's "style.BvhMotion: Input should be a valid dictionary..."."""
    r = httpx.post(server.url + "/v1/transition", json=transition_body(10, style=style), timeout=30)
    err = r.json()["error"]
    assert r.status_code == 422 and err["code"] == "validation_error", err
    assert err["message"].startswith("style: takes a style clip (a Motion, an object: BVH text as {\"bvh\": ") and \
        wanted in err["message"], err
    assert "BvhMotion" not in err["message"] and "PoseMotion" not in err["message"], err
    with Ws(server.ws) as ws:  # the stream's start says the same (without the model's names at hand: the generic fix)
        ws.send({**start_message("c", 10), "style": style})
        got = ws.recv()
    assert got["type"] == "error" and got["code"] == "validation_error" and "instead of \"style\"" in got["message"], got


def test_motion_fields_of_the_wrong_shape_name_the_object_to_send(server) -> None:
    text = bvh(walk(20))["bvh"]
    r = httpx.post(server.url + "/v1/transition", json={**transition_body(10), "context": text}, timeout=30)
    err = r.json()["error"]
    assert r.status_code == 422 and err["message"].startswith("context: BVH text goes inside an object, "
                                                               "{\"bvh\": \"<the BVH file's text>\"}"), err
    r = httpx.post(server.url + "/v1/styles", json={"name": "x", "motion": {"bvh": 3}}, timeout=30)
    assert r.status_code == 422 and r.json()["error"]["message"] == "motion.bvh: Input should be a valid string", r.text
    r = httpx.post(server.url + "/v1/styles", json={"name": "x", "motions": [bvh(walk(20)), [1, 2]]}, timeout=30)
    assert r.status_code == 422 and r.json()["error"]["message"].startswith("motions.1: expects a Motion, an object"), \
        r.text


@pytest.mark.parametrize("content_type", [None, "text/plain", "application/json"])
def test_a_bvh_file_sent_as_the_body_is_shown_the_wrapper(server, content_type: str | None) -> None:
    """Issue 64: a raw BVH body got a 415 without a word about the {"bvh": "<text>"} object it belongs in."""
    headers = {"content-type": content_type} if content_type else {}
    r = httpx.post(server.url + "/v1/transition", content=bvh(walk(20))["bvh"].encode(), headers=headers, timeout=30)
    err = r.json()["error"]
    assert r.status_code == (400 if content_type == "application/json" else 415), err
    assert "This body is a BVH file: send it inside JSON, as the text of a Motion, {\"bvh\": \"<the BVH file's " \
           "text>\"}" in err["message"] and "jq -Rs '{bvh: .}' walk.bvh" in err["message"], err
