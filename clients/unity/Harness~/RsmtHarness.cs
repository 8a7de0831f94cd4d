// Console harness of the Unity core (no UnityEngine), built with Mono's mcs by tests/clients/test_unity_core.py:
//
//   mcs -out:RsmtHarness.exe -r:System.Net.Http.dll Runtime/Core/*.cs Harness~/RsmtHarness.cs
//   mono RsmtHarness.exe selftest
//   mono RsmtHarness.exe run --url http://127.0.0.1:8000 [--api-key K] --context a.bvh --target b.bvh --style s.bvh
//        --frames 40 [--seed 7] [--deterministic] [--encoding binary|json] [--retarget c.bvh --retarget-after 5
//        --retarget-frames 12] [--target-at x,z,yaw --target-at-frames 40] [--delay 0.1] --out result.json
//   mono RsmtHarness.exe failover --url URL [--api-key K] --context a.bvh --target b.bvh [--target2 c.bvh] --style s.bvh
//        --frames 60 [--characters 2] [--encoding binary|json] --kill-after 10 [--failover] [--attempts 40] --out result.json
//
// `run` registers the style over HTTP, connects, reads hello, streams one transition (pace asap) and records
// every frame converted to Unity axes; with --retarget it streams a second one in real time, retargets it
// mid-way, and plays it through the jitter buffer, recording what was shown; with --target-at it streams one more
// started with TargetAtJson (a place and facing in the model's units and axes) and records its last frame.
// `failover` registers the style through the stream client, streams several characters in real time with
// exact_arrival, prints {"kill": true} once the first has sent --kill-after frames (the test then kills the server
// and starts another on the same port) and records every frame (Unity axes), started/end, errors and losses.
using System;
using System.Collections.Generic;
using System.Diagnostics;
using System.Globalization;
using System.IO;
using System.Linq;
using System.Text;
using System.Threading;
using Rsmt.Link;

static class RsmtHarness
{
    static int checks, failures;

    static void Check(bool condition, string what)
    {
        checks++;
        if (!condition)
        {
            failures++;
            Console.Error.WriteLine("FAILED: " + what);
        }
    }

    static bool Near(double a, double b, double tol = 1e-9) { return Math.Abs(a - b) <= tol; }
    static bool NearV(RsmtVec3 a, RsmtVec3 b, double tol = 1e-9) { return Near(a.X, b.X, tol) && Near(a.Y, b.Y, tol) && Near(a.Z, b.Z, tol); }
    static bool NearQ(RsmtQuat a, RsmtQuat b, double tol = 1e-9)
    {
        return Near(a.X, b.X, tol) && Near(a.Y, b.Y, tol) && Near(a.Z, b.Z, tol) && Near(a.W, b.W, tol);
    }

    static string Hello(int joints, bool shuffled)
    {
        var sb = new StringBuilder("{\"type\":\"hello\",\"protocol\":1,\"encoding\":\"binary\",\"model\":{\"name\":\"m\",\"version\":\"v\",\"fps\":30.0,"
            + "\"context_frames\":10,\"max_transition_frames\":60,\"skeleton\":{\"joints\":[");
        for (int j = 0; j < joints; j++)
            sb.Append(j > 0 ? "," : "").Append("{\"name\":\"J" + j + "\",\"parent\":" + (j - 1) + ",\"offset\":[1,2,3]}");
        int rot = 4 * joints;
        sb.Append("],\"units\":\"cm\",\"up_axis\":\"y\",\"handedness\":\"right\"}},\"frame_layout\":{\"encoding\":\"float32-le\",\"floats_per_frame\":" + (7 + rot) + ",\"fields\":[");
        if (!shuffled)
            sb.Append("{\"name\":\"slot\",\"offset\":0,\"count\":1},{\"name\":\"seq\",\"offset\":1,\"count\":1},{\"name\":\"t\",\"offset\":2,\"count\":1},"
                + "{\"name\":\"root_position\",\"offset\":3,\"count\":3},{\"name\":\"rotations\",\"offset\":6,\"count\":" + rot + "},"
                + "{\"name\":\"remaining\",\"offset\":" + (6 + rot) + ",\"count\":1}");
        else  // another order: a client must read offsets from hello, not assume them
            sb.Append("{\"name\":\"rotations\",\"offset\":0,\"count\":" + rot + "},{\"name\":\"root_position\",\"offset\":" + rot + ",\"count\":3},"
                + "{\"name\":\"remaining\",\"offset\":" + (rot + 3) + ",\"count\":1},{\"name\":\"t\",\"offset\":" + (rot + 4) + ",\"count\":1},"
                + "{\"name\":\"seq\",\"offset\":" + (rot + 5) + ",\"count\":1},{\"name\":\"slot\",\"offset\":" + (rot + 6) + ",\"count\":1}");
        sb.Append("]},\"limits\":{\"max_characters\":64,\"send_queue_frames\":16,\"idle_timeout_s\":60,\"max_message_bytes\":65536}}");
        return sb.ToString();
    }

    static byte[] Floats(float[] values)
    {
        var bytes = new byte[values.Length * 4];
        for (int i = 0; i < values.Length; i++)
        {
            var b = BitConverter.GetBytes(values[i]);
            if (!BitConverter.IsLittleEndian) Array.Reverse(b);
            Array.Copy(b, 0, bytes, 4 * i, 4);
        }
        return bytes;
    }

    static RsmtFrame F(int seq, double x)
    {
        var p = new RsmtPose(1) { Root = new RsmtVec3(x, 0, 0) };
        return new RsmtFrame { Seq = seq, T = (seq + 1) / 30.0, Pose = p };
    }

