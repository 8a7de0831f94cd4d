#include "RsmtOnnxStateLoop.h"

#include <algorithm>
#include <cstring>

namespace rsmt {

namespace {

template <typename T>
std::vector<uint8_t> raw(const std::vector<T>& values) {
    std::vector<uint8_t> out(values.size() * sizeof(T));
    if (!values.empty()) std::memcpy(out.data(), values.data(), out.size());
    return out;
}

bool starts_with(const std::string& s, const char* prefix) { return s.rfind(prefix, 0) == 0; }

const char* const kStepped[] = {"h", "c", "rel", "vel", "rot", "root_xz", "phase", "tta"};
const char* const kHeld[] = {"target_pos", "target_rot", "target_emb", "noise"};
const char* const kPose[] = {"rel", "vel", "rot", "root_xz"};

}  // namespace

Tensor Tensor::floats(std::vector<int64_t> shape, const std::vector<float>& values) {
    return Tensor{Type::Float32, std::move(shape), raw(values)};
}

Tensor Tensor::ints(std::vector<int64_t> shape, const std::vector<int64_t>& values) {
    return Tensor{Type::Int64, std::move(shape), raw(values)};
}

Tensor Tensor::flags(std::vector<int64_t> shape, const std::vector<bool>& values) {
    std::vector<uint8_t> bytes;
    for (bool v : values) bytes.push_back(v ? 1 : 0);
    return Tensor{Type::Bool, std::move(shape), std::move(bytes)};
}

std::vector<float> Tensor::as_floats() const {
    std::vector<float> out(bytes.size() / sizeof(float));
    if (!out.empty()) std::memcpy(out.data(), bytes.data(), out.size() * sizeof(float));
    return out;
}

StateLoop::StateLoop(IRsmtGraph& prepare, IRsmtGraph& begin, IRsmtGraph& step, IRsmtGraph& output,
                     std::vector<std::string> memory_keys)
    : prepare_(prepare), begin_(begin), step_(step), output_(output), memory_keys_(std::move(memory_keys)) {}

bool StateLoop::feed(const IRsmtGraph& graph, const Tensors& values, Tensors& inputs) {
    inputs.clear();
    for (const std::string& name : graph.input_names()) {
        auto it = values.find(name);
        if (it == values.end()) return false;  // a graph input the loop has no value for: not an RSMT export
        inputs[name] = it->second;
    }
    return true;
}

bool StateLoop::prepare(const Tensor& target_rotations, const Tensor& target_roots, Tensors& prepared) {
    Tensors values{{"context_rotations", context_rotations_}, {"context_roots", context_roots_},
                   {"target_rotations", target_rotations}, {"target_roots", target_roots}};
    Tensors inputs;
    return feed(prepare_, values, inputs) && prepare_.run(inputs, prepared);
}

bool StateLoop::begin(const Tensors& prepared, int64_t frames, Tensors& began) {
    Tensors values = style_;
    for (const auto& kv : prepared)
        if (starts_with(kv.first, "context_") || starts_with(kv.first, "target_")) values[kv.first] = kv.second;
    values["frames"] = Tensor::ints({1}, {frames});
    values["noise"] = noise_;
    values["velocity_known"] = Tensor::flags({1}, {false});  // the target frame alone
    Tensors inputs;
    return feed(begin_, values, inputs) && begin_.run(inputs, began);
}

bool StateLoop::start(const Tensor& context_rotations, const Tensor& context_roots, const Tensor& target_rotations,
                      const Tensor& target_roots, const Tensors& style, int64_t frames, const Tensor& noise) {
    context_rotations_ = context_rotations;
    context_roots_ = context_roots;
    style_ = style;
    noise_ = noise;
    Tensors prepared, began;
    if (!prepare(target_rotations, target_roots, prepared) || !begin(prepared, frames, began)) return false;
    yaw_ = prepared["yaw"];
    origin_ = prepared["origin"];
    memory_.clear();
    for (const std::string& key : memory_keys_) memory_[key] = prepared[key];
    state_.clear();
    for (const auto& kv : began) state_[kv.first.substr(0, kv.first.size() - 4)] = kv.second;  // NAME_out
    frames_total_ = frames;
    seq_ = 0;
    late_ = false;
    return true;
}

bool StateLoop::retarget(const Tensor& target_rotations, const Tensor& target_roots, int64_t frames) {
    Tensors prepared, began;
    if (!prepare(target_rotations, target_roots, prepared) ||
        !begin(prepared, std::max<int64_t>(1, frames_total_ - seq_), began))
        return false;
    for (const char* key : {"target_pos", "target_rot", "target_emb"}) state_[key] = began[std::string(key) + "_out"];
    if (frames > 0) {
        state_["tta"] = Tensor::ints({1}, {frames});
        frames_total_ = seq_ + frames;
    }
    late_ = true;  // the retarget facing window of the step's steering
    return true;
}

bool StateLoop::next(std::vector<float>& rotations, std::vector<float>& root) {
    if (done()) return false;
    Tensors values = style_;
    for (const char* key : kStepped) values[key] = state_[key];
    for (const char* key : kHeld) values[key] = state_[key];
    values["late"] = Tensor::flags({1}, {late_});
    Tensors inputs, stepped;
    if (!feed(step_, values, inputs) || !step_.run(inputs, stepped)) return false;
    for (const char* key : kStepped) state_[key] = stepped[std::string(key) + "_out"];
    Tensors out_values = memory_;
    for (const char* key : kPose) out_values[key] = state_[key];
    out_values["yaw"] = yaw_;
    out_values["origin"] = origin_;
    out_values["remaining"] = Tensor::ints({1}, {frames_total_ - seq_ - 1});
    out_values["shift"] = stepped["shift"];
    Tensors frame;
    if (!feed(output_, out_values, inputs) || !output_.run(inputs, frame)) return false;
    for (const std::string& key : memory_keys_) memory_[key] = frame[key + "_out"];
    rotations = frame["rotations"].as_floats();
    root = frame["root_position"].as_floats();
    ++seq_;
    return true;
}

}  // namespace rsmt
