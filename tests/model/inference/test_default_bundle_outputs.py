"""The default bundle's frames, pinned: a change that moves any output step's result by one bit fails here.

The hashes were recorded with the engine before the output steps moved into one pipeline
(model/inference/output/); a refactor keeps them. A deliberate change of behaviour records them
anew (run this file with ``RSMT_PRINT_HASHES=1`` and ``-s`` to print the new ones). They are of
this torch build on x86-64 AVX2 CPUs; another build may round differently: the failure names the cases
that moved. On a CPU whose kernels round otherwise (AVX-512/AMX) a case passes within 1e-4 of the same frames
recorded there (tests/fixtures/default_bundle_frames.safetensors; RSMT_RECORD_FRAMES=1 records them anew).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

import pytest
import torch
from safetensors.torch import load_file, save_file

from model.data.synthetic import synthetic_walk
from model.inference.bundle import DEFAULT_BUNDLE, Bundle
from model.inference.engine import CharacterBatch, Engine
from model.inference.overrides import Overrides

# case name -> sha256 of its rotations' and roots' float32 bytes; recorded anew when the legs' forward kinematics
# summed each joint's bones in one product (issue 52: float32 rounding, roots at most 3e-5 cm, quaternions 1.1e-6)
PINNED = {
    "own settings, exact arrival": "d42b059d5bddc50cf71e2858c08fe8118811dcf554df4c9d6edc307fcb1ca9c3",
    "every step off": "e64ae7fd2e7af6b6391cbf82f73e862eb87b0b89b9c24746febeb5c952bfdbc4",
    "no foot lock, seeded noise": "4e27f0a47cf611d728327c7c477cc17fb022d6a85887a9e969318a0abf61a61d",
    "no stride warp, eager": "f42ba6f5c8976002b1cb327f1597b96968b34b8da9fd0224ba9b854472474e97",
    # Re-pinned on the AVX-512 machine of the recorded frames when exact arrival stopped outrunning the speed cap
    # (issue 63 item 5: the exact character's root on three bent frames, by up to 1.6 cm); an AVX2 machine passes
    # it by those frames.
    "stream of two, retargeted": "9eb985fcba20b1b96a720b0561819dd5e599375af5a83d55ab78d54b851ae7c0",
}


# The same frames as float32 arrays (quaternions and cm), recorded with RSMT_RECORD_FRAMES=1 on a Xeon with
# AVX-512 and AMX, where the hashes above (of an AVX2 machine) do not hold; a case passes within TOLERANCE of them.
FRAMES = Path(__file__).resolve().parents[2] / "fixtures" / "default_bundle_frames.safetensors"
TOLERANCE = 1e-4


def _engine(bundle: Bundle, compiled: bool = True, **settings: Any) -> Engine:
    return Engine(bundle, threads=1, compiled=compiled, overrides=Overrides(**settings))


def _digest(*tensors: torch.Tensor) -> str:
    h = hashlib.sha256()
    for t in tensors:
        h.update(t.contiguous().numpy().tobytes())
    return h.hexdigest()


def _outputs() -> dict[str, tuple[torch.Tensor, ...]]:
    bundle = Bundle.load(DEFAULT_BUNDLE)
    walk = synthetic_walk(frames=160, speed_cm_s=140.0, turn_deg_s=20.0)
    turn = synthetic_walk(frames=160, speed_cm_s=90.0, turn_deg_s=-40.0, phase=0.3)
    out: dict[str, tuple[torch.Tensor, ...]] = {}
    off = {"smoothing": 0.0, "foot_lock": False, "steering": 0, "floor": False, "stride_warp": 0.0}
    # name, the engine's overrides, traced or not, the request's options, its frames
    runs: tuple[tuple[str, dict[str, Any], bool, dict[str, Any], int], ...] = (
        ("own settings, exact arrival", {}, True, {"deterministic": True, "exact_arrival": True}, 40),
        ("every step off", off, True, {"deterministic": True}, 30),
        ("no foot lock, seeded noise", {"foot_lock": False}, True, {"seed": 7}, 45),
        ("no stride warp, eager", {"stride_warp": 0.0}, False, {"seed": 3, "exact_arrival": True}, 20))
    for name, settings, compiled, request, length in runs:
        engine = _engine(bundle, compiled, **settings)
        style, _ = engine.encode_style(walk.window(20, 140))
        ch = engine.prepare(walk.window(0, 10), turn.window(60, 62), length, style, **request)
        out[name] = tuple(engine.generate([ch])[0])
    engine = _engine(bundle)
    styles = [engine.encode_style(c.window(20, 140))[0] for c in (walk, turn)]
    chars = [engine.prepare(walk.window(5, 15), turn.window(70, 72), 30, styles[0], seed=1),
             engine.prepare(turn.window(0, 10), walk.window(50, 52), 24, styles[1], seed=2, exact_arrival=True)]
    batch = CharacterBatch(engine)
    batch.add(chars[0])
    frames: list[torch.Tensor] = []
    for t in range(40):
        if t == 3:
            batch.add(chars[1])
        if t == 8:
            engine.retarget(chars[0], batch, target=turn.window(100, 102), frames=20)
        if not len(batch):
            break
        step = batch.step()
        frames += [step.rotations.flatten(), step.root_positions.flatten()]
        batch.drop_finished()
    out["stream of two, retargeted"] = (torch.cat(frames),)
    return out


@pytest.fixture(scope="module")
def outputs() -> dict[str, tuple[torch.Tensor, ...]]:
    return _outputs()


def test_the_default_bundle_gives_the_pinned_frames(outputs: dict[str, tuple[torch.Tensor, ...]]) -> None:
    got = {name: _digest(*tensors) for name, tensors in outputs.items()}
    if os.environ.get("RSMT_PRINT_HASHES"):
        print(got)
    if os.environ.get("RSMT_RECORD_FRAMES"):
        save_file({name: flat(tensors) for name, tensors in outputs.items()}, str(FRAMES))
    reference = load_file(str(FRAMES))
    # Bit for bit as pinned, or (a CPU whose kernels round differently: AVX-512/AMX against AVX2) within
    # float32 rounding of the frames recorded on such a CPU with the same code.
    moved = [name for name in PINNED if got[name] != PINNED[name] and not torch.allclose(
        flat(outputs[name]), reference[name], rtol=0.0, atol=TOLERANCE)]
    assert not moved, f"the default bundle's frames changed in: {', '.join(moved)}"


def flat(tensors: tuple[torch.Tensor, ...]) -> torch.Tensor:
    """A case's output tensors as one flat tensor (how the recorded frames are stored)."""
    return torch.cat([t.flatten() for t in tensors])
