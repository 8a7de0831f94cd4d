// The RSMT WebSocket protocol v1 (docs/protocol.md): hello, frames (JSON or binary float32 laid out as
// hello.frame_layout declares), the other server messages, and the client messages.
using System;
using System.Collections.Generic;
using System.Globalization;
using System.Text;

namespace Rsmt.Link
{
    public sealed class RsmtJoint
    {
        public string Name;
        public int Parent;
        public RsmtVec3 Offset;  // in the parent's frame, model units
    }

    public sealed class RsmtModelInfo
    {
        public string Name = "";
        public string Version = "";
        public double Fps = 30;
        public int ContextFrames;
        public int MaxTransitionFrames;
        public int StyleMinFrames, StyleMaxFrames;  // style_clip_frames (0 when the server does not say)
        public RsmtJoint[] Joints = new RsmtJoint[0];
        public string Units = "cm";
        public string UpAxis = "y";
        public string Handedness = "right";

        public string[] JointNames
        {
            get
            {
                var names = new string[Joints.Length];
                for (int i = 0; i < names.Length; i++) names[i] = Joints[i].Name;
                return names;
            }
        }

        public static RsmtModelInfo FromJson(JsonValue model)
        {
            var skeleton = model != null ? model.Get("skeleton") : null;
            var joints = skeleton != null ? skeleton.Get("joints") : null;
            if (joints == null || joints.Type != JsonType.Array || joints.Array.Count == 0)
                throw new RsmtProtocolException("model.skeleton.joints missing");
            var info = new RsmtModelInfo
            {
                Name = model.GetString("name", ""),
                Version = model.GetString("version", ""),
                Fps = model.GetNumber("fps", 30),
                ContextFrames = model.GetInt("context_frames", 0),
                MaxTransitionFrames = model.GetInt("max_transition_frames", 0),
                Units = skeleton.GetString("units", "cm"),
                UpAxis = skeleton.GetString("up_axis", "y"),
                Handedness = skeleton.GetString("handedness", "right"),
                Joints = new RsmtJoint[joints.Array.Count],
            };
            var style = model.Get("style_clip_frames");
            if (style != null && style.Type == JsonType.Object)
            {
                info.StyleMinFrames = style.GetInt("min", 0);
                info.StyleMaxFrames = style.GetInt("max", 0);
            }
            if (!(info.Fps > 0)) throw new RsmtProtocolException("model.fps must be positive");
            for (int i = 0; i < joints.Array.Count; i++)
            {
                var j = joints.Array[i];
                var offset = j.Get("offset");
                if (offset == null || offset.Type != JsonType.Array || offset.Array.Count != 3)
                    throw new RsmtProtocolException("joint " + i + " has no [x, y, z] offset");
                int parent = j.GetInt("parent", -1);
                if (parent >= i) throw new RsmtProtocolException("joints are not in topological order");
                info.Joints[i] = new RsmtJoint
                {
                    Name = j.GetString("name", ""),
                    Parent = parent,
                    Offset = new RsmtVec3(offset.Array[0].Number, offset.Array[1].Number, offset.Array[2].Number),
                };
            }
            return info;
        }
    }

    /// <summary>Where each field of a binary frame sits, in float32 units (hello.frame_layout).</summary>
    public sealed class RsmtFrameLayout
    {
        public int FloatsPerFrame;
        public int Joints;
        public int Slot = -1, Seq = -1, T = -1, RootPosition = -1, Rotations = -1, Remaining = -1;

        public int BytesPerFrame { get { return 4 * FloatsPerFrame; } }

        /// <summary>
        /// The layout of a model with another joint count (started.floats_per_frame): fields after the rotations
        /// move by the difference, the others stay where hello put them.
        /// </summary>
        public RsmtFrameLayout Resized(int floatsPerFrame)
        {
            int delta = floatsPerFrame - FloatsPerFrame;
            if (delta == 0) return this;
            if (delta % 4 != 0 || Joints + delta / 4 < 1)
                throw new RsmtProtocolException("floats_per_frame " + floatsPerFrame + " does not fit this layout");
            var l = (RsmtFrameLayout)MemberwiseClone();
            l.FloatsPerFrame = floatsPerFrame;
            l.Joints = Joints + delta / 4;
            if (Slot > Rotations) l.Slot += delta;
            if (Seq > Rotations) l.Seq += delta;
            if (T > Rotations) l.T += delta;
            if (RootPosition > Rotations) l.RootPosition += delta;
            if (Remaining > Rotations) l.Remaining += delta;
            return l;
        }

