// IRsmtGraph on Unreal's NNE (UE 5.4+, the NNERuntimeORTCpu runtime of the NNERuntimeORT plugin): one exported RSMT
// graph, imported as a UNNEModelData asset from its .onnx file, run by a CPU model instance.
#pragma once

#include "CoreMinimal.h"
#include "NNE.h"
#include "NNEModelData.h"
#include "NNERuntimeCPU.h"
#include "RsmtOnnxStateLoop.h"

class FRsmtNneGraph final : public rsmt::IRsmtGraph {
public:
    // False (and Valid() false) when the runtime is missing or cannot create the model.
    explicit FRsmtNneGraph(UNNEModelData* ModelData);
    bool Valid() const { return Instance.IsValid(); }

    const std::vector<std::string>& input_names() const override { return InputNames; }
    bool run(const rsmt::Tensors& inputs, rsmt::Tensors& outputs) override;

private:
    TSharedPtr<UE::NNE::IModelInstanceCPU> Instance;
    std::vector<std::string> InputNames, OutputNames;
    std::vector<rsmt::Tensor::Type> OutputTypes;
};
