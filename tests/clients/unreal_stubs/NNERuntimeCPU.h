// STUB OF UNREAL'S NNE API (module NNE), test-only: the CPU runtime, model and model instance interfaces the
// in-engine sample uses, with Unreal's names and signatures (UE 5.4+).
#pragma once

#include "NNE.h"
#include "NNEModelData.h"

namespace UE::NNE {

class IModelInstanceCPU {
public:
    enum class ESetInputTensorShapesStatus : uint8 { Ok, Fail };
    enum class ERunSyncStatus : uint8 { Ok, Fail };
    virtual ~IModelInstanceCPU() = default;
    virtual TConstArrayView<FTensorDesc> GetInputTensorDescs() const = 0;
    virtual TConstArrayView<FTensorDesc> GetOutputTensorDescs() const = 0;
    virtual TConstArrayView<FTensorShape> GetOutputTensorShapes() const = 0;
    virtual ESetInputTensorShapesStatus SetInputTensorShapes(TConstArrayView<FTensorShape> InInputShapes) = 0;
    virtual ERunSyncStatus RunSync(TConstArrayView<FTensorBindingCPU> InInputBindings,
                                   TConstArrayView<FTensorBindingCPU> InOutputBindings) = 0;
};

class IModelCPU {
public:
    virtual ~IModelCPU() = default;
    virtual TSharedPtr<IModelInstanceCPU> CreateModelInstanceCPU() = 0;
};

}  // namespace UE::NNE

class INNERuntimeCPU {
public:
    virtual ~INNERuntimeCPU() = default;
    virtual TSharedPtr<UE::NNE::IModelCPU> CreateModelCPU(UNNEModelData* ModelData) = 0;
};
