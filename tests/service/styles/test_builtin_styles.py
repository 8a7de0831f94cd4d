"""Built-in styles (``builtin:NAME``): codes shipped in the bundle, listed in GET /v1/model and GET /v1/styles for
every key, usable by every API key wherever a style id is accepted (POST /v1/transition, stream ``start`` and
``style``) without registering anything, never owned, counted, evicted or deleted."""

from __future__ import annotations

import copy
import shutil
from pathlib import Path

import httpx
import pytest
import torch

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.bundle import Bundle
from model.inference.bundle_adapters import adapter_from
from model.inference.bundle_styles import StyleClip
from model.inference.style_packing import write_adapter, write_builtin_styles
from tests.service.conftest import transition_body
from tests.service.server import Server
from tests.service.wsclient import Ws, start_message

pytestmark = pytest.mark.slow  # a server with built-in styles and a fine-tuned bundle

KEY_A, KEY_B = "a" * 24, "b" * 24


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path: Path = Bundle.create(synthetic_skeleton(), seed=0).save(tmp_path_factory.mktemp("builtin") / "rsmt")
    write_builtin_styles(path, [StyleClip(n, synthetic_walk(f, speed_cm_s=v), f"{n}.bvh")
                                for n, f, v in (("slow", 60, 60.0), ("brisk", 90, 160.0))])
    return path


@pytest.fixture(scope="module")
def server(base: Path):
    path = base
    # One registered style per key: the built-in ones must not count against it.
    srv = Server(path, env={"RSMT_API_KEYS": f"{KEY_A},{KEY_B}", "RSMT_STYLE_CACHE_ENTRIES_PER_KEY": "1"}).start()
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

    # Listed for every key, first and marked, beside (not instead of) the key's own registered style.
    builtins = [{"style_id": "builtin:brisk", "name": "brisk", "frames": 90, "clips": 1, "cached": True, "model": "rsmt",
                 "builtin": True},
                {"style_id": "builtin:slow", "name": "slow", "frames": 60, "clips": 1, "cached": True, "model": "rsmt",
                 "builtin": True}]
    assert httpx.get(server.url + "/v1/styles", headers=headers(KEY_B)).json()["styles"] == builtins
    listed = httpx.get(server.url + "/v1/styles", headers=headers(KEY_A)).json()["styles"]
    assert listed[:2] == builtins and [(s["style_id"], s["builtin"]) for s in listed[2:]] == [(reg["style_id"], False)]
    assert httpx.get(server.url + "/v1/styles/builtin:slow", headers=headers(KEY_B)).json() == builtins[1]


def test_builtin_styles_count_against_no_keys_cap(server) -> None:
    # The cap is one registered style per key: a second registration evicts the first, never a built-in one.
    ids = []
    for speed in (90.0, 120.0):
        clip = synthetic_walk(40, speed_cm_s=speed)
        r = httpx.post(server.url + "/v1/styles", headers=headers(KEY_B),
                       json={"name": f"w{speed:g}", "motion": {"root_positions": clip.root_positions.tolist(),
                                                               "rotations": clip.rotations.tolist()}})
        assert r.status_code == 201, r.text
        ids.append(r.json()["style_id"])
    listed = httpx.get(server.url + "/v1/styles", headers=headers(KEY_B)).json()["styles"]
    assert [s["style_id"] for s in listed] == ["builtin:brisk", "builtin:slow", ids[1]]
    r = httpx.post(server.url + "/v1/transition", json=transition_body(10, style_id="builtin:brisk"),
                   headers=headers(KEY_B), timeout=60)
    assert r.status_code == 200, r.text


def test_a_builtin_style_cannot_be_deleted(server) -> None:
    r = httpx.delete(server.url + "/v1/styles/builtin:slow", headers=headers(KEY_B))
    assert r.status_code == 405
    err = r.json()["error"]
    assert err["code"] == "method_not_allowed" and "built-in style of model 'rsmt'" in err["message"]
    assert httpx.get(server.url + "/v1/styles/builtin:slow", headers=headers(KEY_B)).status_code == 200
    r = httpx.delete(server.url + "/v1/styles/builtin:proud", headers=headers(KEY_B))
    assert r.status_code == 404 and r.json()["error"]["code"] == "unknown_style"


def test_an_unknown_builtin_names_the_ones_there_are(server) -> None:
    r = httpx.post(server.url + "/v1/transition", json=transition_body(10, style_id="builtin:proud"),
                   headers=headers(KEY_B), timeout=60)
    assert r.status_code == 404
    err = r.json()["error"]
    assert err["code"] == "unknown_style" and "builtin:brisk, builtin:slow" in err["message"]


