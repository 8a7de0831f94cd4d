// Console check of RsmtPoseCapture / RsmtReferencePose / RsmtPoseHistory (built with mcs by
// tests/clients/test_pose_capture.py; ignored by Unity like the rest of Harness~).
//
//   mono RsmtPoseHarness.exe CASE.json     prints one JSON object:
//     exact:      PoseMotion JSON of FromUnityLocal(case.unity_local, case.unity_root)
//     unity_fk:   world positions (Unity axes) by forward kinematics over case.unity_offsets and case.unity_local
//     retarget:   PoseMotion JSON of FromUnityWorld(case.game_world, ...) with RetargetOffsets(case.game_reference_world,
//                 the reference pose read from case.reference_path)
//     turn_left:  FromUnityLocal of one joint rotated -90 degrees about Unity's up (a turn toward the character's left)
//     history:    PoseMotion JSON of the last case.history_frames samples after adding case.history poses
using System;
using System.Collections.Generic;
using System.Globalization;
using System.IO;
using System.Text;
using Rsmt.Link;

static class RsmtPoseHarness
{
    static RsmtQuat Q(JsonValue v) { return new RsmtQuat(v.Array[0].Number, v.Array[1].Number, v.Array[2].Number, v.Array[3].Number); }
    static RsmtVec3 V(JsonValue v) { return new RsmtVec3(v.Array[0].Number, v.Array[1].Number, v.Array[2].Number); }

    static List<RsmtQuat> Quats(JsonValue v)
    {
        var output = new List<RsmtQuat>();
        foreach (var q in v.Array) output.Add(Q(q));
        return output;
    }

    static string Num(double d) { return Json.Number(d); }

    static int Main(string[] args)
    {
        var c = Json.Parse(File.ReadAllText(args[0]));
        double s = c.GetNumber("metres_per_unit", 0.01);
        var parents = new List<int>();
        foreach (var p in c.Get("parents").Array) parents.Add((int)p.Number);
        var sb = new StringBuilder("{");

        // Exact path: a rig with the model's joint frames.
        var local = Quats(c.Get("unity_local"));
        var exact = RsmtPoseCapture.FromUnityLocal(local, V(c.Get("unity_root")), s);
        sb.Append("\"exact\":").Append(RsmtMessages.PoseMotion(new[] { exact }));

        // Forward kinematics in Unity axes, with Unity's own quaternion rotation of the offsets.
        var offsets = c.Get("unity_offsets").Array;
        var world = RsmtPoseCapture.WorldRotations(local, parents);
        var pos = new RsmtVec3[local.Count];
        sb.Append(",\"unity_fk\":[");
        for (int j = 0; j < local.Count; j++)
        {
            if (parents[j] < 0) pos[j] = V(c.Get("unity_root"));
            else
            {
                var o = RsmtQuat.Rotate(world[parents[j]], V(offsets[j]));
                var pp = pos[parents[j]];
                pos[j] = new RsmtVec3(pp.X + o.X, pp.Y + o.Y, pp.Z + o.Z);
            }
            sb.Append(j > 0 ? "," : "").Append('[').Append(Num(pos[j].X)).Append(',').Append(Num(pos[j].Y)).Append(',').Append(Num(pos[j].Z)).Append(']');
        }
        sb.Append(']');

        // Retarget path: a rig with other bone frames, through the reference poses.
        var reference = RsmtReferencePose.FromJson(File.ReadAllText(c.GetString("reference_path", "")));
        var offsetsC = RsmtPoseCapture.RetargetOffsets(Quats(c.Get("game_reference_world")), reference.WorldRotations);
        var retarget = RsmtPoseCapture.FromUnityWorld(Quats(c.Get("game_world")), V(c.Get("game_root")), reference.Parents, offsetsC, s);
        sb.Append(",\"retarget\":").Append(RsmtMessages.PoseMotion(new[] { retarget }));
        sb.Append(",\"reference_names\":[");
        for (int j = 0; j < reference.Names.Length; j++) sb.Append(j > 0 ? "," : "").Append(Json.Quote(reference.Names[j]));
        sb.Append("]");

        // Unity's "turn left": -90 degrees about +Y (Unity rotates clockwise seen from above for positive angles).
        double h = -Math.PI / 4;
        var turn = RsmtPoseCapture.FromUnityLocal(new[] { new RsmtQuat(0, Math.Sin(h), 0, Math.Cos(h)) }, new RsmtVec3(0.1, 0.2, 0.3), s);
        sb.Append(",\"turn_left\":").Append(RsmtMessages.PoseMotion(new[] { turn }));

        // History: poses at irregular times, resampled to the history's fps.
        var history = new RsmtPoseHistory(c.GetNumber("history_fps", 30), 16);
        foreach (var item in c.Get("history").Array)
        {
            var pose = new RsmtPose(item.Get("rotations").Array.Count) { Root = V(item.Get("root")) };
            var rots = Quats(item.Get("rotations"));
            for (int j = 0; j < rots.Count; j++) pose.Rotations[j] = rots[j];
            history.Add(item.GetNumber("t", 0), pose);
        }
        sb.Append(",\"history_count\":").Append(history.Count.ToString(CultureInfo.InvariantCulture));
        sb.Append(",\"history\":").Append(history.MotionJson(c.GetInt("history_frames", 10)));
        Console.WriteLine(sb.Append('}').ToString());
        return 0;
    }
}
