#include "RsmtConvert.h"

namespace rsmt {

double CentimetresPerUnit(const std::string& units) {
    if (units == "cm" || units == "centimeters" || units == "centimetres") return 1.0;
    if (units == "m" || units == "meters" || units == "metres") return 100.0;
    if (units == "mm" || units == "millimeters" || units == "millimetres") return 0.1;
    if (units == "in" || units == "inches") return 2.54;
    return 0.0;
}

bool CheckModelConventions(const ModelInfo& model, std::string* why) {
    std::string problem;
    if (model.upAxis != "y" && model.upAxis != "Y") problem = "up axis is '" + model.upAxis + "', expected y";
    else if (model.handedness != "right") problem = "handedness is '" + model.handedness + "', expected right";
    else if (CentimetresPerUnit(model.units) == 0.0) problem = "unknown units '" + model.units + "'";
    if (!problem.empty() && why != nullptr) *why = problem;
    return problem.empty();
}

Vec3 ModelToUnrealPosition(const Vec3& p, double cmPerUnit) {
    return Vec3{p.x * cmPerUnit, p.z * cmPerUnit, p.y * cmPerUnit};
}

Quat ModelToUnrealRotation(const Quat& q) {
    return Quat{-q.x, -q.z, -q.y, q.w};
}

Vec3 UnrealToModelPosition(const Vec3& p, double cmPerUnit) {
    return Vec3{p.x / cmPerUnit, p.z / cmPerUnit, p.y / cmPerUnit};
}

Quat UnrealToModelRotation(const Quat& q) {
    return Quat{-q.x, -q.z, -q.y, q.w};
}

Pose ModelToUnrealPose(const Pose& pose, double cmPerUnit) {
    Pose out;
    out.root = ModelToUnrealPosition(pose.root, cmPerUnit);
    out.rotations.reserve(pose.rotations.size());
    for (const Quat& q : pose.rotations) out.rotations.push_back(ModelToUnrealRotation(q));
    return out;
}

std::vector<Vec3> UnrealRestOffsets(const ModelInfo& model) {
    const double s = CentimetresPerUnit(model.units) > 0.0 ? CentimetresPerUnit(model.units) : 1.0;
    std::vector<Vec3> out;
    out.reserve(model.joints.size());
    for (const Joint& j : model.joints) out.push_back(ModelToUnrealPosition(j.offset, s));
    return out;
}

}  // namespace rsmt