    // Failover without I/O (RsmtFailover): what is resent after a lost connection and how resumed frames are numbered.
    static RsmtMessage FrameMsg(string cid, int seq, int remaining, double x)
    {
        var p = new RsmtPose(1) { Root = new RsmtVec3(x, 0, 0) };
        return new RsmtMessage { Kind = RsmtMessageKind.Frame, Character = cid, Frame = new RsmtFrame { Character = cid, Seq = seq, Remaining = remaining, Pose = p } };
    }

    static RsmtMessage Msg(RsmtMessageKind kind, string cid, string code = null)
    {
        return new RsmtMessage { Kind = kind, Character = cid, Code = code };
    }

    static double[] ContextXs(string start)
    {
        return Json.Parse(start).Get("context").Get("root_positions").Array.Select(r => r.Array[0].Number).ToArray();
    }

    static void FailoverSelfTest()
    {
        var ctx = new List<RsmtPose>();
        for (int i = 0; i < 6; i++) ctx.Add(new RsmtPose(1) { Root = new RsmtVec3(i, 0, 0) });
        Func<string, int, RsmtStartOptions> opts = (cid, n) => new RsmtStartOptions
        {
            Character = cid, ContextJson = RsmtMessages.PoseMotion(ctx), TargetJson = "{\"bvh\":\"T\"}", Frames = n, StyleId = "sty_a",
            Model = "m2", ExactArrival = true, StyleStrength = 1.25,
        };
        var f = new RsmtFailover { ContextFrames = 4, Fps = 30, Joints = 1 };
        f.SentStart(opts("hero", 10), "start-text");
        var st = Msg(RsmtMessageKind.Started, "hero");
        f.Received(st);
        Check(!st.Resumed && f.Live, "failover: first started is not a resume");
        for (int seq = 0; seq < 6; seq++) f.Received(FrameMsg("hero", seq, 9 - seq, 100 + seq));
        var resume = f.ResumeMessages();
        Check(resume.Count == 1 && f.Resumes == 1, "failover: one resume");
        var r = Json.Parse(resume[0]);
        Check(r.GetInt("frames", 0) == 4 && r.Get("target").GetString("bvh", "") == "T" && r.GetString("style_id", "") == "sty_a"
              && r.GetString("model", "") == "m2" && r.GetBool("exact_arrival", false) && r.GetString("character", "") == "hero", "failover: same start, frames to go");
        Check(Near(r.GetNumber("style_strength", 0), 1.25), "failover: the resume keeps the style strength");
        Check(!r.GetBool("retargeted", false), "failover: a character never retargeted is not resumed as one");
        Check(ContextXs(resume[0]).SequenceEqual(new double[] { 102, 103, 104, 105 }), "failover: context is the last poses received");
        st = Msg(RsmtMessageKind.Started, "hero");
        f.Received(st);
        Check(st.Resumed, "failover: resumed started");
        RsmtMessage last = null;
        for (int seq = 0; seq < 4; seq++) f.Received(last = FrameMsg("hero", seq, 3 - seq, 0));
        Check(last.Frame.Seq == 9 && Near(last.Frame.T, 10 / 30.0), "failover: resumed frames numbered on");
        var end = Msg(RsmtMessageKind.End, "hero");
        end.Frames = 4;
        f.Received(end);
        Check(end.Frames == 10 && !f.Live && f.ResumeMessages().Count == 0, "failover: end counts every frame");

        var g = new RsmtFailover { ContextFrames = 4, Fps = 30, Joints = 1 };  // fewer frames than the context
        g.SentStart(opts("hero", 10), "s");
        g.Received(FrameMsg("hero", 0, 9, 50));
        Check(ContextXs(g.ResumeMessages()[0]).SequenceEqual(new double[] { 3, 4, 5, 50 }), "failover: original context before the received poses");
        var h = new RsmtFailover { ContextFrames = 4, Fps = 30, Joints = 1 };  // a BVH context: the first received pose held
        var bvh = opts("hero", 10);
        bvh.ContextJson = RsmtMessages.BvhMotion("HIERARCHY");
        h.SentStart(bvh, "s");
        h.Received(FrameMsg("hero", 0, 9, 50));
        Check(ContextXs(h.ResumeMessages()[0]).SequenceEqual(new double[] { 50, 50, 50, 50 }), "failover: unreadable context holds the first pose");

        var k = new RsmtFailover { ContextFrames = 4, Fps = 30, Joints = 1 };  // retarget, style and cancel carried over
        k.SentStart(opts("a", 10), "sa");
        k.SentStart(opts("b", 10), "sb");
        k.SentCancel("b");
        for (int seq = 0; seq < 5; seq++) k.Received(FrameMsg("a", seq, 9 - seq, seq));
        k.SentRetarget("a", "{\"bvh\":\"T2\"}", 20);
        k.SentStyle("a", "sty_b", "style-text");
        var kr = k.ResumeMessages();
        var krj = Json.Parse(kr[0]);
        Check(kr.Count == 1 && krj.GetInt("frames", 0) == 20 && krj.Get("target").GetString("bvh", "") == "T2"
              && krj.GetString("style_id", "") == "sty_b", "failover: retarget and style carried, cancelled dropped");
        Check(krj.GetBool("retargeted", false), "failover: a target changed mid-motion resumes as a retargeted character");
        var old = k.Received(Msg(RsmtMessageKind.Error, "a", "validation_error"));  // a replica older than the option
        var oldj = Json.Parse(old.Resend);
        Check(!old.Deliver && old.RegisterStyleId == null && !oldj.GetBool("retargeted", false) && oldj.GetInt("frames", 0) == 20
              && oldj.Get("target").GetString("bvh", "") == "T2", "failover: a resume refused for retargeted is sent again without it");
        Check(k.Received(Msg(RsmtMessageKind.Error, "a", "validation_error")).Deliver && !k.Live, "failover: refused again, the error is delivered");
        var early = new RsmtFailover { ContextFrames = 4, Fps = 30, Joints = 1 };  // a new target before any frame: a start to it
        early.SentStart(opts("a", 10), "sa");
        early.SentRetarget("a", "{\"bvh\":\"T2\"}", 0);
        var nj = Json.Parse(early.ResumeMessages()[0]);
        Check(nj.Get("target").GetString("bvh", "") == "T2" && !nj.GetBool("retargeted", false), "failover: retarget before any frame is a start");
        var placedStart = opts("a", 10);
        placedStart.TargetAtJson = RsmtMessages.TargetAt(50, 60, 90);
        var at = new RsmtFailover { ContextFrames = 4, Fps = 30, Joints = 1 };  // a start to a place: resumed to it
        at.SentStart(placedStart, "sa");
        var atj = Json.Parse(at.ResumeMessages()[0]);
        Check(atj.Get("target") == null && Near(atj.Get("target_at").GetNumber("yaw", 0), 90), "failover: a start to a place resumes to it");
        at.SentRetarget("a", "{\"bvh\":\"T2\"}", 0);
        atj = Json.Parse(at.ResumeMessages()[0]);
        Check(atj.Get("target_at") == null && atj.Get("target").GetString("bvh", "") == "T2", "failover: a pose retarget replaces the place");

        var u = new RsmtFailover { ContextFrames = 4, Fps = 30, Joints = 1 };  // unknown_style: register again and resend
        u.RememberStyle("sty_a", "BVH", "walk");
        u.SentStart(opts("hero", 10), "start-text");
        var act = u.Received(Msg(RsmtMessageKind.Error, "hero", "unknown_style"));
        Check(!act.Deliver && act.RegisterStyleId == "sty_a" && act.Resend == "start-text" && u.Reregistrations == 1, "failover: unknown_style re-registers");
        var w = new RsmtFailover();  // a style it never held: the error goes to the caller, nothing to resume
        w.SentStart(opts("hero", 10), "start-text");
        Check(w.Received(Msg(RsmtMessageKind.Error, "hero", "unknown_style")).Deliver && !w.Live, "failover: unknown clip is an error");
        Check(!RsmtFailover.Resumable(1008) && !RsmtFailover.Resumable(1009) && RsmtFailover.Resumable(1006) && RsmtFailover.Resumable(1001),
              "failover: close codes");
    }

