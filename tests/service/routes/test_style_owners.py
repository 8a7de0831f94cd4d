"""Registered styles belong to the API key that registered them (issue 24, row 6): listing, fetching,
deleting and using an id see only the caller's styles, an admin key's everyone's, and each key's styles
are evicted within its own cap, so one key's registration flood does not evict another's."""

from __future__ import annotations

import httpx
import pytest

from tests.service.conftest import bvh, transition_body, walk
from tests.service.server import Server
from tests.service.wsclient import Ws, start_message

pytestmark = pytest.mark.slow  # a server of its own with several keys

KEY_A, KEY_B, ADMIN = "owner-a-0123456789abcdef", "owner-b-0123456789abcdef", "admin-k-0123456789abcdef"
PER_KEY, TOTAL = 3, 5


@pytest.fixture(scope="module")
def server(bundle_dir):
    srv = Server(bundle_dir, env={"RSMT_API_KEYS": f"{KEY_A},{KEY_B}", "RSMT_ADMIN_API_KEYS": ADMIN,
                                  "RSMT_STYLE_CACHE_ENTRIES_PER_KEY": str(PER_KEY),
                                  "RSMT_STYLE_CACHE_ENTRIES": str(TOTAL)}).start()
    yield srv
    srv.stop()


def clip(i: int) -> dict:
    """A distinct style clip per ``i`` (distinct content hash)."""
    return bvh(walk(30 + i))


class As:
    """Requests with one key."""

    def __init__(self, server: Server, key: str) -> None:
        self.url, self.headers = server.url, {"X-API-Key": key}

    def register(self, i: int) -> dict:
        r = httpx.post(self.url + "/v1/styles", json={"motion": clip(i), "name": f"s{i}"}, headers=self.headers,
                       timeout=60)
        assert r.status_code == 201, r.text
        return r.json()

    def ids(self) -> set[str]:
        r = httpx.get(self.url + "/v1/styles", headers=self.headers, timeout=30)
        assert r.status_code == 200, r.text
        return {s["style_id"] for s in r.json()["styles"]}

    def get(self, sid: str) -> httpx.Response:
        return httpx.get(f"{self.url}/v1/styles/{sid}", headers=self.headers, timeout=30)

    def delete(self, sid: str) -> httpx.Response:
        return httpx.delete(f"{self.url}/v1/styles/{sid}", headers=self.headers, timeout=30)

    def transition(self, sid: str) -> httpx.Response:
        return httpx.post(self.url + "/v1/transition", json=transition_body(20, style_id=sid), headers=self.headers,
                          timeout=60)

    def clear(self) -> None:
        for sid in self.ids():
            assert self.delete(sid).status_code == 204


@pytest.fixture
def keys(server):
    a, b, admin = As(server, KEY_A), As(server, KEY_B), As(server, ADMIN)
    admin.clear()  # the admin deletes everyone's: each test starts from no styles
    yield a, b, admin
    admin.clear()


def _unknown(r: httpx.Response) -> None:
    assert r.status_code == 404 and r.json()["error"]["code"] == "unknown_style", r.text


def test_another_keys_style_is_unknown(keys):
    a, b, _ = keys
    sid = a.register(0)["style_id"]
    assert a.ids() == {sid} and b.ids() == set()
    _unknown(b.get(sid))
    _unknown(b.delete(sid))
    _unknown(b.transition(sid))
    assert a.get(sid).status_code == 200  # B's delete touched nothing
    assert a.transition(sid).status_code == 200


def test_same_clip_two_keys_two_entries(keys):
    a, b, _ = keys
    first = a.register(1)
    assert first["cached"] is False and a.register(1)["cached"] is True
    second = b.register(1)
    assert second["style_id"] == first["style_id"] and second["cached"] is False  # nothing says A has it
    assert a.delete(first["style_id"]).status_code == 204
    _unknown(a.get(first["style_id"]))
    assert b.get(first["style_id"]).status_code == 200 and b.ids() == {first["style_id"]}


def test_admin_sees_uses_and_deletes_everyones(keys):
    a, b, admin = keys
    sa, sb = a.register(2)["style_id"], b.register(3)["style_id"]
    assert admin.ids() == {sa, sb}
    assert admin.get(sb).status_code == 200 and admin.transition(sa).status_code == 200
    assert admin.delete(sa).status_code == 204
    _unknown(a.get(sa))
    assert b.ids() == {sb}


def test_per_key_cap_evicts_only_the_keys_own(keys):
    a, b, _ = keys
    kept = b.register(10)["style_id"]
    mine = [a.register(i)["style_id"] for i in range(20, 20 + PER_KEY + 2)]
    assert a.ids() == set(mine[-PER_KEY:])  # A's least recently used went first
    assert b.ids() == {kept}
    assert b.transition(kept).status_code == 200


def test_whole_bound_evicts_the_biggest_owner(keys):
    a, b, admin = keys
    kept = {b.register(i)["style_id"] for i in (40, 41)}
    flood = [a.register(i)["style_id"] for i in range(50, 50 + PER_KEY)]  # 5 entries: the whole bound
    admin.register(60)  # the sixth: the biggest owner (A) loses its least recently used
    assert b.ids() == kept
    assert a.ids() == set(flood[1:])


def test_stream_start_and_set_style_see_only_own_styles(server, keys):
    a, b, _ = keys
    sid = a.register(70)["style_id"]
    with Ws(server.ws, query=f"token={KEY_B}") as ws:
        ws.send(start_message(style_id=sid, character="c1", frames=10))
        m = ws.recv()
        assert m["type"] == "error" and m["code"] == "unknown_style", m
    own_b = b.register(71)["style_id"]
    with Ws(server.ws, query=f"token={KEY_A}") as ws:
        # Real-time pace at 30 fps: 120 frames last 4 s, so the character is still live at the style message.
        ws.send(start_message(style_id=sid, character="c1", frames=120, pace="realtime"))
        assert ws.recv()["type"] == "started"
        ws.send({"type": "style", "character": "c1", "style_id": own_b})
        errors = [m for m in ws.ping() if m["type"] in ("error", "style_changed")]
        assert [m.get("code") for m in errors] == ["unknown_style"], errors
