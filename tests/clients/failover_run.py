"""What the engine clients' failover tests share: a server to kill and its stand-in on the same port (the load
balancer's next replica), and the checks of what a client delivered across the kill (every frame once and in
order, arrival at the target, a resume that continues the motion)."""

from __future__ import annotations

import signal
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rsmt_client.motion import load_bvh_poses

from model.inference.output.arrival import DEFAULT_WINDOW
from tests.clients.conftest import serve_command
from tests.clients.helpers import API_KEY
from tests.service.server import Server
from tests.service.stream_run import fk

FRAMES = 60  # realtime pace: 2 s per character, long enough to kill the server mid-stream
KILL_AFTER = 12  # frames of the first character before the kill
# The resume's step may be at most this multiple of the largest step between the stream's other frames (as
# tests/service/test_replicas.py: the random test model's first step from a context is up to 1.4x its largest
# later one; a resume from the wrong frames moves the root many times more).
CONTINUITY = 2.0
ARRIVAL_CM = 0.05  # exact_arrival: the arrival frame is the target pose up to float32 and BVH rounding
ENV = {"RSMT_API_KEYS": API_KEY, "RSMT_WARMUP_MAX_BATCH": "2"}


def start_server(bundle: Path, port: int | None = None) -> Server:
    """``rsmt serve`` on a free port, or on ``port`` (a replacement for a killed server: same URL)."""
    if port is None:
        return Server(bundle, env=ENV, command=serve_command(bundle)).start()
    srv = Server(bundle, env=ENV, command=[c.replace("{port}", str(port)) for c in serve_command(bundle)])
    srv.port, srv.url, srv.ws = port, f"http://127.0.0.1:{port}", f"ws://127.0.0.1:{port}/v1/stream"
    return srv.start()


def kill(srv: Server) -> None:
    assert srv.proc is not None
    srv.proc.send_signal(signal.SIGKILL)
    srv.proc.wait(30)


@dataclass
class Delivered:
    """One character as a client delivered it, in model units and axes."""

    seqs: list[int]
    roots: np.ndarray  # [T, 3]
    rotations: np.ndarray  # [T, J, 4]
    resumed_at: int  # index of the first frame after the resume (-1: none)
    end_frames: int | None
    end_reason: str | None


def check(run: Delivered, target_bvh: Path, label: str) -> str:
    """Every frame once and in order, an end that counts them all, arrival at the target, and a resume whose
    first frame continues the last one received. Returns the figures as a line."""
    assert run.seqs == list(range(FRAMES)), (label, run.seqs)
    assert run.end_frames == FRAMES and run.end_reason == "arrived", (label, run.end_frames, run.end_reason)
    target = load_bvh_poses(target_bvh.read_text())
    want = fk(np.asarray(target.root_positions)[-1:], np.asarray(target.rotations)[-1:])[0]
    pos = fk(run.roots, run.rotations)  # [T, J, 3]
    root_err = float(np.linalg.norm(pos[-1, 0] - want[0]))
    joint_err = float(np.linalg.norm(pos[-1] - want, axis=-1).max())
    assert root_err < ARRIVAL_CM and joint_err < ARRIVAL_CM, (label, root_err, joint_err)
    moved = np.linalg.norm(np.diff(pos, axis=0), axis=-1)  # [T-1, J]: step i goes from frame i to frame i+1
    steps = np.stack([moved[:, 0], moved.max(axis=1)], axis=1)[: FRAMES - DEFAULT_WINDOW]
    k = run.resumed_at - 1  # the step into the first resumed frame
    assert 0 <= k < len(steps), (label, run.resumed_at)
    jump, usual = steps[k], np.delete(steps, [k], axis=0).max(axis=0)
    assert (jump <= CONTINUITY * usual).all(), (label, jump, usual)
    return (f"{label}: resumed at frame {run.resumed_at}, jump root {jump[0]:.2f} / joints {jump[1]:.2f} cm vs "
            f"largest usual step {usual[0]:.2f} / {usual[1]:.2f} cm, arrival error root {root_err:.4f} / joints "
            f"{joint_err:.4f} cm")