        public static RsmtFrameLayout FromJson(JsonValue layout, int joints)
        {
            if (layout == null || layout.Type != JsonType.Object) throw new RsmtProtocolException("frame_layout missing");
            string encoding = layout.GetString("encoding", "");
            if (encoding != "float32-le")
                throw new RsmtProtocolException("frame_layout.encoding is '" + encoding + "'; this client reads float32-le");
            var l = new RsmtFrameLayout { FloatsPerFrame = layout.GetInt("floats_per_frame", 0), Joints = joints };
            var fields = layout.Get("fields");
            if (l.FloatsPerFrame <= 0 || fields == null || fields.Type != JsonType.Array)
                throw new RsmtProtocolException("frame_layout lacks fields");
            foreach (var f in fields.Array)
            {
                string name = f.GetString("name", "");
                int offset = f.GetInt("offset", -1), count = f.GetInt("count", -1);
                if (offset < 0 || count < 0 || offset + count > l.FloatsPerFrame)
                    throw new RsmtProtocolException("frame_layout field '" + name + "' lies outside the frame");
                int expected;
                switch (name)
                {
                    case "slot": l.Slot = offset; expected = 1; break;
                    case "seq": l.Seq = offset; expected = 1; break;
                    case "t": l.T = offset; expected = 1; break;
                    case "root_position": l.RootPosition = offset; expected = 3; break;
                    case "rotations": l.Rotations = offset; expected = 4 * joints; break;
                    case "remaining": l.Remaining = offset; expected = 1; break;
                    default: continue;  // fields added by later servers are skipped
                }
                if (count != expected)
                    throw new RsmtProtocolException("frame_layout field '" + name + "' holds " + count + " floats, expected " + expected);
            }
            if (l.Slot < 0 || l.Seq < 0 || l.T < 0 || l.RootPosition < 0 || l.Rotations < 0 || l.Remaining < 0)
                throw new RsmtProtocolException("frame_layout lacks one of slot, seq, t, root_position, rotations, remaining");
            return l;
        }
    }

    public sealed class RsmtHello
    {
        public int Protocol;
        public RsmtModelInfo Model;
        public RsmtFrameLayout Layout;
        public string Encoding = "json";
        public int MaxCharacters, SendQueueFrames, MaxMessageBytes;
        public double IdleTimeoutSeconds;

        public static RsmtHello FromJson(JsonValue json)
        {
            if (json.GetString("type", "") != "hello") throw new RsmtProtocolException("the first message is not hello");
            var h = new RsmtHello { Protocol = json.GetInt("protocol", 0) };
            if (h.Protocol != 1) throw new RsmtProtocolException("server speaks protocol " + h.Protocol + "; this client speaks 1");
            h.Model = RsmtModelInfo.FromJson(json.Get("model"));
            h.Layout = RsmtFrameLayout.FromJson(json.Get("frame_layout"), h.Model.Joints.Length);
            h.Encoding = json.GetString("encoding", "json");
            var limits = json.Get("limits");
            if (limits != null)
            {
                h.MaxCharacters = limits.GetInt("max_characters", 0);
                h.SendQueueFrames = limits.GetInt("send_queue_frames", 0);
                h.IdleTimeoutSeconds = limits.GetNumber("idle_timeout_s", 0);
                h.MaxMessageBytes = limits.GetInt("max_message_bytes", 0);
            }
            return h;
        }
    }

    public sealed class RsmtFrame
    {
        public string Character;  // null for a binary frame whose slot has no `started` yet
        public int Slot = -1;
        public int Seq;
        public double T;          // seconds since the start: (seq + 1) / fps
        public int Remaining;
        public RsmtPose Pose;
    }

    public enum RsmtMessageKind { Hello, Started, Frame, End, Retargeted, StyleChanged, Error, Pong, Unknown }

    public sealed class RsmtMessage
    {
        public RsmtMessageKind Kind = RsmtMessageKind.Unknown;
        public string Type = "";
        public string Character;
        public int Slot = -1;
        public RsmtFrame Frame;     // Kind == Frame
        public int Frames;          // started: frames to come; end: frames sent
        public double Fps;          // started
        public int FromSeq = -1;    // retargeted / style_changed
        public string StyleId;      // started / style_changed
        public string Reason;       // end
        public string Code;         // error
        public string Text;         // error message
        public bool Resumed;        // started: a character resumed on a new connection (RsmtStreamClient.Failover)
        public JsonValue Json;      // the whole text message (null for binary frames)
    }

    public sealed class RsmtProtocolException : Exception
    {
        public RsmtProtocolException(string message) : base(message) { }
    }

