// What the model reads of a motion, cut from a whole take before it is sent (the Python client's
// rsmt_client.motion_cuts, the same numbers): a context to its last context_frames, a target to its last two
// frames (the pose and its velocity), a style clip longer than style_clip_frames.max to its middle, said once
// through Notice. BVH text is cut as text: the numbers go out exactly as written.
using System;
using System.Collections.Generic;
using System.Globalization;
using System.Text;

namespace Rsmt.Link
{
    /// <summary>The frames a model reads (GET /v1/model, or hello's model).</summary>
    public sealed class RsmtMotionLimits
    {
        public double Fps = 30;
        public int ContextFrames;
        public int StyleMinFrames;
        public int StyleMaxFrames;

        /// <summary>Null when the description lacks the fields (an older server): motions then go as they are.</summary>
        public static RsmtMotionLimits FromModel(RsmtModelInfo model)
        {
            if (model == null || model.ContextFrames <= 0 || model.StyleMaxFrames <= 0) return null;
            return new RsmtMotionLimits
            {
                Fps = model.Fps, ContextFrames = model.ContextFrames,
                StyleMinFrames = model.StyleMinFrames, StyleMaxFrames = model.StyleMaxFrames,
            };
        }
    }

    /// <summary>BVH text: frame count, fps and a window of frames, cut as text.</summary>
    public static class RsmtBvhText
    {
        sealed class Parts
        {
            public string Header;        // HIERARCHY ... up to MOTION
            public string FrameTime;     // the number as written
            public List<string> Frames = new List<string>();
        }

        static Parts Split(string bvh)
        {
            string[] lines = bvh.Replace("\r", "").Split('\n');
            int motion = -1;
            for (int i = 0; i < lines.Length; i++)
                if (lines[i].Trim().Equals("MOTION", StringComparison.OrdinalIgnoreCase)) { motion = i; break; }
            if (motion < 0) throw new FormatException("BVH: no MOTION line");
            int channels = 0;
            for (int i = 0; i < motion; i++)
            {
                string[] words = lines[i].Trim().Split((char[])null, StringSplitOptions.RemoveEmptyEntries);
                if (words.Length >= 2 && words[0].Equals("CHANNELS", StringComparison.OrdinalIgnoreCase))
                    channels += int.Parse(words[1], CultureInfo.InvariantCulture);
            }
            var parts = new Parts { Header = string.Join("\n", lines, 0, motion) };
            int declared = -1, at = motion + 1;
            for (; at < lines.Length && (declared < 0 || parts.FrameTime == null); at++)
            {
                string line = lines[at].Trim();
                int colon = line.IndexOf(':');
                if (colon < 0) { if (line.Length == 0) continue; throw new FormatException("BVH: expected Frames: and Frame Time:"); }
                string key = line.Substring(0, colon).Replace(" ", "").Replace("\t", "").ToLowerInvariant();
                string value = line.Substring(colon + 1).Trim();
                if (key == "frames") declared = int.Parse(value, CultureInfo.InvariantCulture);
                else if (key == "frametime") parts.FrameTime = value;
                else throw new FormatException("BVH: unexpected " + line);
            }
            var tokens = new List<string>();
            for (; at < lines.Length; at++)
                tokens.AddRange(lines[at].Split((char[])null, StringSplitOptions.RemoveEmptyEntries));
            if (channels == 0)
            {
                for (int f = 0; f < declared; f++) parts.Frames.Add("");
                return parts;
            }
            if (tokens.Count < (long)declared * channels) throw new FormatException("BVH: fewer values than Frames: says");
            for (int f = 0; f < declared; f++) parts.Frames.Add(string.Join(" ", tokens.GetRange(f * channels, channels)));
            return parts;
        }

        public static int FrameCount(string bvh) { return Split(bvh).Frames.Count; }

        /// <summary>1 / Frame Time, or the whole number it rounds to (0.0333333 s is 30 fps).</summary>
        public static double Fps(string bvh) { return FpsOf(Split(bvh).FrameTime); }

        static double FpsOf(string frameTime)
        {
            double fps = 1.0 / double.Parse(frameTime, NumberStyles.Float, CultureInfo.InvariantCulture);
            double whole = Math.Round(fps);
            return whole >= 1 && Math.Abs(fps - whole) <= 1e-4 * fps ? whole : fps;
        }

