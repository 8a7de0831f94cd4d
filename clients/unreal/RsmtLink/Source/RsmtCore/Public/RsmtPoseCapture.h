// Poses read from a character (Unreal axes) turned into the model's poses, for `start`/`retarget` contexts and
// targets sent as pose arrays (docs/api-contract.md "Motion payloads": root_positions + local rotations).
//
// Unreal -> model is the inverse of RsmtConvert's model -> Unreal map (an axis swap, its own inverse):
//   position (x, y, z)_unreal / s -> (x, z, y)_model,   rotation (x, y, z, w)_unreal -> (-x, -z, -y, w)_model
// (Z up, left-handed, cm in Unreal; component space of a skeletal mesh facing +Y).
//
// Two ways in:
// - FromUnrealLocal: the bones have the model's joint frames (the shipped rig from clients/rig imported, or the
//   RSMT skeleton driven by an IK Retargeter from your character): each local rotation converts on its own. Exact.
// - FromUnrealWorld + RetargetOffsets: any skeleton whose reference pose is the same body pose as the model's
//   reference (ReferencePose, the T-pose of clients/rig). Per joint C_j = inverse(rigRefWorld_j) * modelRefWorld_j
//   (both in Unreal axes); at run time modelWorld_j = rigWorld_j * C_j, then locals from the model's parents.
//   Component-space rotations fold in bones between mapped joints (spine_01..05 onto Spine/Chest).
//
// PoseHistory keeps the last poses resampled to the model's fps (interpolated between ticks).
#pragma once

#include <string>
#include <vector>

#include "RsmtCoreApi.h"
#include "RsmtMath.h"
#include "RsmtProtocol.h"

namespace rsmt {

RSMTCORE_API Quat Inverse(const Quat& q);

// A pose of a skeleton with the model's joint frames: bone-space rotations and the root bone's location (Unreal).
RSMTCORE_API Pose FromUnrealLocal(const std::vector<Quat>& localRotations, const Vec3& rootLocation, double cmPerUnit = 1.0);

// World (component-space) rotations from local ones; parents come before children, the root's parent is -1.
// Empty when a parent index is out of order.
RSMTCORE_API std::vector<Quat> WorldRotations(const std::vector<Quat>& localRotations, const std::vector<int>& parents);

// C_j = inverse(rigReferenceWorld_j) * modelReferenceWorld_j (rig: Unreal axes; model: model axes, converted here).
RSMTCORE_API std::vector<Quat> RetargetOffsets(const std::vector<Quat>& rigReferenceWorld,
                                               const std::vector<Quat>& modelReferenceWorld);

// A pose of any skeleton: the mapped bones' component-space rotations and the root bone's component-space location.
// rootScale multiplies the location (model hip height / your hip height for a character of another size).
RSMTCORE_API Pose FromUnrealWorld(const std::vector<Quat>& rigWorld, const Vec3& rootLocation, const std::vector<int>& parents,
                                  const std::vector<Quat>& offsets, double cmPerUnit = 1.0, double rootScale = 1.0);

// The model's skeleton with its T-pose, from `rsmt rig export`'s STEM.tpose.json (model axes and units).
struct ReferencePose {
    std::vector<std::string> names;
    std::vector<int> parents;
    std::vector<Vec3> offsets;
    std::vector<Quat> localRotations;
    std::vector<Quat> worldRotations;
    Vec3 root;
    std::string units = "cm";
};

RSMTCORE_API bool ParseReferencePose(const std::string& text, ReferencePose& out, std::string* error = nullptr);

// The last poses (model axes), resampled to fps from whatever rate they are added at.
class RSMTCORE_API PoseHistory {
public:
    PoseHistory(double fps, int capacity);
    void Clear();
    // A pose at `time` seconds (a clock that only moves forward).
    void Add(double time, const Pose& pose);
    int Count() const { return count_; }
    double Fps() const { return fps_; }
    // The newest `frames` samples, oldest first.
    std::vector<Pose> Last(int frames) const;
    // The newest `frames` samples as a Motion payload (pose arrays with "fps").
    std::string MotionJson(int frames) const;

private:
    void Push(const Pose& pose);
    double fps_;
    std::vector<Pose> ring_;
    int next_ = 0;
    int count_ = 0;
    bool hasPrev_ = false;
    double prevTime_ = 0.0;
    double nextSample_ = 0.0;
    Pose prev_;
};

}  // namespace rsmt
