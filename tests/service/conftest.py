"""Fixtures of the service tests: a random-weight bundle on the synthetic rig (30 fps) and motion payloads."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.bundle import Bundle
from model.motion.bvh_clip import dump_clip
from model.motion.clip import Clip
from tests.service.server import Server


@pytest.fixture(scope="session")
def bundle_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return Bundle.create(synthetic_skeleton(), seed=0).save(tmp_path_factory.mktemp("bundle") / "rsmt")


@pytest.fixture(scope="module")
def server(bundle_dir):
    """A real uvicorn with default settings for one test module; modules that need other settings
    define their own ``server`` fixture, which takes precedence."""
    srv = Server(bundle_dir).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="session")
def default_model_server():
    """One server of the default model for the session's read-only streaming tests on it (the retarget yardstick
    and the reach sweep), with messages up to 1 MiB (their poses are sent in full): one start instead of one a module."""
    from model.inference.bundle import DEFAULT_BUNDLE

    srv = Server(DEFAULT_BUNDLE, env={"RSMT_WS_MAX_MESSAGE_BYTES": str(1 << 20)}).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def client(server):
    """An HTTP client of the module's server."""
    with httpx.Client(base_url=server.url, timeout=30.0) as c:
        yield c


def bvh(clip: Clip) -> dict:
    return {"bvh": dump_clip(clip)}


def poses(clip: Clip) -> dict:
    return {"root_positions": clip.root_positions.tolist(), "rotations": clip.rotations.tolist()}


def walk(frames: int = 120, **kw) -> Clip:
    return synthetic_walk(frames, **kw)


def context_clip() -> Clip:
    return synthetic_walk(20).window(0, 20)


def target_clip(yaw: float = 45.0, shift: float = 0.0) -> Clip:
    clip = synthetic_walk(60, start_yaw_deg=yaw).window(50, 60)
    if shift:
        root = clip.root_positions.clone()
        root[:, 0] += shift
        clip = Clip(clip.skeleton, clip.rotations, root, clip.fps, clip.name)
    return clip


def transition_body(frames: int = 40, seed: int | None = 3, **kw) -> dict:
    body = {"context": bvh(context_clip()), "target": bvh(target_clip()), "frames": frames, "seed": seed,
            "style": bvh(walk(30))}
    body.update(kw)
    if "style_id" in kw:
        body.pop("style")
    return body
