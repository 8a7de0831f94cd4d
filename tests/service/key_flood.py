"""One API key's burst of engine work on a real server, in a process of its own: ``python -m tests.service.key_flood``.

``--mode start``: ``--clients`` WebSockets each loop ``start`` (an inline style clip of ``--style-frames`` frames,
``--frames`` frames asap) and, once ``started``, ``cancel``: the model's stream-setup thread is never idle.
``--mode transition``: ``--clients`` HTTP clients each loop ``POST /v1/transition`` of ``--frames`` frames, so that
that many are always in the server (running or waiting; one refused with 503 waits its ``Retry-After`` first, as the
Python client does).

Prints ``ready`` once every client has sent its first request, then after ``--seconds`` (or at SIGUSR1) one JSON
line: ``{"done": n, "statuses": {status or error code: count}}``. Flooding from a process of its own keeps the
flood's work from competing for the GIL with the measuring client's.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import signal
import sys
import time
from collections import Counter

import httpx
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from tests.service.child_process import ChildRun


class Flood:
    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.statuses: Counter[str] = Counter()
        self.done = 0
        self.stop = asyncio.Event()
        self.sent = 0

    async def starts(self, i: int) -> None:
        """One connection: start, wait for ``started`` (or an error), cancel, start the next."""
        from tests.service.conftest import bvh, walk
        from tests.service.wsclient import start_message

        a = self.args
        url = f"{a.ws}?encoding=binary&token={a.token}"
        style = bvh(walk(a.style_frames))
        async with connect(url, max_size=None, compression=None, open_timeout=30) as ws:
            json.loads(await ws.recv())  # hello
            n = 0
            with contextlib.suppress(ConnectionClosed):
                while not self.stop.is_set():
                    n += 1
                    cid = f"f{i}.{n}"
                    await ws.send(json.dumps(start_message(cid, a.frames, seed=n, pace="asap", style=style)))
                    self.sent += n == 1
                    while True:
                        raw = await ws.recv()
                        if isinstance(raw, bytes):
                            continue
                        m = json.loads(raw)
                        if m.get("character") != cid:
                            continue
                        if m["type"] == "started":
                            self.statuses["started"] += 1
                            await ws.send(json.dumps({"type": "cancel", "character": cid}))
                            break
                        if m["type"] == "error":
                            self.statuses[m["code"]] += 1
                            break
                    self.done += 1

    async def transitions(self, client: httpx.AsyncClient) -> None:
        """One client: post a transition, and as soon as it is answered, the next."""
        from tests.service.conftest import transition_body

        body = json.dumps(transition_body(frames=self.args.frames)).encode()
        first = True
        while not self.stop.is_set():
            request = client.post("/v1/transition", content=body, headers={"Content-Type": "application/json"})
            if first:
                self.sent += 1
                first = False
            try:
                r = await request
                self.statuses[str(r.status_code)] += 1
            except httpx.HTTPError as exc:
                self.statuses[type(exc).__name__] += 1
                continue
            self.done += 1
            if r.status_code == 503:  # as the Python client: wait the Retry-After (else this process takes a core)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self.stop.wait(), float(r.headers.get("retry-after", "1")))

    async def run(self) -> None:
        a = self.args
        loop = asyncio.get_running_loop()
        loop.add_signal_handler(signal.SIGUSR1, self.stop.set)
        if a.mode == "start":
            tasks = [asyncio.create_task(self.starts(i)) for i in range(a.clients)]
            client = None
        else:
            limits = httpx.Limits(max_connections=a.clients, max_keepalive_connections=a.clients)
            client = httpx.AsyncClient(base_url=a.http, timeout=60.0, limits=limits, headers={"X-API-Key": a.token})
            tasks = [asyncio.create_task(self.transitions(client)) for _ in range(a.clients)]
        deadline = time.monotonic() + 60
        while self.sent < a.clients and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
        print("ready", flush=True)
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self.stop.wait(), a.seconds)
        self.stop.set()
        for task in tasks:  # requests still waiting are abandoned: the server drops them unrun
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        if client is not None:
            await client.aclose()
        print(json.dumps({"done": self.done, "statuses": dict(self.statuses)}), flush=True)


class KeyFlood(ChildRun):
    """Run :class:`Flood` in a child process: ``with KeyFlood(...) as flood:`` returns once every client has
    sent its first request; :meth:`result` stops it and reads its counts."""

    not_started = "the flood process did not start"

    def __init__(self, server_url: str, ws_url: str, token: str, mode: str, clients: int, frames: int,
                 seconds: float = 60.0, style_frames: int = 28) -> None:
        self.command = [sys.executable, "-m", "tests.service.key_flood", "--http", server_url, "--ws", ws_url,
                        "--token", token, "--mode", mode, "--clients", str(clients), "--frames", str(frames),
                        "--seconds", str(seconds), "--style-frames", str(style_frames)]
        self.seconds = seconds
        self.done = 0
        self.statuses: dict[str, int] = {}

    def result(self) -> KeyFlood:
        """Stop the flood now and read its counts."""
        assert self.proc is not None and self.proc.stdout is not None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGUSR1)
        out, _ = self.proc.communicate(timeout=90)
        data = json.loads(out.strip().splitlines()[-1])
        self.done, self.statuses = data["done"], data["statuses"]
        return self


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--http", required=True)
    p.add_argument("--ws", required=True)
    p.add_argument("--token", required=True)
    p.add_argument("--mode", required=True, choices=["start", "transition"])
    p.add_argument("--clients", type=int, required=True)
    p.add_argument("--frames", type=int, required=True)
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--style-frames", type=int, default=28)
    asyncio.run(Flood(p.parse_args(argv)).run())


if __name__ == "__main__":
    main()
