// STUB OF UNREAL'S NNE API (module NNE), test-only: the tensor types and runtime lookup the in-engine sample uses,
// with Unreal's names and signatures (UE 5.4+), so that g++ can type-check the sample. Nothing here runs a network.
#pragma once

#include "CoreMinimal.h"

enum class ENNETensorDataType : uint8 { None, Char, Boolean, Half, Float, Double, Int8, Int16, Int32, Int64, UInt8 };

namespace UE::NNE {

class FTensorDesc {
public:
    const FString& GetName() const { return Name; }
    ENNETensorDataType GetDataType() const { return DataType; }

private:
    FString Name;
    ENNETensorDataType DataType = ENNETensorDataType::Float;
};

class FTensorShape {
public:
    static FTensorShape Make(TConstArrayView<uint32> Data) { (void)Data; return FTensorShape(); }
    TConstArrayView<uint32> GetData() const { return TConstArrayView<uint32>(); }
    uint64 Volume() const { return 0; }
};

struct FTensorBindingCPU {
    void* Data;
    uint64 SizeInBytes;
};

template <typename T>
TWeakInterfacePtr<T> GetRuntime(const FString& Name) { (void)Name; return TWeakInterfacePtr<T>(); }

}  // namespace UE::NNE
