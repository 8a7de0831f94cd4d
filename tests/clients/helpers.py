"""Shared pieces of the client tests: motion files, toolchain builds (mcs, g++) and stream capture.

Every build and run is small and single-threaded: the machine is shared.
"""

from __future__ import annotations

import json
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
UNITY = REPO / "clients" / "unity"
UNREAL = REPO / "clients" / "unreal" / "RsmtLink"
CORE_SOURCES = ["RsmtJson.cpp", "RsmtMath.cpp", "RsmtConvert.cpp", "RsmtProtocol.cpp", "RsmtReassembler.cpp",
                "RsmtJitterBuffer.cpp", "RsmtFailover.cpp", "RsmtMotionCut.cpp"]
API_KEY = "client-tests-key-0123456789abcdef"

# Hello, then frames: the acceptance seed and length.
SEED = 7
FRAMES = 40


# ---------------------------------------------------------------------- coordinate conversions, inverted

def unity_to_model(roots: np.ndarray, rots: np.ndarray, metres_per_unit: float) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of the Unity client's conversion: p = (-x, y, z) / s, q = (x, -y, -z, w)."""
    roots = np.asarray(roots, dtype=np.float64) * np.array([-1.0, 1.0, 1.0]) / metres_per_unit
    rots = np.asarray(rots, dtype=np.float64) * np.array([1.0, -1.0, -1.0, 1.0])
    return roots, rots


def unreal_to_model(roots: np.ndarray, rots: np.ndarray, cm_per_unit: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of the Unreal client's conversion: p = (x, z, y) / s, q = (-x, -z, -y, w)."""
    roots = np.asarray(roots, dtype=np.float64)[..., [0, 2, 1]] / cm_per_unit
    rots = np.asarray(rots, dtype=np.float64)[..., [0, 2, 1, 3]] * np.array([-1.0, -1.0, -1.0, 1.0])
    return roots, rots


# ---------------------------------------------------------------------- C# (Mono)

MONO_PACKAGES = "mono-mcs libmono-system-net-http4.0-cil"


def mono_tools() -> tuple[str, str]:
    """``(mcs, mono)``, or a skip naming the Debian packages when Mono or its System.Net.Http is missing."""
    mcs, mono = shutil.which("mcs"), shutil.which("mono")
    if not mcs or not mono:
        pytest.skip(f"Mono is not installed (no `mcs`/`mono` on PATH): apt-get install {MONO_PACKAGES} "
                    "(.ci/run does this)")
    lib = Path(mono).resolve().parents[1] / "lib" / "mono"
    if not any(lib.glob("*/System.Net.Http.dll")):
        pytest.skip(f"Mono's System.Net.Http.dll is missing under {lib}: apt-get install libmono-system-net-http4.0-cil")
    return mcs, mono


def build_harness(out_dir: Path) -> Path:
    """The Unity core plus the console harness, compiled with mcs (warnings are errors)."""
    mcs, _ = mono_tools()
    exe = out_dir / "RsmtHarness.exe"
    sources = sorted(str(p) for p in (UNITY / "Runtime" / "Core").glob("*.cs")) + [str(UNITY / "Harness~" / "RsmtHarness.cs")]
    run([mcs, "-nologo", "-warnaserror", "-r:System.Net.Http.dll", f"-out:{exe}", *sources], timeout=300)
    return exe


def run_harness(exe: Path, *args: str, timeout: float = 180) -> subprocess.CompletedProcess:
    _, mono = mono_tools()
    return run([mono, str(exe), *args], timeout=timeout, check=False)


# ---------------------------------------------------------------------- C++ (g++)

def gxx() -> str:
    path = shutil.which("g++")
    if not path:
        pytest.skip("g++ is not installed: the Unreal core tests build RsmtCore with it (apt-get install g++)")
    return path


CORE = UNREAL / "Source" / "RsmtCore"
# The warnings Unreal's compilers would raise, as errors; every translation unit is compiled with them.
CXX_FLAGS = ["-std=c++17", "-O1", "-Wall", "-Wextra", "-Wshadow", "-Wconversion", "-Wno-sign-conversion", "-pedantic",
             "-Werror", "-fno-exceptions", "-fno-rtti", f"-I{CORE / 'Public'}"]
_core_objects: dict[str, Path] = {}  # a source of RsmtCore/Private -> its object file, compiled once per test session


def core_objects(out_dir: Path, sources: list[str]) -> list[Path]:
    """The object files of ``sources`` (names in ``RsmtCore/Private``), each compiled once per session (the first
    time into ``out_dir``) and linked into every program that needs it: the same sources and flags as before."""
    for name in sources:
        if name not in _core_objects:
            obj = out_dir / "objects" / f"{Path(name).stem}.o"
            obj.parent.mkdir(parents=True, exist_ok=True)
            run([gxx(), *CXX_FLAGS, "-c", str(CORE / "Private" / name), "-o", str(obj)], timeout=600)
            _core_objects[name] = obj
    return [_core_objects[name] for name in sources]


def build_core_test(out_dir: Path, program: str = "rsmt_core_test") -> Path:
    """RsmtCore (no Unreal) and a test program of ``Tests/``, with the warnings Unreal's compilers would raise as errors."""
    exe = out_dir / program
    objects = core_objects(out_dir, CORE_SOURCES)
    run([gxx(), *CXX_FLAGS, str(UNREAL / "Tests" / f"{program}.cpp"), *map(str, objects), "-o", str(exe)], timeout=600)
    return exe


# ---------------------------------------------------------------------- processes

def run(cmd: list[str], timeout: float, check: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    if check and proc.returncode != 0:
        raise AssertionError(f"{cmd[0]} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return proc


def json_lines(text: str) -> list[dict]:
    return [json.loads(line) for line in text.splitlines() if line.strip().startswith("{")]


# ---------------------------------------------------------------------- capture

def capture(ws_url: str, encoding: str, start: dict, path: Path, api_key: str = API_KEY, timeout: float = 60.0) -> Path:
    """Record one session from a live server: hello, then everything until the character ends.

    Records are ``[kind 'T' | 'B'][uint32 LE length][payload]``, exactly as received.
    """
    from websockets.sync.client import connect

    records: list[bytes] = []
    with connect(f"{ws_url}?encoding={encoding}", additional_headers={"X-API-Key": api_key}, proxy=None,
                 compression=None, open_timeout=30) as ws:
        def take() -> str | bytes:
            raw = ws.recv(timeout)
            data = raw.encode() if isinstance(raw, str) else raw
            records.append((b"T" if isinstance(raw, str) else b"B") + struct.pack("<I", len(data)) + data)
            return raw

        hello = json.loads(take())
        assert hello["type"] == "hello"
        ws.send(json.dumps(start))
        while True:
            raw = take()
            if isinstance(raw, str):
                msg = json.loads(raw)
                if msg["type"] == "error":
                    raise AssertionError(f"server error while capturing: {msg}")
                if msg["type"] == "end" and msg.get("character") == start["character"]:
                    break
    path.write_bytes(b"".join(records))
    return path


def read_capture(path: Path) -> list[tuple[str, bytes]]:
    data, out, pos = path.read_bytes(), [], 0
    while pos < len(data):
        kind, (length,) = chr(data[pos]), struct.unpack_from("<I", data, pos + 1)
        out.append((kind, data[pos + 5:pos + 5 + length]))
        pos += 5 + length
    return out
