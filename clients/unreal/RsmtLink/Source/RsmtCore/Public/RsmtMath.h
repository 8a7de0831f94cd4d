// Plain vector and quaternion types of the core (x, y, z, w quaternions, like the wire and both engines).
#pragma once

#include "RsmtCoreApi.h"

namespace rsmt {

struct Vec3 {
    double x = 0.0;
    double y = 0.0;
    double z = 0.0;
};

struct Quat {
    double x = 0.0;
    double y = 0.0;
    double z = 0.0;
    double w = 1.0;
};

RSMTCORE_API Quat Normalize(const Quat& q);
RSMTCORE_API Quat Multiply(const Quat& a, const Quat& b);  // a then b applied to a vector: (a * b) v = a (b v)
RSMTCORE_API Vec3 Rotate(const Quat& q, const Vec3& v);
// Normalized linear interpolation along the shorter arc (what a 30 fps jitter buffer needs between frames).
RSMTCORE_API Quat Nlerp(const Quat& a, const Quat& b, double t);
RSMTCORE_API Vec3 Lerp(const Vec3& a, const Vec3& b, double t);

}  // namespace rsmt
