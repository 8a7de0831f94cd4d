"""Failover that resumes in the engine clients' cores (issue 26 item 3): a real ``rsmt serve`` is SIGKILLed while
two characters stream to the Unity core (Mono harness, ``RsmtStreamClient.Failover``) or the Unreal core (g++
program with ``rsmt::Failover``), and a new server starts on the same port, standing in for the load balancer's
next replica. The style registered on the first server is unknown to the second, so the client registers it
again. Every character must deliver all its frames once and in order, arrive at its target, and continue the
motion where it stopped; with failover off the same kill ends the stream."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus
from websockets.sync.client import ClientConnection, connect

from tests.clients.failover_run import FRAMES, KILL_AFTER, Delivered, check, kill, start_server
from tests.clients.helpers import API_KEY, build_core_test, mono_tools, unity_to_model, unreal_to_model
from tests.service.server import Server

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]  # slow: compiles with mcs and g++


def run_until_killed(cmd: list[str], bundle: Path, port: int, first, timeout: float = 150) -> tuple[int, str, str]:
    """Run ``cmd``; when it prints ``{"kill": true}``, SIGKILL ``first`` and start a new server on ``port``."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out: list[str] = []
    second = None
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # bounded: the program gives up after its own timeout
            out.append(line)
            if line.strip() == '{"kill": true}' and second is None:
                kill(first)
                second = start_server(bundle, port)
        rc = proc.wait(timeout)
        err = proc.stderr.read() if proc.stderr is not None else ""
    finally:
        if proc.poll() is None:
            proc.kill()
        if second is not None:
            second.stop()
    assert second is not None, f"the client never reached the kill point:\n{''.join(out)}\n{err[-3000:]}"
    return rc, "".join(out), err


def unity_failover(harness_exe: Path, bundle: Path, motions: dict[str, Path], tmp_path: Path, failover: bool) -> dict:
    _, mono = mono_tools()
    first = start_server(bundle)
    out = tmp_path / "failover.json"
    cmd = [mono, str(harness_exe), "failover", "--url", first.url, "--api-key", API_KEY,
           "--context", str(motions["context"]), "--target", str(motions["target"]), "--target2", str(motions["target2"]),
           "--style", str(motions["style"]), "--frames", str(FRAMES), "--characters", "2", "--encoding", "binary",
           "--kill-after", str(KILL_AFTER), "--attempts", "60", "--timeout", "120", "--out", str(out)]
    if failover:
        cmd.append("--failover")
    try:
        rc, stdout, stderr = run_until_killed(cmd, bundle, first.port, first)
    finally:
        first.stop()
    assert rc == 0, stderr[-3000:]
    return json.loads(out.read_text())


def unity_delivered(character: dict) -> Delivered:
    frames = character["frames"]
    roots, rots = unity_to_model(np.array([f["root"] for f in frames]), np.array([f["rotations"] for f in frames]), 0.01)
    end = character["end"] or {}
    return Delivered([f["seq"] for f in frames], roots, rots, character["resumed_at"], end.get("frames"), end.get("reason"))


def test_unity_core_resumes_every_character_on_a_new_server(harness_exe, client_bundle, motions, tmp_path):
    r = unity_failover(harness_exe, client_bundle, motions, tmp_path, failover=True)
    assert r["errors"] == [] and r["closed"] is None and not r["timed_out"], r["errors"]
    assert r["lost"] and r["resumes"] == 1 and r["reregistrations"] >= 1  # the new server did not know the style
    lines = [check(unity_delivered(r["characters"][cid]), motions[target], f"unity {cid}")
             for cid, target in (("f0", "target"), ("f1", "target2"))]
    print("\n" + "\n".join(lines))


def test_unity_core_without_failover_loses_the_stream(harness_exe, client_bundle, motions, tmp_path):
    r = unity_failover(harness_exe, client_bundle, motions, tmp_path, failover=False)
    assert r["closed"] is not None and r["lost"] == [] and r["resumes"] == 0
    assert all(len(c["frames"]) < FRAMES and c["end"] is None for c in r["characters"].values())


# ---------------------------------------------------------------------- Unreal core (rsmt::Failover)

