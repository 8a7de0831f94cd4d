// Failover that resumes, without I/O (RsmtStreamClient.Failover = true does the I/O): what to resend when the
// connection is lost. It keeps, per live character, its start as it stands now (target and frames of later
// retargets, style of later style changes), the last context_frames poses received (model axes) and how many
// frames were delivered. After a reconnection ResumeMessages() gives one start per live character whose context
// is the poses received last, with the same target, style, pace and model and the frames still to come (and
// "retargeted" when its target changed mid-motion); the
// new frames are renumbered on from the count delivered, so the game sees one continuous transition.
// Mirrors clients/python/rsmt_client/stream_failover.py.
using System.Collections.Generic;

namespace Rsmt.Link
{
    /// <summary>What the stream client does with one received message (see RsmtFailover.Received).</summary>
    public sealed class RsmtFailoverAction
    {
        public bool Deliver = true;      // false: swallow it (its style is being registered again, or Resend replaces it)
        public string RegisterStyleId;   // register this style's clip again, then send Resend (null: just send it)
        public string Resend;
    }

    public sealed class RsmtFailover
    {
        sealed class Character
        {
            public RsmtStartOptions Start;         // as it stands now
            public readonly Queue<RsmtPose> Recent = new Queue<RsmtPose>();  // model axes
            public int Delivered, Base, Remaining;
            public int RetargetFrames = -1, RetargetFrom = -1;  // a retarget's frame count not yet seen in a frame
            public bool AwaitingStart = true, Resent, Cancelled;
            public bool Retargeted;                // given a new target after its start: a resume says so
            public string LastStart, LastStyle;    // the start (or resume) and style messages sent last
            public RsmtStartOptions LastResume;    // the options of the resume sent last
            public int Reregistered;
        }

        /// <summary>A registered clip: its BVH text and name, to register it again on unknown_style.</summary>
        public sealed class StyleClip
        {
            public string Bvh, Name;
        }

        readonly Dictionary<string, Character> characters = new Dictionary<string, Character>();
        readonly Dictionary<string, StyleClip> styles = new Dictionary<string, StyleClip>();

        public int ContextFrames = 10;
        public double Fps = 30;
        public int Joints;
        /// <summary>Reconnections that resumed at least one character.</summary>
        public int Resumes { get; private set; }
        /// <summary>Styles registered again after unknown_style.</summary>
        public int Reregistrations { get; private set; }

        /// <summary>Resuming after these close codes would only repeat the failure (the client's own faults).</summary>
        public static bool Resumable(int closeStatus)
        {
            return closeStatus != 1003 && closeStatus != 1007 && closeStatus != 1008 && closeStatus != 1009;
        }

        public void SetModel(RsmtModelInfo model)
        {
            if (model.ContextFrames > 0) ContextFrames = model.ContextFrames;
            Fps = model.Fps;
            Joints = model.Joints.Length;
        }

        public bool Live
        {
            get
            {
                foreach (var c in characters.Values) if (!c.Cancelled) return true;
                return false;
            }
        }

        public bool Tracks(string character) { return character != null && characters.ContainsKey(character); }

        public void RememberStyle(string styleId, string bvhText, string name)
        {
            styles[styleId] = new StyleClip { Bvh = bvhText, Name = name };
        }

        public StyleClip Style(string styleId)
        {
            StyleClip clip;
            return styleId != null && styles.TryGetValue(styleId, out clip) ? clip : null;
        }

        // ------------------------------------------------------------------ what the caller sends
        public void SentStart(RsmtStartOptions o, string text)
        {
            var c = new Character { Start = Copy(o), Remaining = o.Frames, LastStart = text };
            characters[o.Character] = c;
        }

        public void SentRetarget(string character, string targetJson, int frames)
        {
            var c = Get(character);
            if (c == null) return;
            if (targetJson != null)
            {
                c.Start.TargetJson = targetJson;
                c.Start.TargetAtJson = null;  // a pose now: a start names one target or the other
                c.Retargeted = true;
            }
            if (frames > 0)
            {
                c.RetargetFrames = frames;
                c.RetargetFrom = -1;
            }
        }

        public void SentStyle(string character, string styleId, string text)
        {
            var c = Get(character);
            if (c == null) return;
            c.Start.StyleId = styleId;
            c.Start.StyleJson = null;
            c.LastStyle = text;
        }

        public void SentCancel(string character)
        {
            var c = Get(character);
            if (c != null) c.Cancelled = true;
        }

        /// <summary>Stop resuming a character (its style could not be registered again).</summary>
        public void Forget(string character) { if (character != null) characters.Remove(character); }

        // ------------------------------------------------------------------ what arrives (model axes)
        public RsmtFailoverAction Received(RsmtMessage m)
        {
            var action = new RsmtFailoverAction();
            string cid = m.Kind == RsmtMessageKind.Frame && m.Frame != null ? m.Frame.Character : m.Character;
            var c = Get(cid);
            if (c == null) return action;
            switch (m.Kind)
            {
                case RsmtMessageKind.Frame:
                    OnFrame(c, m.Frame);
                    break;
                case RsmtMessageKind.Started:
                    m.Resumed = c.AwaitingStart && c.Resent;
                    c.AwaitingStart = c.Resent = false;
                    break;
                case RsmtMessageKind.Retargeted:
                    if (c.RetargetFrames >= 0) c.RetargetFrom = m.FromSeq;
                    break;
                case RsmtMessageKind.End:
                    characters.Remove(cid);
                    m.Frames = c.Delivered;
                    break;
                case RsmtMessageKind.Error:
                    if (m.Code == "validation_error" && c.AwaitingStart && c.Resent && c.LastResume != null && c.LastResume.Retargeted)
                    {
                        // A replica older than the "retargeted" option (a rolling upgrade): the resume again, without it.
                        c.LastResume.Retargeted = false;
                        c.LastStart = RsmtMessages.Start(c.LastResume);
                        action.Deliver = false;
                        action.Resend = c.LastStart;
                        return action;
                    }
                    if (m.Code == "unknown_style")
                    {
                        string named = c.AwaitingStart ? c.LastStart : c.LastStyle;
                        if (named != null && Style(c.Start.StyleId) != null && c.Reregistered < 2)
                        {
                            c.Reregistered++;
                            Reregistrations++;
                            action.Deliver = false;
                            action.RegisterStyleId = c.Start.StyleId;
                            action.Resend = named;
                            return action;
                        }
                    }
                    if (c.AwaitingStart) characters.Remove(cid);  // the start failed: nothing to resume
                    break;
            }
            return action;
        }

