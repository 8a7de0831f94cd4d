// STUB OF UNREAL ENGINE CORE TYPES, test-only: the few members of TArray, TConstArrayView, FString, TSharedPtr and
// TWeakInterfacePtr that the in-engine sample (clients/unreal/RsmtLink/Samples/InEngineInference) uses, with
// Unreal's names and signatures, so that g++ can type-check it without the engine. Not Unreal's implementation.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

using uint8 = std::uint8_t;
using uint32 = std::uint32_t;
using int32 = std::int32_t;
using uint64 = std::uint64_t;
using TCHAR = char;
#define TEXT(x) x
#define TCHAR_TO_UTF8(x) (x)

class FString {
public:
    FString() = default;
    FString(const TCHAR* Text) : Value(Text) {}
    const TCHAR* operator*() const { return Value.c_str(); }

private:
    std::string Value;
};

template <typename T>
class TConstArrayView {
public:
    TConstArrayView() = default;
    TConstArrayView(const T* InData, int32 InNum) : Data(InData), Count(InNum) {}
    template <typename C>
    TConstArrayView(const C& Container) : Data(Container.GetData()), Count(Container.Num()) {}
    int32 Num() const { return Count; }
    const T& operator[](int32 Index) const { return Data[Index]; }
    const T* begin() const { return Data; }
    const T* end() const { return Data + Count; }

private:
    const T* Data = nullptr;
    int32 Count = 0;
};

template <typename T>
class TArray {
public:
    int32 Add(const T& Item) { Items.push_back(Item); return static_cast<int32>(Items.size()) - 1; }
    int32 Num() const { return static_cast<int32>(Items.size()); }
    const T* GetData() const { return Items.data(); }
    T& operator[](int32 Index) { return Items[static_cast<size_t>(Index)]; }

private:
    std::vector<T> Items;
};

template <typename T>
class TSharedPtr {
public:
    TSharedPtr() = default;
    bool IsValid() const { return Ptr != nullptr; }
    T* operator->() const { return Ptr.get(); }

private:
    std::shared_ptr<T> Ptr;
};

template <typename T>
class TWeakInterfacePtr {
public:
    bool IsValid() const { return Ptr != nullptr; }
    T* operator->() const { return Ptr; }

private:
    T* Ptr = nullptr;
};
