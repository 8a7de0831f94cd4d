"""The in-engine samples (the network run by the game engine on the graphs of ``rsmt export onnx``).

* Unreal (``clients/unreal/RsmtLink/Samples/InEngineInference``): its state loop, compiled with g++ as Unreal would,
  runs a transition with a mid-stream retarget on the exported graphs, each graph call answered by onnxruntime here
  (what NNE's ORT runtime does in the engine), and gives the torch engine's frames; its NNE adapter type-checks
  against stubs of the NNE API (tests/clients/unreal_stubs).
* Unity (``clients/unity/Samples~/InEngineInference``): its state loop, compiled with Mono's mcs, runs the same
  transition the same way (integers and flags as int32, as the Inference Engine passes them) and gives the same
  frames; the Inference Engine adapter and the MonoBehaviour type-check against stubs of the Inference Engine API
  (tests/clients/test_unity_core.py compiles every sample).
"""

from __future__ import annotations

import json
import struct
import subprocess
from pathlib import Path
from typing import IO

import numpy as np
import onnxruntime as ort
import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.inference.bundle import DEFAULT_BUNDLE, Bundle
from model.inference.engine import CharacterBatch, Engine
from model.inference.overrides import Overrides
from model.motion.kinematics import forward_kinematics
from model.nets.sampler import StyleContext
from tests.clients.helpers import REPO, UNITY, UNREAL, gxx, mono_tools, run

pytestmark = [pytest.mark.timeout(900), pytest.mark.slow]  # builds the engine samples with mcs and g++

SAMPLE = UNREAL / "Samples" / "InEngineInference"
STUBS = REPO / "tests" / "clients" / "unreal_stubs"
FLAGS = ["-std=c++17", "-O1", "-Wall", "-Wextra", "-Wshadow", "-Wconversion", "-Wno-sign-conversion", "-pedantic",
         "-Werror", "-fno-exceptions", "-fno-rtti"]
DTYPES: dict[int, np.dtype] = {0: np.dtype(np.float32), 1: np.dtype(np.int64), 2: np.dtype(np.bool_),
                               3: np.dtype(np.int32)}
ORT_TYPES = {"tensor(float)": np.float32, "tensor(int64)": np.int64, "tensor(bool)": np.bool_}
TYPES = {v: k for k, v in DTYPES.items()}
FRAMES, RETARGET_AT = 40, 20


def test_the_nne_adapter_type_checks_against_the_nne_api():
    run([gxx(), *FLAGS, f"-I{STUBS}", f"-I{SAMPLE}", "-fsyntax-only", str(SAMPLE / "RsmtNneGraph.cpp")], timeout=300)
    for header in STUBS.glob("*.h"):
        assert "STUB OF UNREAL" in header.read_text().splitlines()[0], header


def test_the_unity_sample_is_listed_and_its_stubs_say_what_they_are():
    package = json.loads((UNITY / "package.json").read_text())
    assert "Samples~/InEngineInference" in [s["path"] for s in package["samples"]]
    stub = REPO / "tests" / "clients" / "unity_stubs" / "UnityInferenceEngine.cs"
    assert "STUB OF UNITY'S INFERENCE ENGINE API" in stub.read_text().splitlines()[0]


# ---------------------------------------------------------------------- the Unreal loop on onnxruntime
def _write_set(out: IO[bytes], tensors: dict[str, np.ndarray]) -> None:
    out.write(struct.pack("<I", len(tensors)))
    for name, value in tensors.items():
        value = np.ascontiguousarray(value)
        out.write(struct.pack("<I", len(name)) + name.encode() + struct.pack("<BI", TYPES[value.dtype], value.ndim))
        out.write(struct.pack(f"<{value.ndim}q", *value.shape) + struct.pack("<Q", value.nbytes) + value.tobytes())


def _read(stream: IO[bytes], n: int) -> bytes:
    data = stream.read(n)
    assert len(data) == n, "the loop program stopped mid-message"
    return data


def _read_set(stream: IO[bytes]) -> dict[str, np.ndarray]:
    (count,) = struct.unpack("<I", _read(stream, 4))
    out = {}
    for _ in range(count):
        (size,) = struct.unpack("<I", _read(stream, 4))
        name = _read(stream, size).decode()
        kind, rank = struct.unpack("<BI", _read(stream, 5))
        shape = struct.unpack(f"<{rank}q", _read(stream, 8 * rank))
        (nbytes,) = struct.unpack("<Q", _read(stream, 8))
        out[name] = np.frombuffer(_read(stream, nbytes), dtype=DTYPES[kind]).reshape(shape)
    return out


def _write_names(out: IO[bytes], names: list[str]) -> None:
    out.write(struct.pack("<I", len(names)))
    for n in names:
        out.write(struct.pack("<I", len(n)) + n.encode())


@pytest.fixture(scope="module")
def graphs(default_onnx_export: Path) -> Path:
    return default_onnx_export  # tests/conftest.py: the default bundle's `rsmt export onnx`, once a session


def _engine_frames(engine: Engine, context, target, retarget, style_clip) -> torch.Tensor:
    style, _ = engine.encode_style(style_clip)
    batch = CharacterBatch(engine)
    ch = engine.prepare(context, target, FRAMES, style, deterministic=True)
    batch.add(ch)
    rows = []
    for frame in range(FRAMES):
        if frame == RETARGET_AT:
            engine.retarget(ch, batch, target=retarget)
        out = batch.step()
        rows.append((out.rotations[0], out.root_positions[0]))
    rot, root = torch.stack([r for r, _ in rows]), torch.stack([p for _, p in rows])
    return forward_kinematics(rot, root, engine.skeleton.offsets_tensor(), engine.skeleton.parents)[0]


