// The state loop of the exported RSMT graphs (rsmt export onnx), independent of Unreal and of any inference runtime:
// which graph runs when, which outputs feed which inputs, what a character keeps between frames. The runtime behind
// IRsmtGraph runs one graph (RsmtNneGraph.h: Unreal's NNE). Names and shapes are the sidecar's (rsmt-onnx.json).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace rsmt {

// A tensor by shape and element type; the bytes are the values, little-endian, as ONNX lays them out.
struct Tensor {
    enum class Type { Float32, Int64, Bool };
    Type type = Type::Float32;
    std::vector<int64_t> shape;
    std::vector<uint8_t> bytes;

    static Tensor floats(std::vector<int64_t> shape, const std::vector<float>& values);
    static Tensor ints(std::vector<int64_t> shape, const std::vector<int64_t>& values);
    static Tensor flags(std::vector<int64_t> shape, const std::vector<bool>& values);
    std::vector<float> as_floats() const;
};

using Tensors = std::map<std::string, Tensor>;

// One loaded graph: its input names (inputs a graph never reads are dropped by the exporter) and a run. A failed run
// returns false (no exceptions: Unreal builds without them).
class IRsmtGraph {
public:
    virtual ~IRsmtGraph() = default;
    virtual const std::vector<std::string>& input_names() const = 0;
    virtual bool run(const Tensors& inputs, Tensors& outputs) = 0;
};

// One character's transition: prepare and begin once, then step and output every frame.
class StateLoop {
public:
    // memory_keys: the sidecar's "output_memory", in order.
    StateLoop(IRsmtGraph& prepare, IRsmtGraph& begin, IRsmtGraph& step, IRsmtGraph& output,
              std::vector<std::string> memory_keys);

    // context_rotations [K, J, 4] local x, y, z, w, context_roots [K, 3], target_rotations [1, J, 4], target_roots
    // [1, 3] on the model's rig (model axes, cm); style: the style graph's outputs; noise [1, 2 * width].
    bool start(const Tensor& context_rotations, const Tensor& context_roots, const Tensor& target_rotations,
               const Tensor& target_roots, const Tensors& style, int64_t frames, const Tensor& noise);
    // A new target mid-stream from the next frame (frames: those left from then; 0 keeps the length).
    bool retarget(const Tensor& target_rotations, const Tensor& target_roots, int64_t frames);
    // One frame in world space: rotations [J * 4] local x, y, z, w and root [3] (model axes, cm).
    bool next(std::vector<float>& rotations, std::vector<float>& root);

    int64_t frames_total() const { return frames_total_; }
    int64_t seq() const { return seq_; }
    bool done() const { return seq_ >= frames_total_; }

private:
    bool prepare(const Tensor& target_rotations, const Tensor& target_roots, Tensors& prepared);
    bool begin(const Tensors& prepared, int64_t frames, Tensors& began);
    static bool feed(const IRsmtGraph& graph, const Tensors& values, Tensors& inputs);

    IRsmtGraph &prepare_, &begin_, &step_, &output_;
    std::vector<std::string> memory_keys_;
    Tensors state_, memory_, style_;
    Tensor context_rotations_, context_roots_, noise_, yaw_, origin_;
    bool late_ = false;
    int64_t frames_total_ = 0, seq_ = 0;
};

}  // namespace rsmt
