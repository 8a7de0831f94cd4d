// Poses read from a character (Unity axes) turned into the model's poses, for `start`/`retarget` contexts and
// targets sent as pose arrays (docs/api-contract.md "Motion payloads": root_positions + local rotations).
//
// Unity -> model is the inverse of RsmtCoordinates' model -> Unity map (a mirror across the YZ plane, its own
// inverse):  position (x, y, z)_unity / s -> (-x, y, z)_model,  rotation (x, y, z, w)_unity -> (x, -y, -z, w)_model.
//
// Two ways in:
// - FromUnityLocal: the bones have the model's joint frames (the shipped rig, clients/rig, or a rig built from
//   RsmtReferencePose): each local rotation converts on its own. Exact.
// - FromUnityWorld + RetargetOffsets: any rig whose reference pose (captured once, e.g. its T-pose) is the same
//   body pose as the model's reference (RsmtReferencePose, the T-pose of clients/rig). Per joint j,
//   C_j = inverse(rigReferenceWorld_j) * modelReferenceWorld_j (both in Unity axes) is fixed; at run time the
//   model's world rotation is rigWorld_j * C_j (the rig's rotation away from its reference, carried over onto the
//   model's reference), and local rotations follow from the model's parents. Bones between mapped joints
//   (e.g. Spine1/Spine2) are folded in, since world rotations are used.
using System;
using System.Collections.Generic;

namespace Rsmt.Link
{
    public static class RsmtPoseCapture
    {
        public static RsmtQuat Inverse(RsmtQuat q)
        {
            double n = q.X * q.X + q.Y * q.Y + q.Z * q.Z + q.W * q.W;
            return n > 0 ? new RsmtQuat(-q.X / n, -q.Y / n, -q.Z / n, q.W / n) : RsmtQuat.Identity;
        }

        /// <summary>A pose of a rig with the model's joint frames: bone local rotations and the root bone's position (Unity).</summary>
        public static RsmtPose FromUnityLocal(IList<RsmtQuat> localRotations, RsmtVec3 rootPosition, double metresPerUnit)
        {
            var pose = new RsmtPose(localRotations.Count) { Root = RsmtCoordinates.UnityToModelPosition(rootPosition, metresPerUnit) };
            for (int j = 0; j < localRotations.Count; j++)
                pose.Rotations[j] = RsmtCoordinates.UnityToModelRotation(localRotations[j].Normalized());
            return pose;
        }

        /// <summary>World rotations from local ones by the parents (parents before children; the root's parent is -1).</summary>
        public static RsmtQuat[] WorldRotations(IList<RsmtQuat> localRotations, IList<int> parents)
        {
            var world = new RsmtQuat[localRotations.Count];
            for (int j = 0; j < world.Length; j++)
            {
                int p = parents[j];
                if (p >= j) throw new ArgumentException("parents must come before their children");
                world[j] = p < 0 ? localRotations[j] : RsmtQuat.Multiply(world[p], localRotations[j]);
            }
            return world;
        }

        /// <summary>
        /// C_j = inverse(rigReferenceWorld_j) * modelReferenceWorld_j: the rig's world rotations in its reference pose
        /// (Unity axes) and the model's in the same body pose (model axes, e.g. RsmtReferencePose.WorldRotations).
        /// </summary>
        public static RsmtQuat[] RetargetOffsets(IList<RsmtQuat> rigReferenceWorld, IList<RsmtQuat> modelReferenceWorld)
        {
            if (rigReferenceWorld.Count != modelReferenceWorld.Count) throw new ArgumentException("one reference rotation per joint on both sides");
            var offsets = new RsmtQuat[rigReferenceWorld.Count];
            for (int j = 0; j < offsets.Length; j++)
            {
                var modelInUnity = RsmtCoordinates.ModelToUnityRotation(modelReferenceWorld[j]);
                offsets[j] = RsmtQuat.Multiply(Inverse(rigReferenceWorld[j].Normalized()), modelInUnity.Normalized()).Normalized();
            }
            return offsets;
        }

        /// <summary>
        /// A pose of any rig: the mapped bones' world rotations and the root bone's position (Unity axes, in one space:
        /// world or the character's), the model's parents and RetargetOffsets. rootScale multiplies the root position
        /// (model hip height / rig hip height when the rig is another size).
        /// </summary>
        public static RsmtPose FromUnityWorld(IList<RsmtQuat> rigWorld, RsmtVec3 rootPosition, IList<int> parents,
                                              IList<RsmtQuat> offsets, double metresPerUnit, double rootScale = 1.0)
        {
            int n = rigWorld.Count;
            var world = new RsmtQuat[n];
            for (int j = 0; j < n; j++) world[j] = RsmtQuat.Multiply(rigWorld[j].Normalized(), offsets[j]).Normalized();
            var root = new RsmtVec3(rootPosition.X * rootScale, rootPosition.Y * rootScale, rootPosition.Z * rootScale);
            var pose = new RsmtPose(n) { Root = RsmtCoordinates.UnityToModelPosition(root, metresPerUnit) };
            for (int j = 0; j < n; j++)
            {
                int p = parents[j];
                var local = p < 0 ? world[j] : RsmtQuat.Multiply(Inverse(world[p]), world[j]);
                pose.Rotations[j] = RsmtCoordinates.UnityToModelRotation(local.Normalized());
            }
            return pose;
        }
    }