    static int SelfTest()
    {
        // JSON
        var v = Json.Parse("{\"a\": [1, -2.5e2, true, false, null], \"s\": \"q\\\"\\\\\\n\\u00e9\"}");
        Check(v.Get("a").Array.Count == 5 && Near(v.Get("a").Array[1].Number, -250), "json numbers");
        Check(v.Get("a").Array[2].Bool && !v.Get("a").Array[3].Bool && v.Get("a").Array[4].IsNull, "json literals");
        Check(v.GetString("s", "") == "q\"\\\n\u00e9", "json escapes");
        foreach (var bad in new[] { "{\"a\": 1,}", "[1 2]", "\"open", "{} x", "01x", new string('[', 100) })
        {
            JsonValue ignored;
            string error;
            Check(!Json.TryParse(bad, out ignored, out error) && error != null, "json rejects " + bad.Substring(0, Math.Min(12, bad.Length)));
        }
        Check(Json.Quote("a\"b\\c\n\u0001") == "\"a\\\"b\\\\c\\n\\u0001\"", "json quote");
        var saved = Thread.CurrentThread.CurrentCulture;
        Thread.CurrentThread.CurrentCulture = new CultureInfo("de-DE");
        Check(Json.Number(0.5) == "0.5" && Near(Json.Parse("[0.5]").Array[0].Number, 0.5), "json is culture-invariant");
        Thread.CurrentThread.CurrentCulture = saved;

        // Conversion, known values: x mirrored, centimetres to metres.
        double cm = RsmtCoordinates.MetresPerUnit("cm");
        Check(Near(cm, 0.01) && RsmtCoordinates.MetresPerUnit("furlong") == 0, "units");
        Check(NearV(RsmtCoordinates.ModelToUnityPosition(new RsmtVec3(10, 20, 30), cm), new RsmtVec3(-0.1, 0.2, 0.3), 1e-12), "position (10,20,30)cm -> (-0.1,0.2,0.3)m");
        Check(NearV(RsmtCoordinates.UnityToModelPosition(new RsmtVec3(-0.1, 0.2, 0.3), cm), new RsmtVec3(10, 20, 30), 1e-12), "position back");
        double h = Math.Sqrt(0.5);
        var yaw90 = new RsmtQuat(0, h, 0, h);  // model: +90 deg about up turns +Z (forward) to +X (the character's left)
        Check(NearV(RsmtQuat.Rotate(yaw90, new RsmtVec3(0, 0, 1)), new RsmtVec3(1, 0, 0), 1e-12), "model yaw turns left");
        var unityYaw = RsmtCoordinates.ModelToUnityRotation(yaw90);
        Check(NearQ(unityYaw, new RsmtQuat(0, -h, 0, h), 1e-12), "rotation (0,s,0,s) -> (0,-s,0,s)");
        // In Unity that is -90 deg about Y: forward (+Z) turns to -X, which is a +Z-facing character's left too.
        Check(NearV(RsmtQuat.Rotate(unityYaw, new RsmtVec3(0, 0, 1)), new RsmtVec3(-1, 0, 0), 1e-12), "unity yaw turns left");
        var rng = new Random(7);
        Func<double> n = () => rng.NextDouble() * 2 - 1;
        for (int i = 0; i < 200; i++)
        {
            var q = new RsmtQuat(n(), n(), n(), n()).Normalized();
            var r = new RsmtQuat(n(), n(), n(), n()).Normalized();
            var p = new RsmtVec3(n(), n(), n());
            var lhs = RsmtCoordinates.ModelToUnityPosition(RsmtQuat.Rotate(q, p), 1);
            var rhs = RsmtQuat.Rotate(RsmtCoordinates.ModelToUnityRotation(q), RsmtCoordinates.ModelToUnityPosition(p, 1));
            Check(NearV(lhs, rhs, 1e-9), "M(q v) == q'(M v)");
            Check(NearQ(RsmtCoordinates.ModelToUnityRotation(RsmtQuat.Multiply(q, r)),
                        RsmtQuat.Multiply(RsmtCoordinates.ModelToUnityRotation(q), RsmtCoordinates.ModelToUnityRotation(r)), 1e-12), "(q r)' == q' r'");
            Check(NearQ(RsmtCoordinates.UnityToModelRotation(RsmtCoordinates.ModelToUnityRotation(q)), q, 0), "rotation inverse");
        }

        // Protocol: hello, started, binary frames (standard and shuffled layouts), JSON frames, errors.
        foreach (bool shuffled in new[] { false, true })
        {
            var s = new RsmtSession();
            s.HandleText(Hello(2, shuffled));
            Check(s.HasHello && s.Joints == 2 && s.Hello.Layout.FloatsPerFrame == 15 && s.Hello.MaxMessageBytes == 65536, "hello");
            var started = s.HandleText("{\"type\":\"started\",\"character\":\"hero\",\"slot\":3,\"frames\":40,\"fps\":30.0,\"style_id\":\"sty\"}");
            Check(started.Kind == RsmtMessageKind.Started && started.Frames == 40 && started.StyleId == "sty", "started");
            float[] rots = { 0, 0, 0, 1, 0.5f, 0.5f, 0.5f, 0.5f };
            float[] values = shuffled
                ? rots.Concat(new float[] { 1.5f, 92.25f, -3f, 32, 8f / 30f, 7, 3 }).ToArray()
                : new float[] { 3, 7, 8f / 30f, 1.5f, 92.25f, -3f }.Concat(rots).Concat(new float[] { 32 }).ToArray();
            var bin = Floats(values);
            var m = s.HandleBinary(bin, bin.Length);
            Check(m.Kind == RsmtMessageKind.Frame && m.Frame.Character == "hero" && m.Frame.Seq == 7 && m.Frame.Remaining == 32, "binary frame fields" + (shuffled ? " (shuffled layout)" : ""));
            Check(NearV(m.Frame.Pose.Root, new RsmtVec3(1.5, 92.25, -3)) && NearQ(m.Frame.Pose.Rotations[1], new RsmtQuat(0.5, 0.5, 0.5, 0.5)), "binary frame pose");
            bool threw = false;
            try { s.HandleBinary(bin, bin.Length - 4); } catch (RsmtProtocolException) { threw = true; }
            Check(threw, "short binary frame refused");
        }
        // A character of another model (5 joints): its layout comes from started.floats_per_frame.
        var ms = new RsmtSession();
        ms.HandleText(Hello(2, false));
        ms.HandleText("{\"type\":\"started\",\"character\":\"big\",\"slot\":9,\"frames\":3,\"fps\":30.0,\"floats_per_frame\":27}");
        Check(ms.LayoutOf(9).Joints == 5 && ms.LayoutOf(9).Remaining == 26 && ms.LayoutOf(0).Joints == 2, "layout of another model");
        var rots5 = new float[20];
        for (int j = 0; j < 5; j++) rots5[4 * j + 3] = 1;
        var big = Floats(new float[] { 9, 0, 1f / 30f, 0, 1, 2 }.Concat(rots5).Concat(new float[] { 2 }).ToArray());
        var bm = ms.HandleBinary(big, big.Length);
        Check(bm.Frame.Character == "big" && bm.Frame.Pose.Rotations.Length == 5 && bm.Frame.Remaining == 2, "binary frame of another model");
        var jm = ms.HandleText("{\"type\":\"frame\",\"character\":\"big\",\"slot\":9,\"seq\":1,\"t\":0.06666667,\"remaining\":1,"
            + "\"pose\":{\"root_position\":[0,1,2],\"rotations\":[[0,0,0,1],[0,0,0,1],[0,0,0,1],[0,0,0,1],[0,0,0,1]]}}");
        Check(jm.Frame.Pose.Rotations.Length == 5, "json frame of another model");

        var js = new RsmtSession();
        js.HandleText(Hello(2, false));
        var jf = js.HandleText("{\"type\":\"frame\",\"character\":\"a\",\"slot\":0,\"seq\":1,\"t\":0.06666667,\"remaining\":3,\"pose\":{\"root_position\":[1,2,3],\"rotations\":[[0,0,0,1],[0,1,0,0]]}}");
        Check(jf.Kind == RsmtMessageKind.Frame && NearQ(jf.Frame.Pose.Rotations[1], new RsmtQuat(0, 1, 0, 0)) && jf.Frame.Remaining == 3, "json frame");
        var err = js.HandleText("{\"type\":\"error\",\"code\":\"unknown_style\",\"message\":\"no\",\"character\":\"a\"}");
        Check(err.Kind == RsmtMessageKind.Error && err.Code == "unknown_style", "error message");
        bool before = false;
        try { new RsmtSession().HandleText("{\"type\":\"frame\"}"); } catch (RsmtProtocolException) { before = true; }
        Check(before, "hello must come first");

        // Client messages parse back.
        var start = Json.Parse(RsmtMessages.Start(new RsmtStartOptions
        {
            Character = "hero", ContextJson = RsmtMessages.BvhMotion("HIERARCHY\n\"x\"\t"), TargetJson = RsmtMessages.PoseMotion(new[] { new RsmtPose(2) }),
            Frames = 40, StyleId = "sty", Seed = 12345678901234L, Deterministic = true, Pace = "asap", ExactArrival = true,
        }));
        Check(start.GetBool("exact_arrival", false), "start exact_arrival");
        Check(start.Get("style_strength") == null, "start without a style strength leaves it to the server");
        var strong = Json.Parse(RsmtMessages.Start(new RsmtStartOptions
        {
            Character = "hero", ContextJson = RsmtMessages.BvhMotion("C"), TargetJson = RsmtMessages.BvhMotion("T"), Frames = 40,
            StyleId = "sty", StyleStrength = 1.25,
        }));
        Check(Near(strong.GetNumber("style_strength", 0), 1.25), "start style_strength");
        var placed = Json.Parse(RsmtMessages.Start(new RsmtStartOptions
        {
            Character = "hero", ContextJson = RsmtMessages.BvhMotion("C"), TargetAtJson = RsmtMessages.TargetAt(120, -30.5, 90),
            Frames = 40, StyleId = "sty",
        }));
        var placedAt = placed.Get("target_at");
        Check(placed.Get("target") == null && placedAt != null && Near(placedAt.GetNumber("x", 0), 120)
              && Near(placedAt.GetNumber("z", 0), -30.5) && Near(placedAt.GetNumber("yaw", 0), 90), "start target_at");
        Check(start.GetString("type", "") == "start" && start.Get("context").GetString("bvh", "") == "HIERARCHY\n\"x\"\t", "start context");
        Check(Near(start.GetNumber("seed", 0), 12345678901234.0) && start.GetBool("deterministic", false) && start.GetString("pace", "") == "asap", "start options");
        Check(Near(start.Get("target").Get("rotations").Array[0].Array[1].Array[3].Number, 1), "pose motion");
        var retarget = Json.Parse(RsmtMessages.Retarget("hero", null, 12));
        Check(retarget.Get("target") == null && retarget.GetInt("frames", 0) == 12, "retarget frames only");

        // Jitter buffer: steady playback behind the first arrival, interpolation, starvation, skipping, reset.
        var jb = new RsmtJitterBuffer(0.1, 30);
        RsmtPose pose;
        Check(!jb.Sample(0, out pose), "empty buffer shows nothing");
        jb.Push(F(0, 0), 1.0);
        Check(!jb.Sample(1.05, out pose), "frame 0 not due before 1.1");
        Check(jb.Sample(1.1001, out pose) && Near(pose.Root.X, 0), "frame 0 at 1.1");
        jb.Push(F(1, 10), 1.12);
        jb.Push(F(2, 20), 1.13);
        Check(jb.Sample(1.1 + 0.5 / 30, out pose) && Near(pose.Root.X, 5, 1e-9), "interpolates halfway");
        Check(jb.Sample(1.1 + 2.0 / 30 + 1e-6, out pose) && Near(pose.Root.X, 20, 1e-9) && jb.ShownSeq == 2 && jb.Underruns == 0, "frame 2");
        Check(jb.Sample(1.1 + 4.0 / 30, out pose) && Near(pose.Root.X, 20) && jb.Underruns == 1, "starved: hold, one underrun");
        jb.Push(F(3, 30), 1.5);
        Check(jb.Sample(1.55, out pose) && Near(pose.Root.X, 20), "re-buffering holds");
        Check(jb.Sample(1.6 + 1e-6, out pose) && Near(pose.Root.X, 30, 1e-9), "frame 3 plays delay after arrival");
        for (int s = 4; s < 40; s++) jb.Push(F(s, 10 * s), 1.6 + (s - 3) / 30.0);
        Check(jb.Sample(1.6 + 1.0 + 1e-6, out pose) && jb.ShownSeq == 33 && jb.Buffered <= 7, "late frames skipped, not replayed");
        jb.MarkEnded();
        Check(jb.Sample(7, out pose) && jb.ShownSeq == 39 && jb.Finished && jb.Underruns == 1, "ends on the last frame");
        jb.Reset();
        jb.Push(F(0, -1), 10);
        Check(jb.Sample(10, out pose) && Near(pose.Root.X, 390), "new transition: old pose holds until due");
        Check(jb.Sample(10.1001, out pose) && Near(pose.Root.X, -1), "new transition plays");

        // Joint binding by name.
        var bones = new Dictionary<string, string> { { "Hips", "Hips" }, { "Spine", "Spine" }, { "mixamorig:Head", "mixamorig:Head" }, { "Arm", "Arm" } };
        Func<string, string> find = name => { string b; return bones.TryGetValue(name, out b) ? b : null; };
        var missing = new List<string>();
        var bound = RsmtJointBinding.Resolve(new[] { "Hips", "Spine", "Head", "UpperArm_L", "ns:Arm" },
                                             new Dictionary<string, string> { { "Head", "mixamorig:Head" } }, true, find, missing);
        Check(bound[0] == "Hips" && bound[1] == "Spine" && bound[2] == "mixamorig:Head" && bound[3] == null && bound[4] == "Arm", "binding");
        Check(missing.Count == 1 && missing[0] == "UpperArm_L", "binding reports missing joints");

        FailoverSelfTest();

        Console.WriteLine("{\"selftest\": {\"checks\": " + checks + ", \"failures\": " + failures + "}}");
        return failures == 0 ? 0 : 1;
    }

