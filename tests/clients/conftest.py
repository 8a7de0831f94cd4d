"""Fixtures of the client tests: one real ``rsmt serve`` process (API key on) shared by the Python, C# and
C++ client tests, motion files, and the toolchain builds (each made once per session)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.bundle import Bundle
from model.inference.bundle_styles import StyleClip
from model.inference.style_packing import write_builtin_styles
from model.motion.bvh_clip import dump_clip
from tests.clients.helpers import API_KEY, build_core_test, build_harness
from tests.service.server import Server

torch.set_num_threads(1)


def serve_command(bundle: Path) -> list[str]:
    """``rsmt serve`` as the product runs it (settings beyond the options come from RSMT_* variables)."""
    return [sys.executable, "-m", "rsmt_cli.main", "serve", "--host", "127.0.0.1", "--port", "{port}",
            "--models", str(bundle), "--threads", "1"]


@pytest.fixture(scope="session")
def client_bundle(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = Bundle.create(synthetic_skeleton(), seed=0).save(tmp_path_factory.mktemp("client-bundle") / "rsmt")
    write_builtin_styles(path, [StyleClip("walk", synthetic_walk(40), "walk.bvh")])  # served as builtin:walk
    return path


@pytest.fixture(scope="session")
def server(client_bundle: Path):
    srv = Server(client_bundle, env={"RSMT_API_KEYS": API_KEY, "RSMT_WARMUP_MAX_BATCH": "4"},
                 command=serve_command(client_bundle)).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="session")
def motions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """BVH files on the synthetic rig: context (20 frames), two targets, and two style clips."""
    d = tmp_path_factory.mktemp("motions")
    clips = {
        "context": synthetic_walk(20).window(0, 20),
        "target": synthetic_walk(60, start_yaw_deg=45.0).window(50, 60),
        "target2": synthetic_walk(60, start_yaw_deg=-30.0, speed_cm_s=150.0).window(50, 60),
        "style": synthetic_walk(120),
        "style2": synthetic_walk(90, speed_cm_s=150.0, cadence_hz=1.1, stride_deg=30.0),
    }
    out = {}
    for name, clip in clips.items():
        out[name] = d / f"{name}.bvh"
        out[name].write_text(dump_clip(clip))
    return out


@pytest.fixture(scope="session")
def harness_exe(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_harness(tmp_path_factory.mktemp("unity-harness"))


@pytest.fixture(scope="session")
def core_test_exe(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_core_test(tmp_path_factory.mktemp("unreal-core"))
