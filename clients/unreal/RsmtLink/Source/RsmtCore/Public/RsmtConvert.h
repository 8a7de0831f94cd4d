// Coordinate conversion between the model's frame and Unreal's.
//
// Model (hello.model.skeleton): right-handed, Y up, characters face +Z with their left on +X,
// units from skeleton.units (cm for the shipped models).
// Unreal: left-handed, Z up, centimetres. We map model Y (up) to Unreal Z and model Z (the
// character's forward) to Unreal Y, the forward axis of skeletal meshes in component space
// (the Mannequin faces +Y; ACharacter turns its mesh -90 degrees yaw so it faces the actor's +X):
//
//   position:  (x, y, z)_model * s  ->  (x, z, y)_unreal            s = centimetres per model unit
//   rotation:  (x, y, z, w)_model   ->  (-x, -z, -y, w)_unreal
//
// Swapping two axes is a mirror (determinant -1), which is exactly the handedness change; the
// rotation formula is M R M^T for M = that swap: for a mirror, the rotation axis maps to -M a and
// the angle is kept. Applied to every local rotation and every offset, it converts a whole pose
// (forward kinematics commutes with it). Both maps are their own inverse (up to the scale).
#pragma once

#include <string>

#include "RsmtCoreApi.h"
#include "RsmtMath.h"
#include "RsmtProtocol.h"

namespace rsmt {

// Centimetres per model unit for skeleton.units ("cm", "m", "mm", "in"); 0 when unknown.
RSMTCORE_API double CentimetresPerUnit(const std::string& units);

// True when the model declares the conventions these formulas assume (Y up, right-handed, known units).
RSMTCORE_API bool CheckModelConventions(const ModelInfo& model, std::string* why = nullptr);

RSMTCORE_API Vec3 ModelToUnrealPosition(const Vec3& p, double cmPerUnit = 1.0);
RSMTCORE_API Quat ModelToUnrealRotation(const Quat& q);
RSMTCORE_API Vec3 UnrealToModelPosition(const Vec3& p, double cmPerUnit = 1.0);
RSMTCORE_API Quat UnrealToModelRotation(const Quat& q);

// A whole pose: root position and every local rotation.
RSMTCORE_API Pose ModelToUnrealPose(const Pose& pose, double cmPerUnit = 1.0);

// Rest offsets of the skeleton joints (for bone translations), converted.
RSMTCORE_API std::vector<Vec3> UnrealRestOffsets(const ModelInfo& model);

}  // namespace rsmt
