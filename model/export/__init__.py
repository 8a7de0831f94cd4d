"""Exporters: a bundle's networks as graphs other runtimes load (ONNX for onnxruntime, Unity's inference engine, Unreal's NNE)."""
