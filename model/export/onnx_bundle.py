"""``rsmt export onnx``: a bundle's graphs (:mod:`model.export.onnx_graphs`) written to a folder with a JSON sidecar.

Layout::

    OUT/
      prepare.onnx  one character's context and target poses -> begin's inputs, the canonical frame, the first memory
      style.onnx    a style clip's poses -> style context
      begin.onnx    context and target states -> the sampler state before the first frame
      step.onnx     sampler state + style context -> next state and steering's ground shift
      output.onnx   a generated state + the output steps' memory -> local rotations, root, new memory
      rsmt-onnx.json  the sidecar: skeleton, every graph's inputs and outputs, the state layout, the
                      normalisation, the output settings and the loop that runs them

A bundle's style adapters are exported beside it as ``adapters/NAME/step.onnx`` (and begin, style).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import onnx

from model.export.onnx_graphs import Example, Graph, begin_graph, output_graph, prepare_graph, step_graph, style_graph
from model.export.onnx_symbolics import OPSET
from model.inference.bundle import Bundle
from model.inference.engine import Engine
from model.inference.overrides import Overrides

FORMAT = "rsmt-onnx/1"
SIDECAR = "rsmt-onnx.json"

# What each state tensor holds (shapes in the sidecar's graph listings; B: characters).
STATE_LAYOUT: dict[str, str] = {
    "h": "LSTM hidden state [B, rnn]",
    "c": "LSTM cell state [B, rnn]",
    "rel": "joint positions relative to the root's ground point [B, J, 3], cm, canonical frame (heights absolute)",
    "vel": "joint velocities p[t] - p[t-1] [B, J, 3], cm per frame, canonical frame",
    "rot": "global joint rotations as the first two matrix columns (6D) [B, J, 6], canonical frame",
    "root_xz": "the root's ground position [B, 2] (x, z), cm, canonical frame",
    "phase": "phase vectors [B, phases, 2]",
    "target_vec": "the target encoder's input [B, J*12(+1)] (read by begin only)",
    "target_pos": "target joint positions [B, J, 3], canonical frame",
    "target_rot": "target global rotations [B, J, 6], canonical frame",
    "target_emb": "the encoded target [B, width]",
    "tta": "frames left including the next one [B], int64 (step decrements it)",
    "noise": "per-transition noise [B, 2*width] (zeros: deterministic; else normal * noise_std)",
    "late": "[B] bool, true for a character given a new target mid-stream (the retarget facing window)",
    "remaining": "[B] int64, frames after the one being output (0 on the arrival frame)",
    "yaw": "[B] the canonical frame's facing, radians about +Y (world = turn(yaw) * canonical + origin)",
    "origin": "[B, 3] the canonical frame's origin in the world (the last context frame's root on the ground)",
}

LOOP = [
    "once per style clip: style(its local rotations and roots) -> the style context "
    "(9 tensors; keep it, stack rows to batch characters)",
    "once per character: prepare(its last context frames and the target frame, local rotations and roots) -> "
    "begin's context and target states, yaw and origin, the output memory (a batch of one: stack rows to batch)",
    "once per transition: begin(context states, target state, frames, noise, velocity_known, style) -> state",
    "every frame: step(state, style, late) -> (h, c, rel, vel, rot, root_xz, phase, tta) replace the state's, shift",
    "then output(rel, vel, rot, root_xz, yaw, origin, remaining = frames left after this one, shift, memory) "
    "-> local rotations [B, J, 4] (x, y, z, w), root position [B, 3] in the world, memory for the next frame",
    "noise: zeros for a deterministic transition, else normal(0, 1) * noise_std, [B, 2*width]; late: false until the "
    "character is given a new target mid-stream (then rerun prepare for the target part, frame kept: see the README)",
]


def _tensors(items: Any) -> list[dict[str, Any]]:
    out = []
    for v in items:
        t = v.type.tensor_type
        dims = [d.dim_param or d.dim_value for d in t.shape.dim]
        out.append({"name": v.name, "dtype": onnx.helper.tensor_dtype_to_np_dtype(t.elem_type).name, "shape": dims})
    return out


def _write(graph: Graph, folder: Path) -> dict[str, Any]:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{graph.name}.onnx"
    path.write_bytes(graph.model)
    model = onnx.load(path)
    onnx.checker.check_model(model, full_check=True)
    return {"file": path.name, "opset": max(o.version for o in model.opset_import if o.domain in ("", "ai.onnx")),
            "inputs": _tensors(model.graph.input), "outputs": _tensors(model.graph.output)}


def engine_graphs(engine: Engine, weights: str = "") -> dict[str, Graph]:
    """The four graphs of one weight set of ``engine`` (the bundle's own by default)."""
    ws = engine.weights(weights)
    example = Example.of(engine, ws)
    graphs = [style_graph(engine, ws, example), begin_graph(ws, example), step_graph(engine, ws, example)]
    if not weights:
        graphs += [output_graph(engine, example), prepare_graph(engine)]
    return {g.name: g for g in graphs}


def export_onnx(bundle: Bundle, out: Path) -> dict[str, Any]:
    """Write the bundle's graphs and sidecar into ``out``; returns the sidecar. A bundle whose styles run at a
    strength other than 1 is refused: the style graph gives contexts as encoded, and the engine samples would
    run them so."""
    if bundle.inference.style_strength != 1.0:
        raise ValueError(f"the bundle runs its styles at strength {bundle.inference.style_strength:g}; the exported "
                         "style graph gives them as encoded: package a copy with --style-strength 1 to export")
    engine = Engine(bundle, compiled=False, overrides=Overrides(int8_lstm=False))  # the float32 network the graphs hold
    out.mkdir(parents=True, exist_ok=True)
    graphs = {name: _write(g, out) for name, g in engine_graphs(engine).items()}
    adapters = {}
    for name in sorted(bundle.adapters):
        adapters[name] = {g: {**info, "file": f"adapters/{name}/{info['file']}"}
                          for g, info in ((n, _write(gr, out / "adapters" / name))
                                          for n, gr in engine_graphs(engine, name).items())}
    sampler = bundle.sampler
    c = bundle.config
    sidecar = {
        "format": FORMAT, "model": bundle.meta.name, "version": bundle.version, "license": bundle.meta.license,
        "opset": OPSET, "fps": c.fps, "graphs": graphs, "adapters": adapters,
        "skeleton": bundle.skeleton.to_dict(),
        "sampler": {"context": c.context, "max_transition": c.max_transition, "max_frames": engine.max_frames,
                    "width": c.width, "rnn": c.rnn, "phases": c.phases, "noise_std": c.noise_std,
                    "style_frames_min": c.style_frames_min, "style_frames_max": c.style_frames_max,
                    "target_velocity_flag": c.target_velocity_flag},
        "state_layout": STATE_LAYOUT,
        "output_memory": list(engine.output_fn.fn.keys),
        "normalisation": {
            "style_clip": "local rotations and roots of the clip at the model's fps, on its rig; the style graph "
                          "computes its features (each frame in its own canonical frame) and normalises them with "
                          "style_mean and style_std itself",
            "style_mean": [round(float(x), 6) for x in sampler.style_mean],
            "style_std": [round(float(x), 6) for x in sampler.style_std],
            "canonical_frame": "a transition's frame: the last context frame's facing turned to +Z and its root "
                               "over the origin on the ground; states are in it, the output graph returns world space",
        },
        "output_settings": engine.output.to_dict(),
        "int8_lstm": "the graphs hold the float32 LSTM; the bundle's int8_lstm setting applies to the torch backend",
        "loop": LOOP,
    }
    (out / SIDECAR).write_text(json.dumps(sidecar, indent=1))
    return sidecar