        /// <summary>Frames [start, start + count) as BVH text: the same hierarchy, frame time and numbers.</summary>
        public static string Window(string bvh, int start, int count)
        {
            var p = Split(bvh);
            if (start < 0 || count < 1 || start + count > p.Frames.Count)
                throw new ArgumentOutOfRangeException("frames " + start + " to " + (start + count - 1) + " are outside the "
                                                      + p.Frames.Count + " frames");
            var sb = new StringBuilder(p.Header).Append("\nMOTION\nFrames: ").Append(count.ToString(CultureInfo.InvariantCulture))
                .Append("\nFrame Time: ").Append(p.FrameTime).Append('\n');
            for (int f = start; f < start + count; f++) sb.Append(p.Frames[f]).Append('\n');
            return sb.ToString();
        }

        internal static void Measure(string bvh, out int frames, out double fps)
        {
            var p = Split(bvh);
            frames = p.Frames.Count;
            fps = FpsOf(p.FrameTime);
        }
    }

    /// <summary>Cuts BVH motions to what one model reads; says once (Notice) when it cuts a style clip.</summary>
    public sealed class RsmtMotionCutter
    {
        public const int TargetFrames = 2;
        public readonly RsmtMotionLimits Limits;
        /// <summary>Raised once per cutter, the first time a style clip is cut.</summary>
        public event Action<string> Notice;
        bool noticed;

        public RsmtMotionCutter(RsmtMotionLimits limits) { Limits = limits; }

        /// <summary>How many frames `frames` at `sourceFps` become at `fps`, as the server resamples (from frame 0).</summary>
        public static int Resampled(int frames, double sourceFps, double fps)
        {
            return frames > 0 ? (int)Math.Floor((frames - 1) * fps / sourceFps + 1e-9) + 1 : 0;
        }

        /// <summary>The fewest source frames that resample to at least `frames`.</summary>
        public static int FramesFor(int frames, double sourceFps, double fps)
        {
            int n = Math.Max(1, (int)Math.Ceiling((frames - 1) * sourceFps / fps - 1e-9) + 1);
            while (Resampled(n, sourceFps, fps) < frames) n++;
            return n;
        }

        /// <summary>The most source frames that resample to at most `frames`.</summary>
        public static int FramesWithin(int frames, double sourceFps, double fps)
        {
            int n = Math.Max(1, (int)Math.Floor(frames * sourceFps / fps + 1e-9));
            while (n > 1 && Resampled(n, sourceFps, fps) > frames) n--;
            return n;
        }

        public string Context(string bvh) { return Limits == null ? bvh : Tail(bvh, Limits.ContextFrames); }

        public string Target(string bvh) { return Limits == null ? bvh : Tail(bvh, TargetFrames); }

        string Tail(string bvh, int want)
        {
            int total; double fps;
            RsmtBvhText.Measure(bvh, out total, out fps);
            int keep = FramesFor(want, fps, Limits.Fps);
            return total <= keep ? bvh : RsmtBvhText.Window(bvh, total - keep, keep);
        }

        public string Style(string bvh)
        {
            if (Limits == null) return bvh;
            int total; double fps;
            RsmtBvhText.Measure(bvh, out total, out fps);
            if (Resampled(total, fps, Limits.Fps) <= Limits.StyleMaxFrames) return bvh;
            int keep = FramesWithin(Limits.StyleMaxFrames, fps, Limits.Fps);
            int start = (total - keep) / 2;
            if (!noticed)
            {
                noticed = true;
                if (Notice != null)
                    Notice(string.Format(CultureInfo.InvariantCulture,
                        "style clip of {0} frames at {1:0.###} fps: the model reads at most {2} at {3:0.###} fps; sending the "
                        + "middle {4} (frames {5}-{6}). Cut it yourself to choose the part (RsmtBvhText.Window); said once.",
                        total, fps, Limits.StyleMaxFrames, Limits.Fps, keep, start, start + keep - 1));
            }
            return RsmtBvhText.Window(bvh, start, keep);
        }
    }
}