    /// <summary>The protocol state of one connection: hello first, then slot to character for binary frames.</summary>
    public sealed class RsmtSession
    {
        readonly Dictionary<int, string> slots = new Dictionary<int, string>();
        readonly Dictionary<int, RsmtFrameLayout> slotLayouts = new Dictionary<int, RsmtFrameLayout>();  // other models

        public RsmtHello Hello { get; private set; }
        public bool HasHello { get { return Hello != null; } }
        public int Joints { get { return Hello == null ? 0 : Hello.Model.Joints.Length; } }

        public RsmtMessage HandleText(string text)
        {
            JsonValue json;
            try { json = Json.Parse(text); }
            catch (JsonException e) { throw new RsmtProtocolException("invalid JSON from the server: " + e.Message); }
            if (json.Type != JsonType.Object) throw new RsmtProtocolException("a message must be a JSON object");
            var m = new RsmtMessage
            {
                Json = json,
                Type = json.GetString("type", ""),
                Character = json.GetString("character", null),
                Slot = json.GetInt("slot", -1),
            };
            m.Kind = KindOf(m.Type);
            if (Hello == null)
            {
                if (m.Kind != RsmtMessageKind.Hello) throw new RsmtProtocolException("expected hello first, got '" + m.Type + "'");
                Hello = RsmtHello.FromJson(json);
                return m;
            }
            switch (m.Kind)
            {
                case RsmtMessageKind.Started:
                    slots[m.Slot] = m.Character;
                    int fpf = json.GetInt("floats_per_frame", Hello.Layout.FloatsPerFrame);
                    if (fpf != Hello.Layout.FloatsPerFrame) slotLayouts[m.Slot] = Hello.Layout.Resized(fpf);
                    else slotLayouts.Remove(m.Slot);
                    m.Frames = json.GetInt("frames", 0);
                    m.Fps = json.GetNumber("fps", Hello.Model.Fps);
                    m.StyleId = json.GetString("style_id", null);
                    break;
                case RsmtMessageKind.Frame:
                    m.Frame = FrameFromJson(json, LayoutOf(m.Slot).Joints);
                    break;
                case RsmtMessageKind.End:
                    m.Frames = json.GetInt("frames", 0);
                    m.Reason = json.GetString("reason", "");
                    break;
                case RsmtMessageKind.Retargeted:
                case RsmtMessageKind.StyleChanged:
                    m.FromSeq = json.GetInt("from_seq", -1);
                    m.StyleId = json.GetString("style_id", null);
                    break;
                case RsmtMessageKind.Error:
                    m.Code = json.GetString("code", "");
                    m.Text = json.GetString("message", "");
                    break;
            }
            return m;
        }

        public RsmtMessage HandleBinary(byte[] data, int count)
        {
            if (Hello == null) throw new RsmtProtocolException("a binary message before hello");
            int slotAt = 4 * (Hello.Layout.Slot + 1);
            var layout = count >= slotAt ? LayoutOf((int)Math.Round(ReadFloat32LE(data, slotAt - 4))) : Hello.Layout;
            var frame = DecodeBinary(data, count, layout, layout.Joints);
            string character;
            if (slots.TryGetValue(frame.Slot, out character)) frame.Character = character;
            return new RsmtMessage { Kind = RsmtMessageKind.Frame, Type = "frame", Character = frame.Character, Slot = frame.Slot, Frame = frame };
        }

        /// <summary>The binary layout of a slot's character (hello's, unless it runs another model).</summary>
        public RsmtFrameLayout LayoutOf(int slot)
        {
            RsmtFrameLayout layout;
            return slotLayouts.TryGetValue(slot, out layout) ? layout : Hello.Layout;
        }

        static RsmtMessageKind KindOf(string type)
        {
            switch (type)
            {
                case "hello": return RsmtMessageKind.Hello;
                case "started": return RsmtMessageKind.Started;
                case "frame": return RsmtMessageKind.Frame;
                case "end": return RsmtMessageKind.End;
                case "retargeted": return RsmtMessageKind.Retargeted;
                case "style_changed": return RsmtMessageKind.StyleChanged;
                case "error": return RsmtMessageKind.Error;
                case "pong": return RsmtMessageKind.Pong;
                default: return RsmtMessageKind.Unknown;
            }
        }

