"""Per-key fairness of the engine work that is not stepping (issue 64, item 4), through a real server with two API
keys: key B's burst of stream starts (a loop of ``start`` with an inline style clip on 32 connections) and of whole
transitions (40 at once, of the longest length) may not push key A's starts or transitions past 3 times their time
alone, nor get any of A's requests a 503.

The stream-setup threads and the HTTP work queue serve each key's jobs in a queue of its own, the key that has used
the least work time first (:mod:`service.key_turns`); ``RSMT_QUEUE_LIMIT`` bounds the waiting requests of each key,
so the 503 ``overloaded`` goes to the key that floods. Before, both were one first-come queue: A's ``started`` p50
went from 19 to 743 ms beside B's starts, and 43 of A's 46 transitions got 503 beside B's.
"""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.service.conftest import bvh, transition_body, walk
from tests.service.key_flood import KeyFlood
from tests.service.server import Server
from tests.service.wsclient import Ws, start_message

pytestmark = [pytest.mark.slow, pytest.mark.alone]  # two floods of one key beside another key's requests, about 45 s on 2 cores

KEY_A, KEY_B = "quiet-key-a-0123456789abcdef", "flood-key-b-0123456789abcdef"
MOST_SLOWDOWN = 3.0
START_CLIENTS, TRANSITION_CLIENTS = 32, 40
A_FRAMES, B_FRAMES = 40, 120  # B's transitions: the test model's longest
SAMPLES = 15


@pytest.fixture(scope="module")
def server(bundle_dir: Path) -> Iterator[Server]:
    srv = Server(bundle_dir, env={"RSMT_API_KEYS": f"{KEY_A},{KEY_B}"}).start()
    yield srv
    srv.stop()


def _starts_ms(server: Server, n: int) -> list[float]:
    """Key A: ``n`` starts one after another on one connection, each timed from ``start`` to ``started`` (then
    cancelled); an error fails the test. Messages are encoded before the clock starts."""
    times = []
    template = start_message("a", A_FRAMES, pace="asap", style=bvh(walk(28)))
    messages = [json.dumps(dict(template, character=f"a{i}", seed=i)) for i in range(n)]
    with Ws(server.ws, encoding="binary", query=f"token={KEY_A}") as ws:
        for i, message in enumerate(messages):
            cid = f"a{i}"
            began = time.perf_counter()
            ws.send(message)
            while True:
                m = ws.recv(60)
                if m.get("character") != cid or m["type"] == "frame":
                    continue
                assert m["type"] == "started", m
                times.append((time.perf_counter() - began) * 1e3)
                break
            ws.send({"type": "cancel", "character": cid})
            while (m := ws.recv(60))["type"] != "end" or m["character"] != cid:
                pass
    return times


def _transitions_ms(server: Server, n: int) -> tuple[list[float], list[int]]:
    """Key A: ``n`` transitions one after another; their times and every status other than 200."""
    times, refused = [], []
    body = json.dumps(transition_body(frames=A_FRAMES)).encode()
    headers = {"X-API-Key": KEY_A, "Content-Type": "application/json"}
    with httpx.Client(base_url=server.url, timeout=60.0, headers=headers) as client:
        for _ in range(n):
            began = time.perf_counter()
            r = client.post("/v1/transition", content=body)
            times.append((time.perf_counter() - began) * 1e3)
            if r.status_code != 200:
                refused.append(r.status_code)
    return times, refused


def _flood(server: Server, mode: str, clients: int, frames: int) -> KeyFlood:
    return KeyFlood(server.url, server.ws, KEY_B, mode, clients, frames)


def test_a_keys_starts_keep_their_time_beside_another_keys_start_loop(server: Server) -> None:
    _starts_ms(server, 3)  # warm the path
    alone = statistics.median(_starts_ms(server, SAMPLES))
    with _flood(server, "start", START_CLIENTS, 10) as flood:
        time.sleep(1.0)
        beside = statistics.median(_starts_ms(server, SAMPLES))
        b = flood.result()
    print(f"key A start -> started p50: {alone:.1f} ms alone, {beside:.1f} ms beside key B's {START_CLIENTS} "
          f"connections looping start ({b.done} of B's starts meanwhile: {b.statuses})")
    assert b.statuses.get("started", 0) > SAMPLES  # B's loop did run
    assert beside <= MOST_SLOWDOWN * alone, (alone, beside)


def test_a_keys_transitions_keep_their_time_and_get_no_503_beside_another_keys_burst(server: Server) -> None:
    _transitions_ms(server, 3)
    alone = statistics.median(_transitions_ms(server, SAMPLES)[0])
    with _flood(server, "transition", TRANSITION_CLIENTS, B_FRAMES) as flood:
        time.sleep(1.0)
        times, refused = _transitions_ms(server, SAMPLES)
        b = flood.result()
    beside = statistics.median(times)
    print(f"key A transition p50: {alone:.1f} ms alone, {beside:.1f} ms beside key B's {TRANSITION_CLIENTS} "
          f"concurrent {B_FRAMES}-frame transitions; A refused: {refused}; B's answers: {b.statuses}")
    assert b.statuses.get("200", 0) > 0  # B's burst did run
    assert not refused
    assert beside <= MOST_SLOWDOWN * alone, (alone, beside)