    // ------------------------------------------------------------------ live run

    static Dictionary<string, string> Args(string[] args)
    {
        var d = new Dictionary<string, string>();
        for (int i = 1; i < args.Length; i++)
        {
            if (!args[i].StartsWith("--", StringComparison.Ordinal)) throw new ArgumentException("unexpected " + args[i]);
            string key = args[i].Substring(2);
            if (i + 1 < args.Length && !args[i + 1].StartsWith("--", StringComparison.Ordinal)) d[key] = args[++i];
            else d[key] = "true";
        }
        return d;
    }

    static string Get(Dictionary<string, string> d, string key, string fallback = null)
    {
        string v;
        if (d.TryGetValue(key, out v)) return v;
        if (fallback == null) throw new ArgumentException("--" + key + " is required");
        return fallback;
    }

    static string R(double x) { return x.ToString("R", CultureInfo.InvariantCulture); }

    static string PoseJson(RsmtFrame f)
    {
        var sb = new StringBuilder();
        sb.Append("{\"seq\":").Append(f.Seq).Append(",\"t\":").Append(R(f.T)).Append(",\"remaining\":").Append(f.Remaining);
        sb.Append(",\"root\":[").Append(R(f.Pose.Root.X)).Append(',').Append(R(f.Pose.Root.Y)).Append(',').Append(R(f.Pose.Root.Z)).Append("],\"rotations\":[");
        for (int j = 0; j < f.Pose.Rotations.Length; j++)
        {
            var q = f.Pose.Rotations[j];
            sb.Append(j > 0 ? "," : "").Append('[').Append(R(q.X)).Append(',').Append(R(q.Y)).Append(',').Append(R(q.Z)).Append(',').Append(R(q.W)).Append(']');
        }
        return sb.Append("]}").ToString();
    }

