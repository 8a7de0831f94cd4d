// What the model reads of a motion, cut from a whole take before it is sent (the Python client's
// rsmt_client.motion_cuts and the Unity core's RsmtMotionCutter, the same numbers): a context to its last
// context_frames, a target to its last two frames (the pose and its velocity), a style clip longer than
// style_clip_frames.max to its middle, said once through the notice callback. BVH text is cut as text: the
// numbers go out exactly as written. No engine types; no exceptions.
#pragma once

#include <functional>
#include <string>

#include "RsmtCoreApi.h"

namespace rsmt {

struct ModelInfo;

// The frames a model reads (GET /v1/model, or hello's model). valid is false for a description without them
// (an older server): motions then go as they are.
struct MotionLimits {
    bool valid = false;
    double fps = 30.0;
    int contextFrames = 0;
    int styleMaxFrames = 0;
};

RSMTCORE_API MotionLimits LimitsOf(const ModelInfo& model);

// BVH text: its frame count and fps (false, with the reason, when it is not BVH).
RSMTCORE_API bool BvhMeasure(const std::string& bvh, int& frames, double& fps, std::string* error);
// Frames [start, start + count) as BVH text: the same hierarchy, frame time and numbers.
RSMTCORE_API bool BvhWindow(const std::string& bvh, int start, int count, std::string& out, std::string* error);

// How many frames `frames` at `sourceFps` become at `fps`, as the server resamples (from frame 0).
RSMTCORE_API int ResampledFrames(int frames, double sourceFps, double fps);
// The fewest source frames that resample to at least `frames`; the most that resample to at most `frames`.
RSMTCORE_API int FramesFor(int frames, double sourceFps, double fps);
RSMTCORE_API int FramesWithin(int frames, double sourceFps, double fps);

// Cuts BVH motions to what one model reads. Text that is not BVH goes as it is (the server names the fault).
class RSMTCORE_API MotionCutter {
public:
    static constexpr int kTargetFrames = 2;
    explicit MotionCutter(const MotionLimits& limits) : limits_(limits) {}

    std::string Context(const std::string& bvh) const;
    std::string Target(const std::string& bvh) const;
    // The first cut style clip calls the notice once (per cutter).
    std::string Style(const std::string& bvh);
    void SetNotice(std::function<void(const std::string&)> notice) { notice_ = std::move(notice); }
    const MotionLimits& Limits() const { return limits_; }

private:
    std::string Tail(const std::string& bvh, int want) const;
    MotionLimits limits_;
    std::function<void(const std::string&)> notice_;
    bool noticed_ = false;
};

}  // namespace rsmt
