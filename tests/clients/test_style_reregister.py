"""The Python client registers a style again when the server no longer has it (issue 24, row 6): the server
keeps styles in memory only (per key, evicted, lost on restart), so a transition by ``style_id`` that meets
``unknown_style`` re-registers the clip this client registered and retries once, sync and async."""

from __future__ import annotations

import asyncio

import pytest
from rsmt_client import AsyncClient, Client, RsmtError

from tests.clients.helpers import API_KEY
from tests.service.server import Server

pytestmark = pytest.mark.slow  # restarts servers under the client

OTHER_KEY = "client-tests-other-0123456789abcdef"


@pytest.fixture(scope="module")
def server(client_bundle):
    srv = Server(client_bundle, env={"RSMT_API_KEYS": f"{API_KEY},{OTHER_KEY}", "RSMT_WARMUP_MAX_BATCH": "2"}).start()
    yield srv
    srv.stop()


def _ids(server: Server, key: str = API_KEY) -> set[str]:
    with Client(server.url, api_key=key) as c:
        return {s["style_id"] for s in c.styles()}


def test_sync_transition_registers_an_evicted_style_again(server, motions):
    with Client(server.url, api_key=API_KEY) as c, Client(server.url, api_key=API_KEY) as other:
        sid = c.register_style(motions["style"], name="walk")["style_id"]
        other.delete_style(sid)  # as eviction would: the server forgot it, this client still holds the clip
        assert sid not in _ids(server)
        poses = c.transition(motions["context"], motions["target"], 12, style_id=sid, seed=1)
        assert poses.style_id == sid and len(poses.rotations) == 12
        assert sid in _ids(server)
        other.delete_style(sid)
        assert c.transition_bvh(motions["context"], motions["target"], 12, style_id=sid, seed=1).startswith("HIERARCHY")


def test_no_clip_no_retry(server, motions):
    with Client(server.url, api_key=API_KEY) as c, Client(server.url, api_key=OTHER_KEY) as other:
        sid = c.register_style(motions["style2"], name="brisk")["style_id"]
        with pytest.raises(RsmtError) as err:  # another key's style: unknown to it, and it never had the clip
            other.transition(motions["context"], motions["target"], 12, style_id=sid)
        assert err.value.code == "unknown_style" and sid not in _ids(server, OTHER_KEY)
        c.delete_style(sid)  # deleted through this client: forgotten here too
        with pytest.raises(RsmtError) as err:
            c.transition(motions["context"], motions["target"], 12, style_id=sid)
        assert err.value.code == "unknown_style" and sid not in _ids(server)


def test_async_transition_survives_a_server_restart(server, motions):
    async def run() -> tuple[str, int]:
        async with AsyncClient(server.url, api_key=API_KEY) as c:
            sid = (await c.register_style(motions["style"], name="walk"))["style_id"]
            server.stop()
            server.start()  # same port, empty memory
            assert sid not in _ids(server)
            poses = await c.transition(motions["context"], motions["target"], 12, style_id=sid, seed=2)
            return sid, len(poses.rotations)

    sid, frames = asyncio.run(run())
    assert frames == 12 and sid in _ids(server)