    /// <summary>
    /// The model's skeleton with a reference pose, read from `rsmt rig export`'s STEM.tpose.json (clients/rig):
    /// joint names, parents, rest offsets and the T-pose (model axes and units).
    /// </summary>
    public sealed class RsmtReferencePose
    {
        public string[] Names;
        public int[] Parents;
        public RsmtVec3[] Offsets;
        public RsmtQuat[] LocalRotations;
        public RsmtQuat[] WorldRotations;
        public RsmtVec3 Root;
        public string Units = "cm";

        public static RsmtReferencePose FromJson(string text)
        {
            var json = Json.Parse(text);
            var joints = json.Get("joints").Array;
            var r = new RsmtReferencePose
            {
                Names = new string[joints.Count], Parents = new int[joints.Count], Offsets = new RsmtVec3[joints.Count],
                LocalRotations = new RsmtQuat[joints.Count], Units = json.GetString("units", "cm"),
            };
            for (int j = 0; j < joints.Count; j++)
            {
                r.Names[j] = joints[j].GetString("name", "");
                r.Parents[j] = joints[j].GetInt("parent", -1);
                r.Offsets[j] = Vec(joints[j].Get("offset"));
                var q = joints[j].Get("t_pose_rotation").Array;
                r.LocalRotations[j] = new RsmtQuat(q[0].Number, q[1].Number, q[2].Number, q[3].Number).Normalized();
            }
            r.Root = Vec(json.Get("t_pose_root_position"));
            r.WorldRotations = RsmtPoseCapture.WorldRotations(r.LocalRotations, r.Parents);
            return r;
        }

        static RsmtVec3 Vec(JsonValue v)
        {
            return new RsmtVec3(v.Array[0].Number, v.Array[1].Number, v.Array[2].Number);
        }
    }

    /// <summary>
    /// The last poses of a character (model axes), resampled to the model's frame rate from whatever rate they are
    /// added at (render frames): each sample is interpolated between the two added poses around its time.
    /// </summary>
    public sealed class RsmtPoseHistory
    {
        readonly RsmtPose[] ring;
        int next, count;
        double prevTime = double.NaN, nextSample;
        RsmtPose prev;

        public double Fps { get; private set; }
        public int Count { get { return count; } }
        public int Capacity { get { return ring.Length; } }

        public RsmtPoseHistory(double fps, int capacity)
        {
            if (fps <= 0 || capacity < 2) throw new ArgumentException("fps > 0 and capacity >= 2");
            Fps = fps;
            ring = new RsmtPose[capacity];
        }

        public void Clear()
        {
            next = count = 0;
            prevTime = double.NaN;
            prev = null;
        }

        /// <summary>A pose at `time` seconds (any clock that only moves forward).</summary>
        public void Add(double time, RsmtPose pose)
        {
            double step = 1.0 / Fps;
            if (prev == null)
            {
                Push(pose.Clone());
                nextSample = time + step;
            }
            else if (time > prevTime)
            {
                // After a stall, interpolate at most a buffer's worth of samples.
                if ((time - nextSample) * Fps > ring.Length) nextSample += Math.Floor((time - nextSample) * Fps - ring.Length + 1) * step;
                while (nextSample <= time + 1e-9)
                {
                    double a = (nextSample - prevTime) / (time - prevTime);
                    Push(Interpolate(prev, pose, Math.Max(0.0, Math.Min(1.0, a))));
                    nextSample += step;
                }
            }
            prevTime = Math.Max(time, double.IsNaN(prevTime) ? time : prevTime);
            prev = pose.Clone();
        }

        /// <summary>The newest `frames` samples, oldest first (fewer while the history fills).</summary>
        public List<RsmtPose> Last(int frames)
        {
            int n = Math.Min(frames, count);
            var output = new List<RsmtPose>(n);
            for (int i = n; i > 0; i--) output.Add(ring[(next - i + ring.Length) % ring.Length]);
            return output;
        }

        /// <summary>The newest `frames` samples as a Motion payload (pose arrays at this history's fps).</summary>
        public string MotionJson(int frames)
        {
            return RsmtMessages.PoseMotion(Last(frames), Fps);
        }

        void Push(RsmtPose pose)
        {
            ring[next] = pose;
            next = (next + 1) % ring.Length;
            if (count < ring.Length) count++;
        }

        static RsmtPose Interpolate(RsmtPose a, RsmtPose b, double t)
        {
            var p = new RsmtPose(b.Rotations.Length) { Root = RsmtVec3.Lerp(a.Root, b.Root, t) };
            for (int j = 0; j < p.Rotations.Length; j++)
                p.Rotations[j] = j < a.Rotations.Length ? RsmtQuat.Nlerp(a.Rotations[j], b.Rotations[j], t) : b.Rotations[j];
            return p;
        }
    }
}