class _Case:
    """One request for a loop program: a retargeted transition of the default model, and the engine's frames for it."""

    def __init__(self, graphs: Path) -> None:
        self.sidecar = json.loads((graphs / "rsmt-onnx.json").read_text())
        self.sessions = [ort.InferenceSession(str(graphs / self.sidecar["graphs"][g]["file"]),
                                              providers=["CPUExecutionProvider"])
                         for g in ("prepare", "begin", "step", "output")]
        self.engine = Engine(Bundle.load(DEFAULT_BUNDLE), overrides=Overrides(int8_lstm=False))
        walk = self.engine.conform(synthetic_walk(frames=200, speed_cm_s=140.0, turn_deg_s=20.0))
        k = self.sidecar["sampler"]["context"]
        self.context, self.target, self.style = walk.window(0, k), walk.window(k + 45, k + 46), walk.window(60, 180)
        moved = self.target.root_positions.clone()
        moved[:, 0] += 100.0
        self.retarget = type(self.target)(self.target.skeleton, self.target.rotations, moved, self.target.fps, "moved")
        style = ort.InferenceSession(str(graphs / "style.onnx"), providers=["CPUExecutionProvider"])
        style_out = style.run(None, {"rotations": self.style.rotations[None].numpy(),
                                     "roots": self.style.root_positions[None].numpy()})
        self.request = {
            "context_rotations": self.context.rotations.numpy(), "context_roots": self.context.root_positions.numpy(),
            "target_rotations": self.target.rotations.numpy(), "target_roots": self.target.root_positions.numpy(),
            "retarget_rotations": self.retarget.rotations.numpy(),
            "retarget_roots": self.retarget.root_positions.numpy(),
            "frames": np.array([FRAMES], dtype=np.int64), "retarget_at": np.array([RETARGET_AT], dtype=np.int64),
            "noise": np.zeros((1, 2 * self.sidecar["sampler"]["width"]), dtype=np.float32),
            **{f"style.{n}": v for n, v in zip(StyleContext.flat_names(), style_out)}}

    def run(self, command: list[str], int32: bool) -> tuple[torch.Tensor, int]:
        """Joint positions ``[FRAMES, J, 3]`` of the program's frames, and how many graph calls it made. ``int32``:
        the program passes integers and flags as int32 (Unity's Inference Engine does)."""

        def out(values: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
            return {k: v.astype(np.int32) if int32 and v.dtype != np.float32 else v for k, v in values.items()}

        proc = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        assert proc.stdin is not None and proc.stdout is not None
        for s in self.sessions:
            _write_names(proc.stdin, [i.name for i in s.get_inputs()])
        _write_names(proc.stdin, self.sidecar["output_memory"])
        _write_set(proc.stdin, out(self.request))
        proc.stdin.flush()
        frames, calls = [], 0
        while True:
            kind = _read(proc.stdout, 1)[0]
            if kind == 3:
                break
            if kind == 2:
                frames.append(_read_set(proc.stdout))
                continue
            assert kind == 1 and calls < 10 * FRAMES, "the loop runs two graphs a frame"
            (index,) = struct.unpack("<I", _read(proc.stdout, 4))
            session = self.sessions[index]
            inputs = _read_set(proc.stdout)
            types = {i.name: ORT_TYPES[i.type] for i in session.get_inputs()}
            outputs = session.run(None, {k: v.astype(types[k]) for k, v in inputs.items()})
            _write_set(proc.stdin, out(dict(zip([o.name for o in session.get_outputs()], outputs))))
            proc.stdin.flush()
            calls += 1
        assert proc.wait(30) == 0
        assert len(frames) == FRAMES
        joints = self.engine.skeleton.num_joints
        rot = torch.from_numpy(np.stack([f["rotations"] for f in frames]).reshape(FRAMES, joints, 4).copy())
        root = torch.from_numpy(np.stack([f["root"] for f in frames]).copy())
        sk = self.engine.skeleton
        return forward_kinematics(rot, root, sk.offsets_tensor(), sk.parents)[0], calls

    def check(self, got: torch.Tensor, calls: int) -> None:
        assert calls == 2 + 2 + 2 * FRAMES  # prepare + begin, again at the retarget, two graphs a frame
        expected = _engine_frames(self.engine, self.context, self.target, self.retarget, self.style)
        assert float((got - expected).norm(dim=-1).max()) < 1e-3  # cm, on every joint of every frame
        plain = _engine_frames(self.engine, self.context, self.target, self.target, self.style)
        assert float((plain - expected).norm(dim=-1).max()) > 1.0  # the retarget moved it: the loop really retargeted


@pytest.fixture(scope="module")
def case(graphs: Path) -> _Case:
    return _Case(graphs)


def test_the_unreal_sample_loop_on_the_exported_graphs_gives_the_engines_frames(case: _Case, tmp_path: Path):
    exe = tmp_path / "rsmt_loop_bridge"
    run([gxx(), *FLAGS, f"-I{SAMPLE}", str(REPO / "tests" / "clients" / "engine_samples" / "rsmt_loop_bridge.cpp"),
         str(SAMPLE / "RsmtOnnxStateLoop.cpp"), "-o", str(exe)], timeout=300)
    case.check(*case.run([str(exe)], int32=False))


def test_the_unity_sample_loop_on_the_exported_graphs_gives_the_engines_frames(case: _Case, tmp_path: Path):
    mcs, mono = mono_tools()
    exe = tmp_path / "RsmtLoopBridge.exe"
    run([mcs, "-nologo", "-warnaserror", f"-out:{exe}", str(REPO / "tests" / "clients" / "engine_samples" /
         "RsmtLoopBridge.cs"), str(UNITY / "Samples~" / "InEngineInference" / "RsmtOnnxStateLoop.cs")], timeout=300)
    case.check(*case.run([mono, str(exe)], int32=True))
