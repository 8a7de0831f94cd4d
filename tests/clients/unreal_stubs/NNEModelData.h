// STUB OF UNREAL'S NNE API (module NNE), test-only: UNNEModelData, the asset an imported .onnx file becomes.
#pragma once

class UNNEModelData {};
