"""A character cancelled before its first frame leaves nothing behind (issue 64, item 3), through a real server
with keys on: connections that each ``start`` a character and ``cancel`` it at once, round after round, leave the
server's resident memory flat.

Before the fix, a character whose ``cancel`` reached the step thread with its ``start`` (added, never stepped)
stayed in its key's batch, waiting to join, until that key stepped again, which a key that only cancels never
does: about 50 KiB a character, without a ceiling (+15 MB per 300 connections here).
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from websockets.asyncio.client import connect

from tests.service.conftest import bvh, walk
from tests.service.server import Server
from tests.service.wsclient import start_message

pytestmark = pytest.mark.slow  # 1,200 connections through a real server, about 25 s on 2 cores

KEY = "churn-key-0123456789abcdef"
WARM_UP, MEASURED, AT_ONCE = 600, 600, 32
MOST_GROWTH_MB = 10.0


@pytest.fixture(scope="module")
def server(bundle_dir: Path) -> Iterator[Server]:
    srv = Server(bundle_dir, env={"RSMT_API_KEYS": KEY}).start()
    yield srv
    srv.stop()


def rss_mb(pid: int) -> float:
    """Resident memory of process ``pid`` in MB (``VmRSS`` of ``/proc``)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError(f"no VmRSS for process {pid}")


async def _start_and_cancel(url: str, start: dict) -> dict:
    """One connection: ``start``, then ``cancel`` at once without waiting for ``started``; the character's last
    message (``end``, or an ``error``)."""
    async with connect(url, compression=None, max_size=None, open_timeout=30) as ws:
        json.loads(await ws.recv())  # hello
        await ws.send(json.dumps(start))
        await ws.send(json.dumps({"type": "cancel", "character": start["character"]}))
        while True:
            raw = await asyncio.wait_for(ws.recv(), 30)
            if isinstance(raw, str) and (m := json.loads(raw))["type"] in ("end", "error"):
                return m


async def _round(url: str, count: int) -> list[dict]:
    start = start_message("c", 40, pace="realtime", style=bvh(walk(30)))
    room = asyncio.Semaphore(AT_ONCE)

    async def one(i: int) -> dict:
        async with room:
            return await _start_and_cancel(url, dict(start, character=f"c{i}", seed=i))

    return await asyncio.gather(*(one(i) for i in range(count)))


def _churn(server: Server, count: int) -> float:
    """A round of ``count`` start+cancel connections; the server's RSS after it."""
    ends = asyncio.run(_round(f"{server.ws}?encoding=binary&token={KEY}", count))
    assert all(m["type"] == "end" and m["reason"] == "cancelled" for m in ends), \
        [m for m in ends if m["type"] != "end"][:3]
    assert server.proc is not None
    return rss_mb(server.proc.pid)


def test_start_then_cancel_churn_leaves_memory_flat(server: Server) -> None:
    assert server.proc is not None
    before = rss_mb(server.proc.pid)
    warm = _churn(server, WARM_UP)
    after = _churn(server, MEASURED)
    print(f"RSS {before:.1f} MB at start, {warm:.1f} MB after {WARM_UP} start+cancel connections (warm-up), "
          f"{after:.1f} MB after {MEASURED} more: {after - warm:+.1f} MB")
    assert after - warm <= MOST_GROWTH_MB, f"{MEASURED} start+cancel connections grew the server by {after - warm:.1f} MB"
    assert server.ready() == 200  # and the server still serves