        public static RsmtFrame FrameFromJson(JsonValue json, int joints)
        {
            var pose = json.Get("pose");
            var root = pose != null ? pose.Get("root_position") : null;
            var rots = pose != null ? pose.Get("rotations") : null;
            if (root == null || root.Type != JsonType.Array || root.Array.Count != 3)
                throw new RsmtProtocolException("frame without pose.root_position");
            if (rots == null || rots.Type != JsonType.Array || rots.Array.Count != joints)
                throw new RsmtProtocolException("frame pose.rotations must hold " + joints + " quaternions");
            // The server's numbers are float32 written as the shortest text that reads back to them: rounding to
            // float32 here gives exactly the values a binary frame carries.
            var p = new RsmtPose(joints) { Root = new RsmtVec3(F32(root.Array[0]), F32(root.Array[1]), F32(root.Array[2])) };
            for (int j = 0; j < joints; j++)
            {
                var q = rots.Array[j];
                if (q.Type != JsonType.Array || q.Array.Count != 4) throw new RsmtProtocolException("a rotation is not [x, y, z, w]");
                p.Rotations[j] = new RsmtQuat(F32(q.Array[0]), F32(q.Array[1]), F32(q.Array[2]), F32(q.Array[3]));
            }
            return new RsmtFrame
            {
                Character = json.GetString("character", null),
                Slot = json.GetInt("slot", -1),
                Seq = json.GetInt("seq", 0),
                T = (float)json.GetNumber("t", 0),
                Remaining = json.GetInt("remaining", 0),
                Pose = p,
            };
        }

        static double F32(JsonValue v)
        {
            if (v.Type != JsonType.Number) throw new RsmtProtocolException("a pose value is not a number");
            return (float)v.Number;
        }

        /// <summary>A little-endian float32, whatever the machine's byte order.</summary>
        public static float ReadFloat32LE(byte[] data, int offset)
        {
            if (BitConverter.IsLittleEndian) return BitConverter.ToSingle(data, offset);
            var tmp = new byte[] { data[offset + 3], data[offset + 2], data[offset + 1], data[offset] };
            return BitConverter.ToSingle(tmp, 0);
        }

        public static RsmtFrame DecodeBinary(byte[] data, int count, RsmtFrameLayout layout, int joints)
        {
            if (count != layout.BytesPerFrame)
                throw new RsmtProtocolException("binary frame of " + count + " bytes; the layout says " + layout.BytesPerFrame);
            var p = new RsmtPose(joints)
            {
                Root = new RsmtVec3(ReadFloat32LE(data, 4 * layout.RootPosition), ReadFloat32LE(data, 4 * (layout.RootPosition + 1)),
                                    ReadFloat32LE(data, 4 * (layout.RootPosition + 2))),
            };
            for (int j = 0; j < joints; j++)
            {
                int o = 4 * (layout.Rotations + 4 * j);
                p.Rotations[j] = new RsmtQuat(ReadFloat32LE(data, o), ReadFloat32LE(data, o + 4), ReadFloat32LE(data, o + 8),
                                              ReadFloat32LE(data, o + 12));
            }
            return new RsmtFrame
            {
                Slot = (int)Math.Round(ReadFloat32LE(data, 4 * layout.Slot)),
                Seq = (int)Math.Round(ReadFloat32LE(data, 4 * layout.Seq)),
                T = ReadFloat32LE(data, 4 * layout.T),
                Remaining = (int)Math.Round(ReadFloat32LE(data, 4 * layout.Remaining)),
                Pose = p,
            };
        }
    }

    /// <summary>Options of a `start` message. Motions are payload JSON from RsmtMessages.BvhMotion / PoseMotion.</summary>
    public sealed class RsmtStartOptions
    {
        public string Character;
        public string ContextJson;
        public string TargetJson;    // one of TargetJson / TargetAtJson
        public string TargetAtJson;  // a place and facing (RsmtMessages.TargetAt): the server picks the pose, arrives exactly
        public int Frames = 30;
        public string StyleId;       // one of StyleId / StyleJson
        public string StyleJson;
        public long? Seed;
        public bool Deterministic;
        public bool ExactArrival;         // bend the last frames so the arrival frame equals the target pose
        public bool Retargeted;           // a resume of a character retargeted mid-motion (failover sets it)
        public double? StyleStrength;     // 0 to 4: the style moved from the model's neutral style by this factor; null: the server's (not sent)
        public string Pace = "realtime";  // or "asap"
        public string Model;              // a model of GET /v1/models; null: the default
        public string RequestId;
    }

    /// <summary>Client messages as JSON text.</summary>
    public static class RsmtMessages
    {
        public static string BvhMotion(string bvhText)
        {
            return "{\"bvh\":" + Json.Quote(bvhText) + "}";
        }

