"""One API key's load on a real server, in a process of its own: ``python -m tests.service.key_load``.

Opens as many WebSockets as ``--characters`` needs at ``--per-connection`` each, starts that many characters
of ``--pace`` (each restarted as it ends), reads every frame without decoding it and counts the frames per
tenth of a second of ``time.monotonic()`` (one clock for every process of the machine); a character about
to arrive gets more frames (``retarget``), so the load goes on without new ``start`` work. Prints ``ready`` once
every character has started, then after ``--seconds`` (or at SIGUSR1) one JSON line: ``{"buckets": {tenth: frames}, "started":
n, "errors": [...]}``. Reading in a process of its own keeps the load's frames from competing for the GIL with
the measuring client's.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import signal
import struct
import sys
import time
from collections import Counter
from typing import Any, Self

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from tests.service.child_process import ChildRun
from tests.service.wsclient import start_message

_FLOAT = struct.Struct("<f")
EXTEND_AT = 10  # frames left when a character is given more


class Load:
    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.buckets: Counter[int] = Counter()
        self.errors: list[dict[str, Any]] = []
        self.started = 0
        self.runs = 0

    async def start(self, ws: ClientConnection, base: str) -> None:
        self.runs += 1
        await ws.send(json.dumps(start_message(f"{base}.{self.runs}", self.args.frames, seed=self.runs,
                                               pace=self.args.pace, style=self.args.style)))

    async def read(self, ws: ClientConnection) -> None:
        """Count frames until the connection is closed (by :meth:`run`). A character about to arrive is given
        ``--frames`` more (a ``retarget`` with ``frames``: no new setup work), one that ended is restarted."""
        buckets = self.buckets
        names: dict[int, str] = {}  # slot -> character id
        extended: set[int] = set()  # slots given more frames, until their remaining count rises
        try:
            async for raw in ws:
                if isinstance(raw, bytes):
                    buckets[int(time.monotonic() * 10)] += 1
                    slot, remaining = int(_FLOAT.unpack_from(raw, 0)[0]), _FLOAT.unpack_from(raw, len(raw) - 4)[0]
                    if remaining > EXTEND_AT:
                        extended.discard(slot)
                    elif slot not in extended and slot in names:
                        extended.add(slot)
                        await ws.send(json.dumps({"type": "retarget", "character": names[slot],
                                                  "frames": self.args.frames}))
                    continue
                m = json.loads(raw)
                if m["type"] == "started":
                    self.started += 1
                    names[m["slot"]] = m["character"]
                elif m["type"] == "end":
                    await self.start(ws, m["character"].rsplit(".", 1)[0])
                elif m["type"] == "error" and m.get("code") != "unknown_character":  # a retarget just too late
                    self.errors.append(m)
        except ConnectionClosed:
            pass

    async def run(self) -> None:
        a = self.args
        url = f"{a.ws}?encoding=binary&token={a.token}"
        conns: list[ClientConnection] = []
        readers: list[asyncio.Task[None]] = []
        deadline = time.monotonic() + 120
        for first in range(0, a.characters, a.per_connection):  # one connection at a time, each once started
            ws = await connect(url, max_size=None, compression=None, open_timeout=30)
            json.loads(await ws.recv())  # hello
            conns.append(ws)
            readers.append(asyncio.create_task(self.read(ws)))
            for i in range(first, min(a.characters, first + a.per_connection)):
                await self.start(ws, f"c{i}")
                await asyncio.sleep(0)  # let the readers read meanwhile
            while self.started + len(self.errors) < min(a.characters, first + a.per_connection):
                if time.monotonic() > deadline:
                    break
                await asyncio.sleep(0.05)
        print("ready", flush=True)
        stop = asyncio.Event()
        asyncio.get_running_loop().add_signal_handler(signal.SIGUSR1, stop.set)  # KeyLoad.stop
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), a.seconds)
        for ws in conns:
            await ws.close()
        await asyncio.gather(*readers)
        print(json.dumps({"buckets": dict(self.buckets), "started": self.started, "errors": self.errors[:5]}),
              flush=True)


class KeyLoad(ChildRun):
    """Run :class:`Load` in a child process for ``seconds`` (bounded): ``with KeyLoad(...) as load:`` returns once
    its characters have started (within its two minutes to start); :meth:`result` waits for its end and reads its
    counts."""

    not_started = "the load process did not start its characters"

    def __init__(self, ws_url: str, token: str, characters: int, seconds: float, frames: int, pace: str = "asap",
                 per_connection: int = 64) -> None:
        self.seconds = seconds
        self.command = [sys.executable, "-m", "tests.service.key_load", "--ws", ws_url, "--token", token,
                        "--characters", str(characters), "--per-connection", str(per_connection), "--pace", pace,
                        "--frames", str(frames), "--seconds", str(seconds)]
        self.buckets: dict[int, int] = {}
        self.started = 0
        self.errors: list[dict[str, Any]] = []
        self.ready_at = 0.0  # time.monotonic() when every character had started

    def __enter__(self) -> Self:
        super().__enter__()
        self.ready_at = time.monotonic()
        return self

    def stop(self) -> None:
        """End the run now (before its ``seconds``); :meth:`result` then reads it."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGUSR1)

    def result(self) -> KeyLoad:
        """Wait for the end of the run (its ``seconds`` and a minute more at most) and read its counts."""
        assert self.proc is not None and self.proc.stdout is not None
        out, _ = self.proc.communicate(timeout=self.seconds + 60)
        data = json.loads(out.strip().splitlines()[-1])
        self.buckets = {int(k): v for k, v in data["buckets"].items()}
        self.started, self.errors = data["started"], data["errors"]
        return self

    def rate(self, since: float, until: float) -> float:
        """Frames per second received in ``[since, until]`` (``time.monotonic()``, whole tenths of a second)."""
        lo, hi = int(since * 10) + 1, int(until * 10)
        return sum(v for k, v in self.buckets.items() if lo <= k < hi) / max(0.1, (hi - lo) / 10)


def main(argv: list[str] | None = None) -> None:
    from tests.service.conftest import bvh, walk

    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--ws", required=True)
    p.add_argument("--token", required=True)
    p.add_argument("--characters", type=int, required=True)
    p.add_argument("--per-connection", type=int, default=64)
    p.add_argument("--pace", default="asap", choices=["asap", "realtime"])
    p.add_argument("--frames", type=int, required=True)
    p.add_argument("--seconds", type=float, required=True)
    args = p.parse_args(argv)
    args.style = bvh(walk(30))
    asyncio.run(Load(args).run())


if __name__ == "__main__":
    main()
