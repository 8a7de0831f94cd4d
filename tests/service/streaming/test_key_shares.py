"""One key cannot take every character slot (issue 53, item 7), against a real server with two API keys: key A
trying to fill every slot gets its share (a quarter of RSMT_MAX_CHARACTERS by default, over all its
connections) and key B still starts its real-time characters beside them."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest

from tests.service.conftest import bvh, walk
from tests.service.probes import GapProbe, p99
from tests.service.server import Server
from tests.service.wsclient import Ws, start_message

pytestmark = pytest.mark.slow  # fills a server's character slots from two keys

KEY_A, KEY_B = "share-key-a-0123456789abcdef", "share-key-b-0123456789abcdef"
MAX_CHARACTERS, PER_CONNECTION = 16, 8


@pytest.fixture(scope="module")
def server(bundle_dir) -> Iterator[Server]:
    srv = Server(bundle_dir, env={"RSMT_API_KEYS": f"{KEY_A},{KEY_B}", "RSMT_MAX_CHARACTERS": str(MAX_CHARACTERS),
                                  "RSMT_MAX_CHARACTERS_PER_CONNECTION": str(PER_CONNECTION)}).start()
    yield srv
    srv.stop()


def _ask(ws: Ws, prefix: str, count: int, frames: int) -> None:
    for i in range(count):
        ws.send(start_message(f"{prefix}{i}", frames, seed=i, pace="realtime", style=bvh(walk(30))))


class Events:
    """Every started, end and error message of one connection, with the time it was read (in a thread)."""

    def __init__(self, ws: Ws) -> None:
        self.ws = ws
        self.seen: list[tuple[float, dict]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        for m in self.ws.messages_until(self._stop, poll_s=0.5):
            if m["type"] in ("started", "end", "error"):
                self.seen.append((time.monotonic(), m))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)


def test_one_key_gets_its_share_of_the_slots_and_another_key_still_starts(server):
    frames = 120  # the test model's longest transition: 4 s at 30 fps
    share = MAX_CHARACTERS // 4
    with Ws(server.ws, encoding="binary", query=f"token={KEY_A}") as a1, \
            Ws(server.ws, encoding="binary", query=f"token={KEY_A}") as a2:
        events = [Events(a1), Events(a2)]
        _ask(a1, "a", PER_CONNECTION, frames)
        _ask(a2, "b", PER_CONNECTION, frames)
        deadline = time.monotonic() + 120
        while sum(m["type"] in ("started", "error") for e in events for _, m in e.seen) < 2 * PER_CONNECTION:
            assert time.monotonic() < deadline, [m for e in events for _, m in e.seen]
            time.sleep(0.1)
        with GapProbe(server.ws, characters=4, query=f"token={KEY_B}") as probe:  # key B, beside key A's share
            time.sleep(3.0)
            now = time.monotonic()
            gaps = probe.gaps_ms(now - 2.0, now)
        for e in events:
            e.stop()
    timeline = sorted(((t, m) for e in events for t, m in e.seen), key=lambda x: x[0])
    live = most = 0
    for _, m in timeline:
        live += {"started": 1, "end": -1}.get(m["type"], 0)
        most = max(most, live)
    refused = [m for _, m in timeline if m["type"] == "error"]
    print(f"key A asked for {2 * PER_CONNECTION} of {MAX_CHARACTERS} slots on two connections: at most {most} live "
          f"at once (share {share}), {len(refused)} refused; key B's 4 beside them: p99 gap {p99(gaps):.1f} ms")
    assert all(m["code"] == "too_many_characters" and "share" in m["message"] for m in refused), refused
    assert most == share and refused
    assert not probe.errors, probe.errors
    assert len(gaps) > 50
