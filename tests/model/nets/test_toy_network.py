"""A second network behind the seam (:mod:`model.nets.transition_net`), added the way docs/architecture.md says:
a toy GRU that walks the pose straight at the target, with its own state and style records, registered under a
name, saved in a bundle, run by the engine and served by a real uvicorn server. Nothing else in the project names it.
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import httpx
import pytest
import torch
from torch import nn

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.bundle import Bundle
from model.inference.engine import Engine
from model.nets.manifold import ManifoldDecoder
from model.nets.pose_state import PoseState, integrate
from model.nets.sampler import SamplerConfig
from model.nets.tensor_record import TensorRecord
from model.nets.transition_net import NETWORKS, TransitionNet
from tests.service.conftest import transition_body
from tests.service.server import Server

Tensor = torch.Tensor
NAME = "toy-gru"


@dataclass
class GruState(TensorRecord):
    POSES: ClassVar[tuple[str, ...]] = ("pose",)
    FIXED: ClassVar[tuple[str, ...]] = ("target_pos", "target_rot", "target_emb", "noise")

    h: Tensor
    pose: PoseState
    target_pos: Tensor
    target_rot: Tensor
    target_emb: Tensor
    tta: Tensor
    noise: Tensor


@dataclass
class GruStyle(TensorRecord):
    film: Tensor  # [B, channels]: the code's time mean


class ToyGru(nn.Module):
    """Moves every joint a share of what is left to the target each frame, plus a small learned correction."""

    state_type = GruState
    style_type = GruStyle

    def __init__(self, config: SamplerConfig, decoder: ManifoldDecoder) -> None:
        super().__init__()
        self.config = config
        d, w = config.joints * 12, config.width
        self.style = nn.Linear(d, config.style_channels)
        self.target = nn.Linear(d, w)
        self.cell = nn.GRUCell(d + w + config.style_channels, config.rnn)
        self.head = nn.Linear(config.rnn, config.joints * 3)

    def encode_style(self, features: Tensor) -> Tensor:
        return self.style(features)

    def style_context(self, code: Tensor) -> GruStyle:
        return GruStyle(code.mean(dim=1))

    def noise(self, generator: torch.Generator | None) -> Tensor:
        if generator is None:
            return torch.zeros(1, self.config.width)
        return torch.randn(1, self.config.width, generator=generator) * self.config.noise_std

    def target_fields(self, state: GruState, target: PoseState, velocity_known: Tensor,
                      frames: Tensor) -> dict[str, Tensor]:
        return {"target_pos": target.positions(), "target_rot": target.rot, "target_emb": self.target(target.vector())}

    def reencoded(self, state: GruState) -> dict[str, Tensor]:
        return {}  # its target code is all it keeps of its weights, and a style switch keeps the weights

    def begin(self, context: PoseState, target: PoseState, frames: Tensor, noise: Tensor, style: GruStyle, *,
              velocity_known: Tensor | None = None) -> GruState:
        emb = self.target(target.vector())
        h = emb.new_zeros(emb.shape[0], self.config.rnn)
        for i in range(context.rel.shape[1]):  # warm up on every context frame
            h = self.cell(torch.cat([context.index((slice(None), i)).vector(), emb + noise, style.film], -1), h)
        return GruState(h, context.index((slice(None), -1)), target.positions(), target.rot, emb, frames.long(), noise)

    def step(self, state: GruState, style: GruStyle) -> tuple[GruState, dict[str, Tensor]]:
        pose = state.pose
        h = self.cell(torch.cat([pose.vector(), state.target_emb + state.noise, style.film], -1), state.h)
        share = 1.0 / state.tta.clamp_min(1).float().view(-1, 1, 1)
        velocity = (state.target_pos - pose.positions()) * share + 0.1 * torch.tanh(self.head(h)).view(-1, pose.rel.shape[1], 3)
        turned = integrate(pose, velocity, (state.target_rot - pose.rot) * share, root=self.config.root)
        return GruState(h, turned, state.target_pos, state.target_rot, state.target_emb, state.tta - 1, state.noise), {}


def register() -> None:
    """What a new network adds to the project: its name in the table of networks."""
    NETWORKS[NAME] = ToyGru


@pytest.fixture(scope="module")
def toy_bundle(tmp_path_factory: pytest.TempPathFactory) -> Path:
    register()
    return Bundle.create(synthetic_skeleton(), network=NAME, seed=3).save(tmp_path_factory.mktemp("toy") / "toy")


def test_the_toy_network_is_a_transition_net_and_its_bundle_names_it(toy_bundle: Path) -> None:
    net: TransitionNet = ToyGru(SamplerConfig(joints=22), ManifoldDecoder.__new__(ManifoldDecoder))
    assert net.state_type.carried_names() == ("h", "rel", "vel", "rot", "root_xz", "tta")
    assert json.loads((toy_bundle / "config.json").read_text())["network"] == NAME
    loaded = Bundle.load(toy_bundle)
    assert isinstance(loaded.net, ToyGru) and loaded.network == NAME
    with pytest.raises(ValueError, match="not the RSMT sampler"):
        loaded.sampler  # noqa: B018 - training code asks for the RSMT sampler by name


@pytest.mark.parametrize("compiled", [True, False])
def test_the_engine_runs_it_traced_and_eager_and_it_walks_to_the_target(toy_bundle: Path, compiled: bool) -> None:
    engine = Engine(Bundle.load(toy_bundle), compiled=compiled)
    walk = synthetic_walk(frames=120)
    style, _ = engine.encode_style(walk.window(20, 80))
    chars = [engine.prepare(walk.window(0, 10), walk.window(58, 60), 40, style, seed=s) for s in (1, 2)]
    for (rot, root), _ in zip(engine.generate(chars), chars):
        assert rot.shape == (40, engine.skeleton.num_joints, 4) and bool(torch.isfinite(rot).all() and torch.isfinite(root).all())
        miss = (root[-1, [0, 2]] - walk.root_positions[59, [0, 2]]).norm()
        assert float(miss) < 10.0, f"the toy network ended {float(miss):.1f} cm from the target's root"


def test_a_real_server_serves_a_transition_with_it(toy_bundle: Path) -> None:
    script = ("import sys, uvicorn\nfrom tests.model.nets.test_toy_network import register\nregister()\n"
              "uvicorn.run('service.app:create_app', factory=True, host='127.0.0.1', port=int(sys.argv[1]), "
              "log_level='warning')")
    server = Server(toy_bundle, command=[sys.executable, "-c", script, "{port}"]).start()
    try:
        reply = httpx.post(server.url + "/v1/transition", json=transition_body(frames=30), timeout=60.0)
        assert reply.status_code == 200, reply.text
        frames = reply.json()["frames"]
        assert len(frames) == 30 and all(math.isfinite(x) for x in frames[-1]["root_position"])
        served = httpx.get(server.url + "/v1/models", timeout=10.0).json()["models"]
        assert [m["version"] for m in served] == [Bundle.load(toy_bundle).version]  # the toy's bundle, nothing else
    finally:
        server.stop()