@pytest.fixture(scope="module")
def failover_exe(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_core_test(tmp_path_factory.mktemp("unreal-failover"), "rsmt_failover_test")


def open_stream(url: str) -> ClientConnection:
    return connect(url.replace("http://", "ws://") + "/v1/stream?encoding=binary", additional_headers={"X-API-Key": API_KEY},
                   proxy=None, compression=None, open_timeout=10)


class CoreSocket:
    """The socket of rsmt_failover_test (see the program's header): every decision is the core's; this only
    moves bytes, kills the first server when told and starts its stand-in on the same port."""

    def __init__(self, bundle: Path, first: Server) -> None:
        self.bundle, self.first = bundle, first
        self.second: Server | None = None
        self.ws: ClientConnection = open_stream(first.url)
        self.pending: list[str] = []
        self.out: dict = {"characters": {}, "done": None}

    def next_line(self) -> str:
        if self.pending:
            return self.pending.pop(0)
        try:
            raw = self.ws.recv(30)
        except ConnectionClosed as exc:
            return f"C {exc.rcvd.code if exc.rcvd is not None else 1006}"
        return ("T " + raw.encode().hex()) if isinstance(raw, str) else ("B " + raw.hex())

    def act(self, msg: dict) -> None:
        chars = self.out["characters"]
        if "send" in msg:
            self.ws.send(msg["send"])
        elif "register" in msg:
            r = httpx.post(self.first.url + "/v1/styles", content=msg["register"], timeout=60,
                           headers={"X-API-Key": API_KEY, "Content-Type": "application/json"})
            assert r.status_code in (200, 201), r.text
            self.ws.send(msg["then"])
        elif "reconnect" in msg:
            time.sleep(msg["delay"])
            try:
                self.ws = open_stream(self.first.url)
            except (OSError, InvalidHandshake, InvalidStatus, TimeoutError):
                self.pending.append("X")
        elif "kill" in msg:
            kill(self.first)
            self.second = start_server(self.bundle, self.first.port)
        elif "frame" in msg:
            chars.setdefault(msg["frame"]["character"], {"frames": [], "resumed_at": -1, "end": None})
            chars[msg["frame"]["character"]]["frames"].append(msg["frame"])
        elif "started" in msg and msg["started"]["resumed"]:
            ch = chars[msg["started"]["character"]]
            ch["resumed_at"] = len(ch["frames"])
        elif "end" in msg:
            chars[msg["end"]["character"]]["end"] = msg["end"]

    def run(self, proc: subprocess.Popen, timeout_s: float = 150) -> dict:
        assert proc.stdin is not None and proc.stdout is not None
        deadline = time.monotonic() + timeout_s
        while self.out["done"] is None and time.monotonic() < deadline:
            proc.stdin.write(self.next_line() + "\n")
            proc.stdin.flush()
            for answer in proc.stdout:  # the program's answers to that line, up to {"next"} or {"done"}
                msg = json.loads(answer)
                if "next" in msg:
                    break
                if "done" in msg:
                    self.out["done"] = msg["done"]
                    break
                self.act(msg)
        return self.out


def unreal_failover(exe: Path, bundle: Path, motions: dict[str, Path], tmp_path: Path, failover: bool) -> dict:
    first = start_server(bundle)
    body = {"name": "ue-failover", "motion": {"bvh": motions["style"].read_text()}}
    style_id = httpx.post(first.url + "/v1/styles", json=body, headers={"X-API-Key": API_KEY}, timeout=60).json()["style_id"]
    (tmp_path / "body.json").write_text(json.dumps(body))
    cmd = [str(exe), "--context", str(motions["context"]), "--target", str(motions["target"]), "--target2",
           str(motions["target2"]), "--style-id", style_id, "--style-body", str(tmp_path / "body.json"), "--frames",
           str(FRAMES), "--characters", "2", "--kill-after", str(KILL_AFTER), "--attempts", "60"]
    if failover:
        cmd.append("--failover")
    sock = CoreSocket(bundle, first)
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        out = sock.run(proc)
    finally:
        proc.kill()
        proc.wait(10)
        sock.ws.close()
        first.stop()
        if sock.second is not None:
            sock.second.stop()
    assert sock.second is not None and out["done"] is not None, out["done"]
    return out


def unreal_delivered(character: dict) -> Delivered:
    frames = character["frames"]
    roots, rots = unreal_to_model(np.array([f["root"] for f in frames]), np.array([f["rotations"] for f in frames]))
    end = character["end"] or {}
    return Delivered([f["seq"] for f in frames], roots, rots, character["resumed_at"], end.get("frames"), end.get("reason"))


def test_unreal_core_resumes_every_character_on_a_new_server(failover_exe, client_bundle, motions, tmp_path):
    r = unreal_failover(failover_exe, client_bundle, motions, tmp_path, failover=True)
    done = r["done"]
    assert done["errors"] == [] and done["closed"] is None, done
    assert done["resumes"] == 1 and done["reregistrations"] >= 1  # the new server did not know the style
    lines = [check(unreal_delivered(r["characters"][cid]), motions[target], f"unreal {cid}")
             for cid, target in (("f0", "target"), ("f1", "target2"))]
    print("\n" + "\n".join(lines))


def test_unreal_core_without_failover_loses_the_stream(failover_exe, client_bundle, motions, tmp_path):
    r = unreal_failover(failover_exe, client_bundle, motions, tmp_path, failover=False)
    assert r["done"]["closed"] == 1006 and r["done"]["resumes"] == 0
    assert all(len(c["frames"]) < FRAMES and c["end"] is None for c in r["characters"].values())
