"""``rsmt export onnx``: the default bundle's graphs pass onnx.checker, load in onnxruntime at opset <= 15 with a
dynamic batch, and the sidecar describes what an engine needs to run them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest

pytestmark = pytest.mark.slow  # exports the default bundle's five graphs

GRAPHS = ("prepare", "style", "begin", "step", "output")


@pytest.fixture(scope="module")
def exported(default_onnx_export: Path) -> Path:
    return default_onnx_export  # tests/conftest.py: `rsmt export onnx --out DIR`, once a session


def test_every_graph_passes_the_checker_at_opset_15_or_below(exported: Path) -> None:
    for name in GRAPHS:
        model = onnx.load(exported / f"{name}.onnx")
        onnx.checker.check_model(model, full_check=True)
        assert max(o.version for o in model.opset_import if o.domain in ("", "ai.onnx")) <= 15
        assert all(o.domain in ("", "ai.onnx") for o in model.opset_import), "only standard operators"


def _feed(session: ort.InferenceSession, batch: int, steps: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    feed = {}
    for i in session.get_inputs():
        shape = [batch if d == "batch" else steps if isinstance(d, str) else d for d in i.shape]
        if i.type == "tensor(bool)":
            feed[i.name] = np.ones(shape, dtype=bool)
        elif i.type == "tensor(int64)":
            feed[i.name] = np.full(shape, 20, dtype=np.int64)
        else:
            feed[i.name] = rng.standard_normal(shape).astype(np.float32)
    return feed


@pytest.mark.parametrize("batch", [1, 5])
def test_onnxruntime_runs_the_step_and_output_graphs_at_any_batch(exported: Path, batch: int) -> None:
    rng = np.random.default_rng(0)
    for name in ("step", "output"):
        session = ort.InferenceSession(str(exported / f"{name}.onnx"), providers=["CPUExecutionProvider"])
        outputs = session.run(None, _feed(session, batch, 27, rng))
        assert all(o.shape[0] == batch for o in outputs)


def test_the_style_graph_takes_clips_of_any_length(exported: Path) -> None:
    sidecar = json.loads((exported / "rsmt-onnx.json").read_text())
    session = ort.InferenceSession(str(exported / "style.onnx"), providers=["CPUExecutionProvider"])
    joints = len(sidecar["skeleton"]["joints"])
    lengths = []
    for frames in (sidecar["sampler"]["style_frames_min"], 120):
        rotations = np.zeros((2, frames, joints, 4), dtype=np.float32)
        rotations[..., 3] = 1.0
        roots = np.zeros((2, frames, 3), dtype=np.float32)
        roots[..., 1] = 90.0
        roots[..., 2] = np.arange(frames) * 4.0  # walking along +Z
        out = dict(zip([o.name for o in session.get_outputs()],
                       session.run(None, {"rotations": rotations, "roots": roots})))
        lengths.append(out["mask"].shape[1])
        assert out["keys1"].shape[0] == 2 and out["keys1"].shape[2] == out["mask"].shape[1]
        assert np.isfinite(out["keys1"]).all()
    assert lengths[0] < lengths[1]


def test_the_sidecar_lists_every_graph_input_and_the_state_layout(exported: Path) -> None:
    sidecar = json.loads((exported / "rsmt-onnx.json").read_text())
    assert sidecar["format"] == "rsmt-onnx/1" and sidecar["opset"] <= 15
    assert set(sidecar["graphs"]) == set(GRAPHS)
    for name, graph in sidecar["graphs"].items():
        model = onnx.load(exported / graph["file"])
        assert [i["name"] for i in graph["inputs"]] == [i.name for i in model.graph.input], name
        for tensor in graph["inputs"]:
            assert tensor["name"] in sidecar["state_layout"] or tensor["name"] in sidecar["output_memory"] \
                or tensor["name"].startswith(("context_", "target_", "gamma", "beta", "keys", "values")) \
                or tensor["name"] in ("rotations", "roots", "mask", "frames", "velocity_known", "shift"), tensor["name"]
    prepare = sidecar["graphs"]["prepare"]
    assert [o["name"] for o in prepare["outputs"]][-len(sidecar["output_memory"]):] == sidecar["output_memory"]
    assert sidecar["output_settings"]["foot_lock"] is True  # the default bundle's settings travel with it
    assert len(sidecar["normalisation"]["style_mean"]) == len(sidecar["skeleton"]["joints"]) * 12


def test_the_style_graph_gives_the_engines_style_context(exported: Path) -> None:
    from model.data.synthetic import synthetic_walk
    from model.inference.bundle import DEFAULT_BUNDLE, Bundle
    from model.inference.engine import Engine
    from model.nets.sampler import StyleContext

    engine = Engine(Bundle.load(DEFAULT_BUNDLE), compiled=False)
    clip = engine.conform(synthetic_walk(frames=100, turn_deg_s=25.0))
    style, _ = engine.encode_style(clip)
    session = ort.InferenceSession(str(exported / "style.onnx"), providers=["CPUExecutionProvider"])
    out = session.run(None, {"rotations": clip.rotations[None].numpy(), "roots": clip.root_positions[None].numpy()})
    for name, got in zip([o.name for o in session.get_outputs()], out):
        assert name in StyleContext.flat_names()
        np.testing.assert_allclose(got, getattr(style.context, name).numpy(), atol=1e-4, err_msg=name)


def test_a_bundle_with_a_style_strength_is_not_exported(tmp_path: Path) -> None:
    import dataclasses

    from model.export.onnx_bundle import export_onnx
    from model.inference.bundle import DEFAULT_BUNDLE, Bundle

    bundle = Bundle.load(DEFAULT_BUNDLE)
    bundle.inference = dataclasses.replace(bundle.inference, style_strength=1.25)
    with pytest.raises(ValueError, match="strength 1.25.*--style-strength 1 to export"):
        export_onnx(bundle, tmp_path / "out")
    assert not (tmp_path / "out").exists()  # refused before anything is written
