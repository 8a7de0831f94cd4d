#include "RsmtPoseCapture.h"

#include <algorithm>
#include <cmath>

#include "RsmtConvert.h"
#include "RsmtJson.h"

namespace rsmt {

Quat Inverse(const Quat& q) {
    const double n = q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w;
    if (!(n > 0.0)) return Quat();
    return Quat{-q.x / n, -q.y / n, -q.z / n, q.w / n};
}

Pose FromUnrealLocal(const std::vector<Quat>& localRotations, const Vec3& rootLocation, double cmPerUnit) {
    Pose pose;
    pose.root = UnrealToModelPosition(rootLocation, cmPerUnit);
    pose.rotations.reserve(localRotations.size());
    for (const Quat& q : localRotations) pose.rotations.push_back(UnrealToModelRotation(Normalize(q)));
    return pose;
}

std::vector<Quat> WorldRotations(const std::vector<Quat>& localRotations, const std::vector<int>& parents) {
    std::vector<Quat> world(localRotations.size());
    if (parents.size() < localRotations.size()) return {};
    for (std::size_t j = 0; j < world.size(); ++j) {
        const int p = parents[j];
        if (p >= static_cast<int>(j)) return {};
        world[j] = p < 0 ? localRotations[j] : Multiply(world[static_cast<std::size_t>(p)], localRotations[j]);
    }
    return world;
}

std::vector<Quat> RetargetOffsets(const std::vector<Quat>& rigReferenceWorld, const std::vector<Quat>& modelReferenceWorld) {
    std::vector<Quat> offsets;
    const std::size_t n = std::min(rigReferenceWorld.size(), modelReferenceWorld.size());
    offsets.reserve(n);
    for (std::size_t j = 0; j < n; ++j) {
        const Quat modelInUnreal = Normalize(ModelToUnrealRotation(modelReferenceWorld[j]));
        offsets.push_back(Normalize(Multiply(Inverse(Normalize(rigReferenceWorld[j])), modelInUnreal)));
    }
    return offsets;
}

Pose FromUnrealWorld(const std::vector<Quat>& rigWorld, const Vec3& rootLocation, const std::vector<int>& parents,
                     const std::vector<Quat>& offsets, double cmPerUnit, double rootScale) {
    const std::size_t n = std::min({rigWorld.size(), parents.size(), offsets.size()});
    std::vector<Quat> world(n);
    for (std::size_t j = 0; j < n; ++j) world[j] = Normalize(Multiply(Normalize(rigWorld[j]), offsets[j]));
    Pose pose;
    pose.root = UnrealToModelPosition(Vec3{rootLocation.x * rootScale, rootLocation.y * rootScale, rootLocation.z * rootScale},
                                      cmPerUnit);
    pose.rotations.reserve(n);
    for (std::size_t j = 0; j < n; ++j) {
        const int p = parents[j];
        const Quat local = p < 0 || p >= static_cast<int>(n) ? world[j] : Multiply(Inverse(world[static_cast<std::size_t>(p)]), world[j]);
        pose.rotations.push_back(UnrealToModelRotation(Normalize(local)));
    }
    return pose;
}

namespace {

bool ReadVec(const JsonValue* v, Vec3& out) {
    if (v == nullptr || !v->IsArray() || v->array.size() != 3) return false;
    for (const JsonValue& x : v->array) {
        if (!x.IsNumber()) return false;
    }
    out = Vec3{v->array[0].number, v->array[1].number, v->array[2].number};
    return true;
}

bool Fail(std::string* error, const std::string& why) {
    if (error != nullptr) *error = why;
    return false;
}

}  // namespace

bool ParseReferencePose(const std::string& text, ReferencePose& out, std::string* error) {
    JsonValue doc;
    if (!ParseJson(text, doc, error)) return false;
    const JsonValue* joints = doc.Find("joints");
    if (joints == nullptr || !joints->IsArray() || joints->array.empty()) return Fail(error, "no joints");
    out = ReferencePose();
    out.units = doc.StringOr("units", "cm");
    for (const JsonValue& j : joints->array) {
        Vec3 offset;
        const JsonValue* q = j.Find("t_pose_rotation");
        if (!ReadVec(j.Find("offset"), offset) || q == nullptr || !q->IsArray() || q->array.size() != 4)
            return Fail(error, "joint " + std::to_string(out.names.size()) + " needs offset [3] and t_pose_rotation [4]");
        out.names.push_back(j.StringOr("name", ""));
        out.parents.push_back(static_cast<int>(j.NumberOr("parent", -1.0)));
        out.offsets.push_back(offset);
        out.localRotations.push_back(Normalize(Quat{q->array[0].number, q->array[1].number, q->array[2].number, q->array[3].number}));
    }
    if (!ReadVec(doc.Find("t_pose_root_position"), out.root)) return Fail(error, "no t_pose_root_position");
    out.worldRotations = WorldRotations(out.localRotations, out.parents);
    if (out.worldRotations.empty()) return Fail(error, "parents must come before their children");
    return true;
}

PoseHistory::PoseHistory(double fps, int capacity)
    : fps_(fps > 0.0 ? fps : 30.0), ring_(static_cast<std::size_t>(std::max(capacity, 2))) {}

void PoseHistory::Clear() {
    next_ = count_ = 0;
    hasPrev_ = false;
}

void PoseHistory::Push(const Pose& pose) {
    ring_[static_cast<std::size_t>(next_)] = pose;
    next_ = (next_ + 1) % static_cast<int>(ring_.size());
    if (count_ < static_cast<int>(ring_.size())) ++count_;
}

void PoseHistory::Add(double time, const Pose& pose) {
    const double step = 1.0 / fps_;
    if (!hasPrev_) {
        Push(pose);
        nextSample_ = time + step;
        hasPrev_ = true;
        prevTime_ = time;
        prev_ = pose;
        return;
    }
    if (time > prevTime_) {
        const double behind = (time - nextSample_) * fps_;
        const double cap = static_cast<double>(ring_.size());
        if (behind > cap) nextSample_ += std::floor(behind - cap + 1.0) * step;  // after a stall: a buffer's worth at most
        while (nextSample_ <= time + 1e-9) {
            const double a = std::max(0.0, std::min(1.0, (nextSample_ - prevTime_) / (time - prevTime_)));
            Pose s;
            s.root = Lerp(prev_.root, pose.root, a);
            s.rotations.resize(pose.rotations.size());
            for (std::size_t j = 0; j < s.rotations.size(); ++j)
                s.rotations[j] = j < prev_.rotations.size() ? Nlerp(prev_.rotations[j], pose.rotations[j], a) : pose.rotations[j];
            Push(s);
            nextSample_ += step;
        }
        prevTime_ = time;
    }
    prev_ = pose;
}

std::vector<Pose> PoseHistory::Last(int frames) const {
    const int n = std::min(frames, count_);
    const int size = static_cast<int>(ring_.size());
    std::vector<Pose> out;
    out.reserve(static_cast<std::size_t>(std::max(n, 0)));
    for (int i = n; i > 0; --i) out.push_back(ring_[static_cast<std::size_t>((next_ - i + size) % size)]);
    return out;
}

std::string PoseHistory::MotionJson(int frames) const {
    std::vector<Vec3> roots;
    std::vector<std::vector<Quat>> rotations;
    for (const Pose& p : Last(frames)) {
        roots.push_back(p.root);
        rotations.push_back(p.rotations);
    }
    std::string s = PoseMotionJson(roots, rotations);
    s.pop_back();  // the closing brace: add the frame rate
    return s + ",\"fps\":" + JsonNumber(fps_) + "}";
}

}  // namespace rsmt