def _switched_stream(ws: Ws, first: str, then: str) -> tuple[dict, bool]:
    """A 30-frame stream started with style ``first`` and switched to ``then`` at frame 5; its record, and
    whether the switch was sent."""
    ws.send(start_message("w", 30, style_id=first, pace="asap"))
    switched: list[bool] = []

    def switch(w: Ws, frame: dict) -> None:
        if frame["seq"] == 5 and not switched:
            w.send({"type": "style", "character": "w", "style_id": then})
            switched.append(True)

    return ws.run({"w"}, on_frame=switch)["w"], bool(switched)


def test_a_stream_starts_and_switches_with_builtin_ids(server) -> None:
    with Ws(server.ws, query=f"token={KEY_B}") as ws:
        assert [s["style_id"] for s in ws.hello["model"]["builtin_styles"]] == ["builtin:brisk", "builtin:slow"]
        out, _ = _switched_stream(ws, "builtin:brisk", "builtin:slow")
        assert len(out["frames"]) == 30 and out["end"]["reason"] == "arrived"
        started = [m for m in out["messages"] if m["type"] == "started"]
        assert started and started[0].get("style_id", "builtin:brisk") == "builtin:brisk"


@pytest.fixture(scope="module")
def adapted(base: Path, tmp_path_factory: pytest.TempPathFactory):
    """Servers on the bundle plus a style adapter ``limp``, and on a bundle whose own weights are limp's."""
    folder = tmp_path_factory.mktemp("adapted")
    bundle = Bundle.load(base)
    tuned = copy.deepcopy(bundle.sampler)
    gen = torch.Generator().manual_seed(5)
    with torch.no_grad():
        for name, p in tuned.named_parameters():
            if name.startswith(("film1.", "lstm.", "head_out.")):
                p.add_(0.2 * torch.randn(p.shape, generator=gen))
    limp = StyleClip("limp", synthetic_walk(70, speed_cm_s=40.0), "limp.bvh")
    shutil.copytree(base, folder / "rsmt")
    write_adapter(folder / "rsmt", adapter_from(bundle.sampler, tuned, "limp", bundle.version), limp)
    own = Bundle.load(base, styles=False)
    own.sampler = tuned
    own.save(folder / "own" / "rsmt")
    write_builtin_styles(folder / "own" / "rsmt", [limp])
    servers = [Server(folder / "rsmt").start(), Server(folder / "own" / "rsmt").start()]
    yield servers
    for srv in servers:
        srv.stop()


def test_a_fine_tuned_style_runs_on_its_adapter_and_the_others_as_before(server, adapted) -> None:
    with_adapter, own = adapted
    listed = [s["style_id"] for s in httpx.get(with_adapter.url + "/v1/model").json()["builtin_styles"]]
    assert listed == ["builtin:brisk", "builtin:limp", "builtin:slow"]

    def frames(srv: Server, style_id: str) -> list:
        r = httpx.post(srv.url + "/v1/transition", json=transition_body(20, style_id=style_id), timeout=60,
                       headers=headers(KEY_A) if srv is server else None)
        assert r.status_code == 200, r.text
        return r.json()["frames"]

    # The known styles: the same frames as the bundle without the adapter; the new one: its own weights'.
    assert frames(with_adapter, "builtin:slow") == frames(server, "builtin:slow")
    assert frames(with_adapter, "builtin:limp") == frames(own, "builtin:limp")
    # A stream switches between styles of the two weight sets and arrives.
    with Ws(with_adapter.ws) as ws:
        out, switched = _switched_stream(ws, "builtin:slow", "builtin:limp")
        assert switched and len(out["frames"]) == 30 and out["end"]["reason"] == "arrived"


@pytest.mark.slow
def test_a_fresh_server_on_the_default_model_lists_and_uses_its_seven_styles() -> None:
    from model.inference.bundle import DEFAULT_BUNDLE

    srv = Server(DEFAULT_BUNDLE, env={"RSMT_WARMUP_MAX_BATCH": "1"}).start(300)
    try:
        listed = httpx.get(srv.url + "/v1/styles").json()["styles"]
        assert [s["style_id"] for s in listed] == [f"builtin:{n}" for n in (
            "active", "elderly", "exhausted", "feminine", "masculine", "normal", "youthful")]
        assert all(s["builtin"] and s["frames"] == 180 and s["model"] == "rsmt-default" for s in listed)
        joints = httpx.get(srv.url + "/v1/model").json()["skeleton"]["joints"]
        rest = {"root_positions": [[0.0, 90.0, 0.0]] * 10, "rotations": [[[0.0, 0.0, 0.0, 1.0]] * len(joints)] * 10}
        target = {"root_positions": [[0.0, 90.0, 150.0]], "rotations": [[[0.0, 0.0, 0.0, 1.0]] * len(joints)]}
        r = httpx.post(srv.url + "/v1/transition", json={"context": rest, "target": target, "frames": 30,
                                                         "style_id": "builtin:elderly", "seed": 7}, timeout=120)
        assert r.status_code == 200, r.text
        assert r.json()["style_id"] == "builtin:elderly" and len(r.json()["frames"]) == 30
    finally:
        srv.stop()
