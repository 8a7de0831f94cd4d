#include "RsmtNneGraph.h"

namespace {

std::string Narrow(const FString& Name) { return std::string(TCHAR_TO_UTF8(*Name)); }

rsmt::Tensor::Type TypeOf(ENNETensorDataType Type) {
    switch (Type) {
        case ENNETensorDataType::Int64: return rsmt::Tensor::Type::Int64;
        case ENNETensorDataType::Boolean: return rsmt::Tensor::Type::Bool;
        default: return rsmt::Tensor::Type::Float32;
    }
}

size_t ElementBytes(rsmt::Tensor::Type Type) {
    return Type == rsmt::Tensor::Type::Int64 ? 8 : Type == rsmt::Tensor::Type::Bool ? 1 : 4;
}

}  // namespace

FRsmtNneGraph::FRsmtNneGraph(UNNEModelData* ModelData) {
    TWeakInterfacePtr<INNERuntimeCPU> Runtime = UE::NNE::GetRuntime<INNERuntimeCPU>(TEXT("NNERuntimeORTCpu"));
    if (!Runtime.IsValid()) return;
    TSharedPtr<UE::NNE::IModelCPU> Model = Runtime->CreateModelCPU(ModelData);
    if (!Model.IsValid()) return;
    Instance = Model->CreateModelInstanceCPU();
    if (!Instance.IsValid()) return;
    for (const UE::NNE::FTensorDesc& Desc : Instance->GetInputTensorDescs()) InputNames.push_back(Narrow(Desc.GetName()));
    for (const UE::NNE::FTensorDesc& Desc : Instance->GetOutputTensorDescs()) {
        OutputNames.push_back(Narrow(Desc.GetName()));
        OutputTypes.push_back(TypeOf(Desc.GetDataType()));
    }
}

bool FRsmtNneGraph::run(const rsmt::Tensors& inputs, rsmt::Tensors& outputs) {
    if (!Instance.IsValid()) return false;
    TArray<UE::NNE::FTensorShape> Shapes;
    TArray<UE::NNE::FTensorBindingCPU> In;
    for (const std::string& Name : InputNames) {
        const rsmt::Tensor& T = inputs.at(Name);
        TArray<uint32> Dims;
        for (int64_t D : T.shape) Dims.Add(static_cast<uint32>(D));
        Shapes.Add(UE::NNE::FTensorShape::Make(Dims));
        In.Add({const_cast<uint8_t*>(T.bytes.data()), static_cast<uint64>(T.bytes.size())});
    }
    // The batch and the style code's length are dynamic: the shapes are set before every run.
    if (Instance->SetInputTensorShapes(Shapes) != UE::NNE::IModelInstanceCPU::ESetInputTensorShapesStatus::Ok) return false;
    TConstArrayView<UE::NNE::FTensorShape> OutShapes = Instance->GetOutputTensorShapes();
    if (static_cast<size_t>(OutShapes.Num()) != OutputNames.size()) return false;
    TArray<UE::NNE::FTensorBindingCPU> Out;
    outputs.clear();
    for (size_t I = 0; I < OutputNames.size(); ++I) {
        rsmt::Tensor& T = outputs[OutputNames[I]];
        T.type = OutputTypes[I];
        for (uint32 D : OutShapes[static_cast<int32>(I)].GetData()) T.shape.push_back(static_cast<int64_t>(D));
        T.bytes.resize(static_cast<size_t>(OutShapes[static_cast<int32>(I)].Volume()) * ElementBytes(T.type));
    }
    for (const std::string& Name : OutputNames) {  // bound after every output exists: the map no longer moves them
        rsmt::Tensor& T = outputs[Name];
        Out.Add({T.bytes.data(), static_cast<uint64>(T.bytes.size())});
    }
    return Instance->RunSync(In, Out) == UE::NNE::IModelInstanceCPU::ERunSyncStatus::Ok;
}
