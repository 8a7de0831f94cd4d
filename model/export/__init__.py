"""ONNX: a bundle's networks as graphs other runtimes load (onnxruntime, Unity's inference engine, Unreal's NNE),
and the engine's onnxruntime backend that runs them."""
