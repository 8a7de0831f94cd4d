// Test-only: the Unreal sample's state loop (RsmtOnnxStateLoop.cpp) driving the exported graphs, each run answered
// over stdin/stdout by onnxruntime in the Python test (tests/clients/test_engine_samples.py). Messages are binary:
// a tensor is [u32 name length][name][u8 type: 0 float32, 1 int64, 2 bool][u32 rank][i64 dims][u64 bytes][bytes],
// a set is [u32 count][tensors]. In: the four graphs' input names and the memory keys, then the request set. Out:
// [u8 1][u32 graph][set] for a run (the answer comes back as a set), [u8 2][set] for a frame, [u8 3] at the end.
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "RsmtOnnxStateLoop.h"

namespace {

bool read_bytes(void* out, size_t n) { return n == 0 || std::fread(out, 1, n, stdin) == n; }
void write_bytes(const void* data, size_t n) { if (n) std::fwrite(data, 1, n, stdout); }

template <typename T>
bool read_value(T& v) { return read_bytes(&v, sizeof v); }
template <typename T>
void write_value(const T& v) { write_bytes(&v, sizeof v); }

bool read_string(std::string& s) {
    uint32_t n = 0;
    if (!read_value(n)) return false;
    s.resize(n);
    return read_bytes(&s[0], n);
}

bool read_names(std::vector<std::string>& names) {
    uint32_t n = 0;
    if (!read_value(n)) return false;
    names.resize(n);
    for (std::string& s : names)
        if (!read_string(s)) return false;
    return true;
}

bool read_set(rsmt::Tensors& set) {
    uint32_t count = 0;
    if (!read_value(count)) return false;
    set.clear();
    for (uint32_t i = 0; i < count; ++i) {
        std::string name;
        uint8_t type = 0;
        uint32_t rank = 0;
        uint64_t size = 0;
        if (!read_string(name) || !read_value(type) || !read_value(rank)) return false;
        rsmt::Tensor& t = set[name];
        t.type = static_cast<rsmt::Tensor::Type>(type);
        t.shape.resize(rank);
        for (int64_t& d : t.shape)
            if (!read_value(d)) return false;
        if (!read_value(size)) return false;
        t.bytes.resize(size);
        if (!read_bytes(t.bytes.data(), size)) return false;
    }
    return true;
}

void write_set(const rsmt::Tensors& set) {
    write_value(static_cast<uint32_t>(set.size()));
    for (const auto& kv : set) {
        write_value(static_cast<uint32_t>(kv.first.size()));
        write_bytes(kv.first.data(), kv.first.size());
        write_value(static_cast<uint8_t>(kv.second.type));
        write_value(static_cast<uint32_t>(kv.second.shape.size()));
        for (int64_t d : kv.second.shape) write_value(d);
        write_value(static_cast<uint64_t>(kv.second.bytes.size()));
        write_bytes(kv.second.bytes.data(), kv.second.bytes.size());
    }
}

class PipeGraph final : public rsmt::IRsmtGraph {
public:
    PipeGraph(uint32_t index, std::vector<std::string> names) : index_(index), names_(std::move(names)) {}
    const std::vector<std::string>& input_names() const override { return names_; }
    bool run(const rsmt::Tensors& inputs, rsmt::Tensors& outputs) override {
        write_value(static_cast<uint8_t>(1));
        write_value(index_);
        write_set(inputs);
        std::fflush(stdout);
        return read_set(outputs);
    }

private:
    uint32_t index_;
    std::vector<std::string> names_;
};

int64_t scalar(const rsmt::Tensor& t) {
    int64_t v = 0;
    std::memcpy(&v, t.bytes.data(), sizeof v);
    return v;
}

}  // namespace

int main() {
    std::vector<std::string> names[4], memory;
    for (auto& n : names)
        if (!read_names(n)) return 2;
    if (!read_names(memory)) return 2;
    rsmt::Tensors request, style;
    if (!read_set(request)) return 2;
    for (const auto& kv : request)
        if (kv.first.rfind("style.", 0) == 0) style[kv.first.substr(6)] = kv.second;
    PipeGraph prepare(0, names[0]), begin(1, names[1]), step(2, names[2]), output(3, names[3]);
    rsmt::StateLoop loop(prepare, begin, step, output, memory);
    const int64_t frames = scalar(request["frames"]), retarget_at = scalar(request["retarget_at"]);
    if (!loop.start(request["context_rotations"], request["context_roots"], request["target_rotations"],
                    request["target_roots"], style, frames, request["noise"]))
        return 3;
    std::vector<float> rotations, root;
    while (!loop.done()) {
        if (loop.seq() == retarget_at && !loop.retarget(request["retarget_rotations"], request["retarget_roots"], 0))
            return 4;
        if (!loop.next(rotations, root)) return 5;
        write_value(static_cast<uint8_t>(2));
        write_set({{"rotations", rsmt::Tensor::floats({static_cast<int64_t>(rotations.size())}, rotations)},
                   {"root", rsmt::Tensor::floats({3}, root)}});
    }
    write_value(static_cast<uint8_t>(3));
    std::fflush(stdout);
    return 0;
}