    static void Pump(RsmtStreamClient client, Stopwatch clock, Func<bool> done, double timeoutSeconds, Action each = null)
    {
        double deadline = clock.Elapsed.TotalSeconds + timeoutSeconds;
        while (!done())
        {
            if (clock.Elapsed.TotalSeconds > deadline) throw new TimeoutException("timed out waiting for the server");
            if (client.CloseInfo != null)
                throw new Exception("the stream closed: " + client.CloseInfo.CloseStatus + " " + client.CloseInfo.CloseReason);
            if (client.Dispatch(clock.Elapsed.TotalSeconds) == 0) Thread.Sleep(2);
            if (each != null) each();
        }
    }

    static int Run(string[] argv)
    {
        var a = Args(argv);
        string url = Get(a, "url"), apiKey = Get(a, "api-key", "");
        string context = File.ReadAllText(Get(a, "context")), target = File.ReadAllText(Get(a, "target"));
        string styleBvh = File.ReadAllText(Get(a, "style"));
        int frames = int.Parse(Get(a, "frames"), CultureInfo.InvariantCulture);
        long? seed = a.ContainsKey("seed") ? (long?)long.Parse(a["seed"], CultureInfo.InvariantCulture) : null;
        bool deterministic = a.ContainsKey("deterministic");
        bool binary = Get(a, "encoding", "json") == "binary";
        double delay = double.Parse(Get(a, "delay", "0.1"), CultureInfo.InvariantCulture);
        var clock = Stopwatch.StartNew();
        var output = new StringBuilder("{");

        // 1. Style registration over HTTP (retries 429/503).
        RsmtStyleInfo style;
        using (var http = new RsmtHttpClient(url, apiKey))
        {
            style = http.RegisterStyleAsync(styleBvh, "harness-style").Result;
            if (a.ContainsKey("style2"))  // a style from two clips, registered as one
            {
                var multi = http.RegisterStyleClipsAsync(new List<string> { styleBvh, File.ReadAllText(a["style2"]) },
                                                         "harness-two-clips").Result;
                output.Append("\"multi\":{\"style_id\":").Append(Json.Quote(multi.StyleId)).Append(",\"clips\":")
                      .Append(multi.Clips).Append(",\"frames\":").Append(multi.Frames).Append("},");
            }
        }
        output.Append("\"style_id\":").Append(Json.Quote(style.StyleId));

        using (var client = new RsmtStreamClient(new ClientWebSocketTransport(), delay))
        {
            // 2. Hello.
            client.ConnectAsync(url, apiKey, binary).Wait();
            Pump(client, clock, () => client.Hello != null, 30);
            var model = client.Hello.Model;
            output.Append(",\"hello\":{\"joints\":").Append(model.Joints.Length).Append(",\"fps\":").Append(R(model.Fps))
                  .Append(",\"units\":").Append(Json.Quote(model.Units)).Append(",\"encoding\":").Append(Json.Quote(client.Hello.Encoding))
                  .Append(",\"metres_per_unit\":").Append(R(client.MetresPerUnit)).Append('}');

            // 3. One transition, as fast as it is generated; every frame recorded in Unity axes.
            var recorded = new List<RsmtFrame>();
            RsmtMessage end = null, started = null;
            var errors = new List<string>();
            bool pong = false;
            client.ErrorReceived += m => errors.Add(m.Code + ": " + m.Text);
            client.MessageReceived += m =>
            {
                if (m.Kind == RsmtMessageKind.Pong) pong = true;
                if (m.Character != "cs1") return;
                if (m.Kind == RsmtMessageKind.Frame) recorded.Add(m.Frame);
                else if (m.Kind == RsmtMessageKind.End) end = m;
                else if (m.Kind == RsmtMessageKind.Started) started = m;
            };
            client.Start(new RsmtStartOptions
            {
                // Whole takes are cut to what hello's model reads, as RsmtCharacter does.
                Character = "cs1", ContextJson = RsmtMessages.BvhMotion(client.Cuts.Context(context)),
                TargetJson = RsmtMessages.BvhMotion(client.Cuts.Target(target)),
                Frames = frames, StyleId = style.StyleId, Seed = seed, Deterministic = deterministic, Pace = "asap",
            });
            Pump(client, clock, () => end != null || errors.Count > 0, 60);
            if (errors.Count > 0) throw new Exception("server error: " + errors[0]);
            client.Ping("harness");
            Pump(client, clock, () => pong, 30);
            output.Append(",\"started\":{\"slot\":").Append(started.Slot).Append(",\"frames\":").Append(started.Frames).Append('}');
            output.Append(",\"end\":{\"reason\":").Append(Json.Quote(end.Reason)).Append(",\"frames\":").Append(end.Frames).Append('}');
            output.Append(",\"pong\":").Append(pong ? "true" : "false");
            output.Append(",\"frames\":[").Append(string.Join(",", recorded.Select(PoseJson))).Append(']');

            // 4. A start to a place and facing (TargetAtJson, the model's units and axes): the last frame recorded.
            if (a.ContainsKey("target-at"))
            {
                var at = a["target-at"].Split(',').Select(x => double.Parse(x, CultureInfo.InvariantCulture)).ToArray();
                if (at.Length != 3) throw new ArgumentException("--target-at takes x,z,yaw");
                int atFrames = int.Parse(Get(a, "target-at-frames", Get(a, "frames")), CultureInfo.InvariantCulture);
                RsmtFrame last = null;
                int count = 0;
                RsmtMessage end3 = null;
                client.MessageReceived += m =>
                {
                    if (m.Character != "cs3") return;
                    if (m.Kind == RsmtMessageKind.Frame)
                    {
                        count++;
                        last = m.Frame;
                    }
                    else if (m.Kind == RsmtMessageKind.End) end3 = m;
                };
                client.Start(new RsmtStartOptions
                {
                    Character = "cs3", ContextJson = RsmtMessages.BvhMotion(client.Cuts.Context(context)),
                    TargetAtJson = RsmtMessages.TargetAt(at[0], at[1], at[2]),
                    Frames = atFrames, StyleId = style.StyleId, Seed = seed, Pace = "asap",
                });
                Pump(client, clock, () => end3 != null || errors.Count > 0, 60);
                if (errors.Count > 0) throw new Exception("server error: " + errors[0]);
                output.Append(",\"target_at\":{\"received\":").Append(count).Append(",\"end\":{\"reason\":")
                      .Append(Json.Quote(end3.Reason)).Append(",\"frames\":").Append(end3.Frames).Append("},\"last\":")
                      .Append(last == null ? "null" : PoseJson(last)).Append('}');
            }

            // 5. Retarget mid-way, in real time, played through the jitter buffer.
            if (a.ContainsKey("retarget"))
            {
                string newTarget = File.ReadAllText(a["retarget"]);
                int after = int.Parse(Get(a, "retarget-after", "5"), CultureInfo.InvariantCulture);
                int newFrames = int.Parse(Get(a, "retarget-frames", "0"), CultureInfo.InvariantCulture);
                int received = 0, fromSeq = -1, shownLast = -1, samples = 0;
                bool sent = false, monotonic = true;
                RsmtMessage end2 = null;
                client.MessageReceived += m =>
                {
                    if (m.Character != "cs2") return;
                    if (m.Kind == RsmtMessageKind.Frame)
                    {
                        received++;
                        if (!sent && m.Frame.Seq >= after)
                        {
                            client.Retarget("cs2", RsmtMessages.BvhMotion(newTarget), newFrames);
                            sent = true;
                        }
                    }
                    else if (m.Kind == RsmtMessageKind.Retargeted) fromSeq = m.FromSeq;
                    else if (m.Kind == RsmtMessageKind.End) end2 = m;
                };
                client.Start(new RsmtStartOptions
                {
                    Character = "cs2", ContextJson = RsmtMessages.BvhMotion(context), TargetJson = RsmtMessages.BvhMotion(target),
                    Frames = frames, StyleId = style.StyleId, Seed = seed, Deterministic = deterministic, Pace = "realtime",
                });
                var buffer = client.Buffer("cs2");
                Action sample = () =>
                {
                    RsmtPose shown;
                    if (client.TrySample("cs2", clock.Elapsed.TotalSeconds, out shown))
                    {
                        samples++;
                        if (buffer.ShownSeq >= 0 && buffer.ShownSeq < shownLast) monotonic = false;
                        if (buffer.ShownSeq >= 0) shownLast = buffer.ShownSeq;
                    }
                };
                Pump(client, clock, () => (end2 != null && buffer.Finished) || errors.Count > 0, 60, sample);
                if (errors.Count > 0) throw new Exception("server error: " + errors[0]);
                output.Append(",\"retarget\":{\"from_seq\":").Append(fromSeq).Append(",\"received\":").Append(received)
                      .Append(",\"end_frames\":").Append(end2.Frames).Append(",\"reason\":").Append(Json.Quote(end2.Reason))
                      .Append(",\"shown_last\":").Append(shownLast).Append(",\"samples\":").Append(samples)
                      .Append(",\"monotonic\":").Append(monotonic ? "true" : "false").Append(",\"underruns\":").Append(buffer.Underruns).Append('}');
            }
        }
        output.Append('}');
        File.WriteAllText(Get(a, "out"), output.ToString());
        Console.WriteLine("{\"ok\": true, \"seconds\": " + R(clock.Elapsed.TotalSeconds) + "}");
        return 0;
    }

