"""Per-key shares of the step budget, measured through real servers: ``python -m tests.service.step_share_bench``.

Starts ``rsmt``'s app under uvicorn on 127.0.0.1 with two API keys, once per ``--shares`` value (``off``: every
key's characters in the same batches; ``equal``: the default with keys on), one after the other, and on each:

* **realtime beside asap**: key A drives ``--asap`` asap characters (in a process of its own) while key B
  streams ``--realtime`` realtime characters; prints B's speed (the frame period over B's mean gap between
  frames: 1.00 is real time), B's p99 and largest gap, and A's frames per second;
* **two asap keys**: key S drives ``--small`` asap characters and key A ``--big``, first each alone, then
  both together; prints each key's frames per second together as a share of its rate alone (equal shares
  of the step time: S about 0.5 or more; one batch for both: S steps at the big batch's pace).

The model is a random-weight bundle on the synthetic rig unless ``--bundle`` names one (the step's cost is the
architecture's, not the weights').
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from model.data.synthetic import synthetic_skeleton
from model.inference.bundle import Bundle
from tests.service.key_load import KeyLoad
from tests.service.probes import GapProbe, p99
from tests.service.server import Server

KEY_A, KEY_B = "step-share-key-a-0123456789abcdef", "step-share-key-b-0123456789abcdef"


def serve(bundle: Path, shares: str, extra: dict[str, str] | None = None) -> Server:
    env = {"RSMT_API_KEYS": f"{KEY_A},{KEY_B}", "RSMT_STEP_SHARES": shares, **(extra or {})}
    return Server(bundle, env=env).start(timeout_s=180)


def realtime_beside_asap(server: Server, asap: int, realtime: int, seconds: float = 8.0) -> dict[str, float]:
    """Key B's realtime speed and gaps while key A drives ``asap`` asap characters."""
    with GapProbe(server.ws, characters=0, query=f"token={KEY_B}") as idle:
        frames, fps = idle.frames, float(idle.ws.hello["model"]["fps"])
    with KeyLoad(server.ws, KEY_A, asap, seconds + 5.0, frames) as load:
        with GapProbe(server.ws, characters=realtime, query=f"token={KEY_B}") as probe:
            time.sleep(2.0)
            since = time.monotonic()
            time.sleep(seconds)
            until = time.monotonic()
            gaps = probe.gaps_ms(since, until)
        load.result()
    assert not probe.errors and not load.errors, (probe.errors, load.errors)
    return {"speed": (1e3 / fps) / float(np.mean(gaps)) if len(gaps) else 0.0, "p99_ms": p99(gaps),
            "max_ms": float(gaps.max()) if len(gaps) else float("inf"), "a_frames_per_s": load.rate(since, until),
            "gaps": float(len(gaps))}


def rate_alone(server: Server, token: str, characters: int, frames: int, seconds: float) -> float:
    """Frames per second of ``characters`` asap characters of ``token`` with no other key on the server."""
    with KeyLoad(server.ws, token, characters, seconds + 1.0, frames) as load:
        since = load.ready_at + 1.0
        load.result()
    assert not load.errors, load.errors
    return load.rate(since, since + seconds)


def rates_together(server: Server, small_key: str, small: int, big_key: str, big: int, frames: int,
                   seconds: float) -> tuple[float, float]:
    """Frames per second of ``small`` asap characters of ``small_key`` and of ``big`` of ``big_key``, side by
    side (each key's load in a process of its own), over ``seconds`` once the small key's load is ready."""
    with KeyLoad(server.ws, big_key, big, seconds + 120.0, frames) as b, \
            KeyLoad(server.ws, small_key, small, seconds + 1.0, frames) as s:
        since = s.ready_at + 1.0
        s.result()
        b.stop()
        b.result()
    assert not b.errors and not s.errors, (b.errors, s.errors)
    return s.rate(since, since + seconds), b.rate(since, since + seconds)


def two_asap_keys(server: Server, small: int, big: int, seconds: float = 5.0) -> dict[str, float]:
    """Each key's asap frame rate beside the other as a share of its rate alone."""
    with GapProbe(server.ws, characters=0, query=f"token={KEY_B}") as idle:
        frames = idle.frames
    alone_s = rate_alone(server, KEY_B, small, frames, seconds)
    alone_a = rate_alone(server, KEY_A, big, frames, seconds)
    together_s, together_a = rates_together(server, KEY_B, small, KEY_A, big, frames, seconds)
    return {"small_alone": alone_s, "big_alone": alone_a, "small_together": together_s, "big_together": together_a,
            "small_share": together_s / max(alone_s, 1e-9), "big_share": together_a / max(alone_a, 1e-9)}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bundle", type=Path, help="a model bundle (default: random weights on the synthetic rig)")
    p.add_argument("--shares", nargs="+", default=["off", "equal"], choices=["off", "equal"])
    p.add_argument("--asap", type=int, default=128, help="key A's asap characters beside key B's realtime ones")
    p.add_argument("--realtime", type=int, default=1, help="key B's realtime characters")
    p.add_argument("--small", type=int, default=2, help="key S's asap characters (two asap keys)")
    p.add_argument("--big", type=int, default=64, help="key A's asap characters (two asap keys)")
    p.add_argument("--only", choices=["realtime", "asap"], help="run one of the two measures")
    p.add_argument("--rounds", type=int, default=1, help="repeat both servers this often, alternating")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        bundle = args.bundle or Bundle.create(synthetic_skeleton(), seed=0).save(Path(tmp) / "rsmt")
        for r in range(args.rounds):
            for shares in args.shares:
                server = serve(bundle, shares)
                try:
                    rt = realtime_beside_asap(server, args.asap, args.realtime) if args.only != "asap" else None
                    two = two_asap_keys(server, args.small, args.big) if args.only != "realtime" else None
                finally:
                    server.stop()
                if rt is not None:
                    print(f"round {r + 1} shares={shares}: key B's {args.realtime} realtime beside key A's "
                          f"{args.asap} asap: speed {rt['speed']:.2f}, p99 gap {rt['p99_ms']:.0f} ms, max "
                          f"{rt['max_ms']:.0f} ms ({rt['gaps']:.0f} gaps), A {rt['a_frames_per_s']:.0f} frames/s",
                          flush=True)
                if two is not None:
                    print(f"round {r + 1} shares={shares}: asap keys of {args.small} and {args.big} characters: "
                          f"alone {two['small_alone']:.0f} / {two['big_alone']:.0f} frames/s, together "
                          f"{two['small_together']:.0f} / {two['big_together']:.0f}: shares of their rate alone "
                          f"{two['small_share']:.2f} / {two['big_share']:.2f}", flush=True)

if __name__ == "__main__":
    main()
