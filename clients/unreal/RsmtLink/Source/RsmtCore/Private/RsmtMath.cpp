#include "RsmtMath.h"

#include <cmath>

namespace rsmt {

Quat Normalize(const Quat& q) {
    const double n = std::sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w);
    if (!(n > 0.0)) return Quat();
    return Quat{q.x / n, q.y / n, q.z / n, q.w / n};
}

Quat Multiply(const Quat& a, const Quat& b) {
    return Quat{a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
                a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x,
                a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w,
                a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z};
}

Vec3 Rotate(const Quat& q, const Vec3& v) {
    // v' = v + 2 w (u x v) + 2 u x (u x v), u = (x, y, z)
    const double tx = 2.0 * (q.y * v.z - q.z * v.y);
    const double ty = 2.0 * (q.z * v.x - q.x * v.z);
    const double tz = 2.0 * (q.x * v.y - q.y * v.x);
    return Vec3{v.x + q.w * tx + (q.y * tz - q.z * ty),
                v.y + q.w * ty + (q.z * tx - q.x * tz),
                v.z + q.w * tz + (q.x * ty - q.y * tx)};
}

Quat Nlerp(const Quat& a, const Quat& b, double t) {
    const double dot = a.x * b.x + a.y * b.y + a.z * b.z + a.w * b.w;
    const double s = dot < 0.0 ? -1.0 : 1.0;
    return Normalize(Quat{a.x + t * (s * b.x - a.x), a.y + t * (s * b.y - a.y), a.z + t * (s * b.z - a.z),
                          a.w + t * (s * b.w - a.w)});
}

Vec3 Lerp(const Vec3& a, const Vec3& b, double t) {
    return Vec3{a.x + t * (b.x - a.x), a.y + t * (b.y - a.y), a.z + t * (b.z - a.z)};
}

}  // namespace rsmt