    static int RunFailover(string[] argv)
    {
        var a = Args(argv);
        string url = Get(a, "url"), apiKey = Get(a, "api-key", "");
        string context = File.ReadAllText(Get(a, "context"));
        var targets = new[] { File.ReadAllText(Get(a, "target")), File.ReadAllText(Get(a, "target2", Get(a, "target"))) };
        string styleBvh = File.ReadAllText(Get(a, "style"));
        int frames = int.Parse(Get(a, "frames"), CultureInfo.InvariantCulture);
        int count = int.Parse(Get(a, "characters", "2"), CultureInfo.InvariantCulture);
        int killAfter = int.Parse(Get(a, "kill-after", "10"), CultureInfo.InvariantCulture);
        var clock = Stopwatch.StartNew();
        var recorded = new Dictionary<string, List<RsmtFrame>>();
        var ends = new Dictionary<string, RsmtMessage>();
        var resumed = new Dictionary<string, int>();  // frames recorded before the resumed start
        var errors = new List<string>();
        var lost = new List<int>();
        bool killed = false;
        var output = new StringBuilder("{");
        using (var client = new RsmtStreamClient(new ClientWebSocketTransport()))
        {
            client.Failover = a.ContainsKey("failover");
            client.ReconnectAttempts = int.Parse(Get(a, "attempts", "40"), CultureInfo.InvariantCulture);
            client.MaxBackoffSeconds = 1;
            client.ConnectAsync(url, apiKey, Get(a, "encoding", "binary") == "binary").Wait();
            Pump(client, clock, () => client.Hello != null, 30);
            var style = client.RegisterStyleAsync(styleBvh, "harness-failover").Result;
            output.Append("\"style_id\":").Append(Json.Quote(style.StyleId));
            client.ErrorReceived += m => errors.Add(m.Character + " " + m.Code + ": " + m.Text);
            client.ConnectionLost += (status, reason) => lost.Add(status);
            client.MessageReceived += m =>
            {
                if (m.Kind == RsmtMessageKind.Frame && m.Frame.Character != null && recorded.ContainsKey(m.Frame.Character))
                {
                    recorded[m.Frame.Character].Add(m.Frame);
                    if (!killed && recorded["f0"].Count >= killAfter)
                    {
                        killed = true;
                        Console.WriteLine("{\"kill\": true}");
                        Console.Out.Flush();
                    }
                }
                else if (m.Kind == RsmtMessageKind.End && m.Character != null) ends[m.Character] = m;
                else if (m.Kind == RsmtMessageKind.Started && m.Resumed) resumed[m.Character] = recorded[m.Character].Count;
            };
            for (int i = 0; i < count; i++)
            {
                string cid = "f" + i;
                recorded[cid] = new List<RsmtFrame>();
                resumed[cid] = -1;
                client.Start(new RsmtStartOptions
                {
                    Character = cid, ContextJson = RsmtMessages.BvhMotion(context), TargetJson = RsmtMessages.BvhMotion(targets[i % 2]),
                    Frames = frames, StyleId = style.StyleId, Seed = i, Pace = "realtime", ExactArrival = true,
                });
            }
            double deadline = clock.Elapsed.TotalSeconds + double.Parse(Get(a, "timeout", "120"), CultureInfo.InvariantCulture);
            while (ends.Count < count && errors.Count == 0 && client.CloseInfo == null && clock.Elapsed.TotalSeconds < deadline)
            {
                if (client.Dispatch(clock.Elapsed.TotalSeconds) == 0) Thread.Sleep(2);
            }
            output.Append(",\"resumes\":").Append(client.FailoverState.Resumes)
                  .Append(",\"reregistrations\":").Append(client.FailoverState.Reregistrations);
            output.Append(",\"lost\":[").Append(string.Join(",", lost)).Append(']');
            output.Append(",\"closed\":").Append(client.CloseInfo == null ? "null" : client.CloseInfo.CloseStatus.ToString(CultureInfo.InvariantCulture));
            output.Append(",\"timed_out\":").Append(ends.Count < count && errors.Count == 0 && client.CloseInfo == null ? "true" : "false");
            output.Append(",\"errors\":[").Append(string.Join(",", errors.Select(e => Json.Quote(e)))).Append(']');
            output.Append(",\"characters\":{");
            int k = 0;
            foreach (var cid in recorded.Keys)
            {
                RsmtMessage end;
                ends.TryGetValue(cid, out end);
                output.Append(k++ > 0 ? "," : "").Append(Json.Quote(cid)).Append(":{\"resumed_at\":").Append(resumed[cid]);
                output.Append(",\"end\":").Append(end == null ? "null" : "{\"reason\":" + Json.Quote(end.Reason) + ",\"frames\":" + end.Frames + "}");
                output.Append(",\"frames\":[").Append(string.Join(",", recorded[cid].Select(PoseJson))).Append("]}");
            }
            output.Append('}');
        }
        output.Append('}');
        File.WriteAllText(Get(a, "out"), output.ToString());
        Console.WriteLine("{\"ok\": true, \"seconds\": " + R(clock.Elapsed.TotalSeconds) + "}");
        return 0;
    }

