"""The ``rsmt export`` command: a bundle's networks as graphs for other runtimes (``rsmt export onnx``)."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("export", help="export a bundle's networks for other runtimes (ONNX)",
                              description="Export a bundle's networks as graphs other runtimes load.")
    sub = p.add_subparsers(dest="format", required=True, metavar="FORMAT")
    onnx = sub.add_parser(
        "onnx", help="ONNX graphs (opset 15) and a JSON sidecar, for onnxruntime, Unity's inference engine, Unreal's NNE",
        description="Write style.onnx, begin.onnx, step.onnx, output.onnx and rsmt-onnx.json (the skeleton, every "
                    "graph's inputs and outputs, the state layout, the normalisation, the output settings and the "
                    "loop) into --out. Each graph passes onnx.checker; the batch is dynamic.")
    onnx.add_argument("--model", type=Path, help="bundle folder (default: the bundled default model)")
    onnx.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder to write the graphs into")
    onnx.add_argument("--parity", action="store_true",
                      help="also run 50 transitions through onnxruntime and the torch engine (float32) and print the "
                           "largest joint distance between them")
    onnx.set_defaults(func=_onnx)


def _onnx(args: argparse.Namespace) -> int:
    from model.export.onnx_bundle import SIDECAR, export_onnx
    from model.inference.bundle import DEFAULT_BUNDLE, Bundle

    bundle = Bundle.load(args.model or DEFAULT_BUNDLE)
    sidecar = export_onnx(bundle, args.out)
    for graph in sidecar["graphs"].values():
        size = (args.out / graph["file"]).stat().st_size
        print(f"{graph['file']}: opset {graph['opset']}, {len(graph['inputs'])} inputs, "
              f"{len(graph['outputs'])} outputs, {size / 2**20:.1f} MiB")
    print(f"{SIDECAR}: {sidecar['model']} {sidecar['version']}, {len(sidecar['skeleton']['joints'])} joints")
    if args.parity:
        from model.export.onnx_backend import use_onnxruntime
        from model.export.onnx_parity import largest_joint_error_cm
        from model.inference.engine import Engine
        from model.inference.overrides import Overrides

        error = largest_joint_error_cm(Engine(bundle, overrides=Overrides(int8_lstm=False)),
                                       use_onnxruntime(Engine(bundle, overrides=Overrides(int8_lstm=False))))
        print(f"parity: onnxruntime and the torch engine (float32) within {error:.2e} cm on every joint of 50 "
              f"40-frame transitions")
    return 0
