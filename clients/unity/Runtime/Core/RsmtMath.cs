// Plain vector and quaternion types of the core (doubles; x, y, z, w quaternions like the wire and Unity).
using System;

namespace Rsmt.Link
{
    public struct RsmtVec3
    {
        public double X, Y, Z;

        public RsmtVec3(double x, double y, double z) { X = x; Y = y; Z = z; }

        public static RsmtVec3 Lerp(RsmtVec3 a, RsmtVec3 b, double t)
        {
            return new RsmtVec3(a.X + t * (b.X - a.X), a.Y + t * (b.Y - a.Y), a.Z + t * (b.Z - a.Z));
        }

        public override string ToString() { return "(" + X + ", " + Y + ", " + Z + ")"; }
    }

    public struct RsmtQuat
    {
        public double X, Y, Z, W;

        public RsmtQuat(double x, double y, double z, double w) { X = x; Y = y; Z = z; W = w; }

        public static readonly RsmtQuat Identity = new RsmtQuat(0, 0, 0, 1);

        public RsmtQuat Normalized()
        {
            double n = Math.Sqrt(X * X + Y * Y + Z * Z + W * W);
            return n > 0 ? new RsmtQuat(X / n, Y / n, Z / n, W / n) : Identity;
        }

        /// <summary>a * b: apply b, then a.</summary>
        public static RsmtQuat Multiply(RsmtQuat a, RsmtQuat b)
        {
            return new RsmtQuat(a.W * b.X + a.X * b.W + a.Y * b.Z - a.Z * b.Y,
                                a.W * b.Y - a.X * b.Z + a.Y * b.W + a.Z * b.X,
                                a.W * b.Z + a.X * b.Y - a.Y * b.X + a.Z * b.W,
                                a.W * b.W - a.X * b.X - a.Y * b.Y - a.Z * b.Z);
        }

        public static RsmtVec3 Rotate(RsmtQuat q, RsmtVec3 v)
        {
            double tx = 2 * (q.Y * v.Z - q.Z * v.Y), ty = 2 * (q.Z * v.X - q.X * v.Z), tz = 2 * (q.X * v.Y - q.Y * v.X);
            return new RsmtVec3(v.X + q.W * tx + (q.Y * tz - q.Z * ty),
                                v.Y + q.W * ty + (q.Z * tx - q.X * tz),
                                v.Z + q.W * tz + (q.X * ty - q.Y * tx));
        }

        /// <summary>Normalized linear interpolation along the shorter arc.</summary>
        public static RsmtQuat Nlerp(RsmtQuat a, RsmtQuat b, double t)
        {
            double s = a.X * b.X + a.Y * b.Y + a.Z * b.Z + a.W * b.W < 0 ? -1 : 1;
            return new RsmtQuat(a.X + t * (s * b.X - a.X), a.Y + t * (s * b.Y - a.Y), a.Z + t * (s * b.Z - a.Z),
                                a.W + t * (s * b.W - a.W)).Normalized();
        }

        public override string ToString() { return "(" + X + ", " + Y + ", " + Z + ", " + W + ")"; }
    }

    /// <summary>One pose: the root joint's position and every joint's local rotation, in skeleton order.</summary>
    public sealed class RsmtPose
    {
        public RsmtVec3 Root;
        public RsmtQuat[] Rotations;

        public RsmtPose(int joints)
        {
            Rotations = new RsmtQuat[joints];
            for (int i = 0; i < joints; i++) Rotations[i] = RsmtQuat.Identity;
        }

        public RsmtPose Clone()
        {
            var p = new RsmtPose(Rotations.Length) { Root = Root };
            Array.Copy(Rotations, p.Rotations, Rotations.Length);
            return p;
        }
    }
}