        /// <summary>
        /// A target given as a place and a facing (the start's `target_at`), in the model's units and axes: the root
        /// arrives over (x, z) facing yaw degrees about +Y (0: +Z, 90: +X). From Unity: x = -position.x / s,
        /// z = position.z / s (s = metres per model unit), yaw = -eulerAngles.y.
        /// </summary>
        public static string TargetAt(double x, double z, double yaw)
        {
            return "{\"x\":" + Json.Number(x) + ",\"z\":" + Json.Number(z) + ",\"yaw\":" + Json.Number(yaw) + "}";
        }

        /// <summary>Root positions and local rotations in model units and axes (convert Unity poses back first).</summary>
        public static string PoseMotion(IList<RsmtPose> poses, double? fps = null)
        {
            var sb = new StringBuilder("{\"root_positions\":[");
            for (int i = 0; i < poses.Count; i++)
            {
                if (i > 0) sb.Append(',');
                var r = poses[i].Root;
                sb.Append('[').Append(Json.Number(r.X)).Append(',').Append(Json.Number(r.Y)).Append(',').Append(Json.Number(r.Z)).Append(']');
            }
            sb.Append("],\"rotations\":[");
            for (int i = 0; i < poses.Count; i++)
            {
                if (i > 0) sb.Append(',');
                sb.Append('[');
                var rots = poses[i].Rotations;
                for (int j = 0; j < rots.Length; j++)
                {
                    if (j > 0) sb.Append(',');
                    sb.Append('[').Append(Json.Number(rots[j].X)).Append(',').Append(Json.Number(rots[j].Y)).Append(',')
                      .Append(Json.Number(rots[j].Z)).Append(',').Append(Json.Number(rots[j].W)).Append(']');
                }
                sb.Append(']');
            }
            sb.Append(']');
            if (fps.HasValue) sb.Append(",\"fps\":").Append(Json.Number(fps.Value));
            return sb.Append('}').ToString();
        }

        public static string Start(RsmtStartOptions o)
        {
            var sb = new StringBuilder("{\"type\":\"start\"");
            if (!string.IsNullOrEmpty(o.Character)) sb.Append(",\"character\":").Append(Json.Quote(o.Character));
            sb.Append(",\"context\":").Append(o.ContextJson);
            if (!string.IsNullOrEmpty(o.TargetAtJson)) sb.Append(",\"target_at\":").Append(o.TargetAtJson);
            else sb.Append(",\"target\":").Append(o.TargetJson);
            sb.Append(",\"frames\":").Append(o.Frames.ToString(CultureInfo.InvariantCulture));
            if (!string.IsNullOrEmpty(o.StyleId)) sb.Append(",\"style_id\":").Append(Json.Quote(o.StyleId));
            else sb.Append(",\"style\":").Append(o.StyleJson);
            if (o.Seed.HasValue) sb.Append(",\"seed\":").Append(o.Seed.Value.ToString(CultureInfo.InvariantCulture));
            sb.Append(",\"deterministic\":").Append(o.Deterministic ? "true" : "false");
            if (o.ExactArrival) sb.Append(",\"exact_arrival\":true");
            if (o.Retargeted) sb.Append(",\"retargeted\":true");
            if (o.StyleStrength.HasValue) sb.Append(",\"style_strength\":").Append(Json.Number(o.StyleStrength.Value));
            sb.Append(",\"pace\":").Append(Json.Quote(o.Pace));
            if (!string.IsNullOrEmpty(o.Model)) sb.Append(",\"model\":").Append(Json.Quote(o.Model));
            if (!string.IsNullOrEmpty(o.RequestId)) sb.Append(",\"request_id\":").Append(Json.Quote(o.RequestId));
            return sb.Append('}').ToString();
        }

        /// <summary>targetJson null: frames only; frames &lt;= 0: target only.</summary>
        public static string Retarget(string character, string targetJson, int frames)
        {
            var sb = new StringBuilder("{\"type\":\"retarget\",\"character\":").Append(Json.Quote(character));
            if (targetJson != null) sb.Append(",\"target\":").Append(targetJson);
            if (frames > 0) sb.Append(",\"frames\":").Append(frames.ToString(CultureInfo.InvariantCulture));
            return sb.Append('}').ToString();
        }

        public static string Style(string character, string styleId)
        {
            return "{\"type\":\"style\",\"character\":" + Json.Quote(character) + ",\"style_id\":" + Json.Quote(styleId) + "}";
        }

        public static string Cancel(string character)
        {
            return "{\"type\":\"cancel\",\"character\":" + Json.Quote(character) + "}";
        }

        public static string Ping(string id)
        {
            return "{\"type\":\"ping\",\"id\":" + Json.Quote(id) + "}";
        }
    }
}
