"""Built-in styles (``builtin:NAME``): shipped in the bundle, listed in GET /v1/model, usable by every API key
wherever a style id is accepted (POST /v1/transition, stream ``start`` and ``style``), never owned or deleted."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.bundle import Bundle
from model.inference.bundle_styles import BuiltinStyle
from tests.service.conftest import transition_body
from tests.service.server import Server
from tests.service.wsclient import Ws, start_message

KEY_A, KEY_B = "a" * 24, "b" * 24


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory):
    bundle = Bundle.create(synthetic_skeleton(), seed=0)
    bundle.styles = {n: BuiltinStyle(n, synthetic_walk(f, speed_cm_s=v), f"{n}.bvh")
                     for n, f, v in (("slow", 60, 60.0), ("brisk", 90, 160.0))}
    path: Path = bundle.save(tmp_path_factory.mktemp("builtin") / "rsmt")
    srv = Server(path, env={"RSMT_API_KEYS": f"{KEY_A},{KEY_B}"}).start()
    yield srv
    srv.stop()


def headers(key: str) -> dict[str, str]:
    return {"X-API-Key": key}


def test_the_model_lists_its_builtin_styles_and_every_key_uses_them(server) -> None:
    model = httpx.get(server.url + "/v1/model", headers=headers(KEY_A)).json()
    assert model["builtin_styles"] == [{"style_id": "builtin:brisk", "name": "brisk", "frames": 90},
                                       {"style_id": "builtin:slow", "name": "slow", "frames": 60}]
    for key in (KEY_A, KEY_B):
        r = httpx.post(server.url + "/v1/transition", json=transition_body(20, style_id="builtin:slow"),
                       headers=headers(key), timeout=60)
        assert r.status_code == 200, r.text
        assert r.json()["style_id"] == "builtin:slow" and len(r.json()["frames"]) == 20
    # The same clip registered by hand: the same frames (the built-in id is a name for that clip's encoding).
    slow = synthetic_walk(60, speed_cm_s=60.0)
    reg = httpx.post(server.url + "/v1/styles", headers=headers(KEY_A),
                     json={"name": "mine", "motion": {"root_positions": slow.root_positions.tolist(),
                                                      "rotations": slow.rotations.tolist()}}).json()
    a = httpx.post(server.url + "/v1/transition", json=transition_body(20, style_id="builtin:slow"),
                   headers=headers(KEY_A), timeout=60).json()
    b = httpx.post(server.url + "/v1/transition", json=transition_body(20, style_id=reg["style_id"]),
                   headers=headers(KEY_A), timeout=60).json()
    assert a["frames"] == b["frames"]
    # Not a registered style: not listed, not deletable.
    listed = httpx.get(server.url + "/v1/styles", headers=headers(KEY_B)).json()["styles"]
    assert all(not s["style_id"].startswith("builtin:") for s in listed)
    assert httpx.delete(server.url + "/v1/styles/builtin:slow", headers=headers(KEY_B)).status_code == 404


def test_an_unknown_builtin_names_the_ones_there_are(server) -> None:
    r = httpx.post(server.url + "/v1/transition", json=transition_body(10, style_id="builtin:proud"),
                   headers=headers(KEY_B), timeout=60)
    assert r.status_code == 404
    err = r.json()["error"]
    assert err["code"] == "unknown_style" and "builtin:brisk, builtin:slow" in err["message"]


def test_a_stream_starts_and_switches_with_builtin_ids(server) -> None:
    with Ws(server.ws, query=f"token={KEY_B}") as ws:
        assert [s["style_id"] for s in ws.hello["model"]["builtin_styles"]] == ["builtin:brisk", "builtin:slow"]
        ws.send(start_message("w", 30, style_id="builtin:brisk", pace="asap"))
        switched: list[bool] = []

        def switch(w: Ws, frame: dict) -> None:
            if frame["seq"] == 5 and not switched:
                w.send({"type": "style", "character": "w", "style_id": "builtin:slow"})
                switched.append(True)

        out = ws.run({"w"}, on_frame=switch)["w"]
        assert len(out["frames"]) == 30 and out["end"]["reason"] == "arrived"
        started = [m for m in out["messages"] if m["type"] == "started"]
        assert started and started[0].get("style_id", "builtin:brisk") == "builtin:brisk"