        void OnFrame(Character c, RsmtFrame f)
        {
            if (c.RetargetFrames >= 0 && c.RetargetFrom >= 0 && f.Seq >= c.RetargetFrom)
                c.RetargetFrames = c.RetargetFrom = -1;  // the frame's remaining counts the retarget now
            int seq = c.Base + f.Seq;
            if (c.Base > 0)
            {
                f.Seq = seq;
                f.T = (seq + 1) / Fps;
            }
            c.Recent.Enqueue(f.Pose);
            while (c.Recent.Count > ContextFrames) c.Recent.Dequeue();
            c.Delivered = seq + 1;
            c.Remaining = f.Remaining;
        }

        // ------------------------------------------------------------------ after a reconnection
        /// <summary>A start message for every live character; cancelled and finished ones are dropped.</summary>
        public List<string> ResumeMessages()
        {
            var output = new List<string>();
            foreach (var id in new List<string>(characters.Keys))
            {
                var c = characters[id];
                int remaining = c.RetargetFrames >= 0 ? c.RetargetFrames : c.Remaining;
                c.RetargetFrames = c.RetargetFrom = -1;
                if (c.Cancelled || (c.Delivered > 0 && remaining <= 0))
                {
                    characters.Remove(id);  // cancelled, or every frame arrived and only the end was lost
                    continue;
                }
                var o = Copy(c.Start);
                if (c.Delivered > 0)
                {
                    o.ContextJson = Context(c);
                    o.Frames = remaining;
                    o.Retargeted = c.Retargeted;  // mid-motion: the new server finishes its facing as a retargeted one's
                }
                c.Base = c.Delivered;
                c.Remaining = remaining;
                c.AwaitingStart = c.Resent = true;
                c.Reregistered = 0;
                c.LastStart = RsmtMessages.Start(o);
                c.LastResume = o;
                output.Add(c.LastStart);
            }
            if (output.Count > 0) Resumes++;
            return output;
        }

        /// <summary>The last ContextFrames poses received; when fewer arrived, the original context's last poses
        /// before them if it is a pose payload on this model, else the first received pose held.</summary>
        string Context(Character c)
        {
            var poses = new List<RsmtPose>(c.Recent);
            int need = ContextFrames - poses.Count;
            if (need > 0)
            {
                var before = OriginalPoses(c.Start.ContextJson);
                var head = new List<RsmtPose>();
                for (int i = 0; i < need; i++)
                    head.Add(before != null && before.Count >= need ? before[before.Count - need + i] : poses[0]);
                poses.InsertRange(0, head);
            }
            return RsmtMessages.PoseMotion(poses);
        }

        List<RsmtPose> OriginalPoses(string contextJson)
        {
            JsonValue motion;
            string error;
            if (contextJson == null || !Json.TryParse(contextJson, out motion, out error) || motion.Type != JsonType.Object) return null;
            var roots = motion.Get("root_positions");
            var rots = motion.Get("rotations");
            if (roots == null || rots == null || roots.Type != JsonType.Array || rots.Type != JsonType.Array) return null;
            if (motion.Get("joints") != null || System.Math.Abs(motion.GetNumber("fps", Fps) - Fps) > 1e-6) return null;
            if (roots.Array.Count != rots.Array.Count) return null;
            var poses = new List<RsmtPose>();
            for (int i = 0; i < roots.Array.Count; i++)
            {
                var r = roots.Array[i];
                var q = rots.Array[i];
                if (r.Type != JsonType.Array || r.Array.Count != 3 || q.Type != JsonType.Array || q.Array.Count != Joints) return null;
                var p = new RsmtPose(Joints) { Root = new RsmtVec3(r.Array[0].Number, r.Array[1].Number, r.Array[2].Number) };
                for (int j = 0; j < Joints; j++)
                {
                    var a = q.Array[j];
                    if (a.Type != JsonType.Array || a.Array.Count != 4) return null;
                    p.Rotations[j] = new RsmtQuat(a.Array[0].Number, a.Array[1].Number, a.Array[2].Number, a.Array[3].Number);
                }
                poses.Add(p);
            }
            return poses;
        }

        Character Get(string character)
        {
            Character c;
            return character != null && characters.TryGetValue(character, out c) ? c : null;
        }

        static RsmtStartOptions Copy(RsmtStartOptions o)
        {
            return new RsmtStartOptions
            {
                Character = o.Character, ContextJson = o.ContextJson, TargetJson = o.TargetJson, TargetAtJson = o.TargetAtJson,
                Frames = o.Frames,
                StyleId = o.StyleId, StyleJson = o.StyleJson, Seed = o.Seed, Deterministic = o.Deterministic,
                ExactArrival = o.ExactArrival, Retargeted = o.Retargeted, StyleStrength = o.StyleStrength, Pace = o.Pace,
                RequestId = o.RequestId, Model = o.Model,
            };
        }
    }
}