    /// <summary>cut --what context|target|style --fps F --context-frames N --style-max M --in A.bvh --out B.bvh</summary>
    static int Cut(string[] argv)
    {
        var a = Args(argv);
        var cutter = new RsmtMotionCutter(new RsmtMotionLimits
        {
            Fps = double.Parse(Get(a, "fps"), CultureInfo.InvariantCulture),
            ContextFrames = int.Parse(Get(a, "context-frames"), CultureInfo.InvariantCulture),
            StyleMaxFrames = int.Parse(Get(a, "style-max"), CultureInfo.InvariantCulture),
        });
        cutter.Notice += note => Console.Error.WriteLine("notice: " + note);
        string bvh = File.ReadAllText(Get(a, "in")), what = Get(a, "what");
        if (what == "style") cutter.Style(bvh);  // twice: the notice comes once
        string cut = what == "context" ? cutter.Context(bvh) : what == "target" ? cutter.Target(bvh) : cutter.Style(bvh);
        File.WriteAllText(Get(a, "out"), cut);
        Console.WriteLine("{\"frames\": " + RsmtBvhText.FrameCount(cut) + ", \"bytes\": " + Encoding.UTF8.GetByteCount(cut) + "}");
        return 0;
    }

    static int Main(string[] args)
    {
        Thread.CurrentThread.CurrentCulture = CultureInfo.InvariantCulture;
        if (args.Length >= 1 && args[0] == "selftest") return SelfTest();
        if (args.Length >= 1 && args[0] == "cut") return Cut(args);
        if (args.Length >= 1 && (args[0] == "run" || args[0] == "failover"))
        {
            try { return args[0] == "run" ? Run(args) : RunFailover(args); }
            catch (Exception e)
            {
                Console.Error.WriteLine("harness: " + e);
                return 1;
            }
        }
        Console.Error.WriteLine("usage: RsmtHarness.exe selftest | run --url URL --context A.bvh --target B.bvh --style S.bvh --frames N --out FILE [...]");
        return 2;
    }
}
