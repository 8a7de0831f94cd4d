// A jitter buffer that plays one character's frames at the model's frame rate (same algorithm as the
// Unreal client's RsmtJitterBuffer.h).
//
// Frames carry t = (seq + 1) / fps. The first frame to arrive is shown `Delay` seconds after it arrived;
// every later frame at the same offset from its t, so network and generation jitter smaller than Delay
// never shows. Between frames the pose is interpolated (root lerp, rotation nlerp), so any render rate
// works. When the buffer runs dry the last pose holds and the next frame re-buffers (plays Delay after it
// arrives) instead of fast-forwarding. Frames already in the past when they arrive (after a stall of the
// main thread or an unfocused window) are skipped, never replayed in a burst. `now` is any clock in seconds.
using System;
using System.Collections.Generic;

namespace Rsmt.Link
{
    public sealed class RsmtJitterBuffer
    {
        readonly LinkedList<RsmtFrame> frames = new LinkedList<RsmtFrame>();
        readonly int maxFrames;
        double anchor;  // playback time = now - anchor
        bool anchored, ended, starved, hasShown;
        int lastSeq = -1;
        RsmtPose shown;

        public double Delay;
        public double Fps;
        public int Underruns { get; private set; }
        public int ShownSeq { get; private set; }
        public int Buffered { get { return frames.Count; } }

        public RsmtJitterBuffer(double delaySeconds = 0.1, double fps = 30, int maxFrames = 1024)
        {
            Delay = delaySeconds;
            Fps = fps;
            this.maxFrames = maxFrames;
            ShownSeq = -1;
        }

        /// <summary>A new transition for this character (`started`): forget frames and timing, keep the shown pose.</summary>
        public void Reset()
        {
            frames.Clear();
            anchored = ended = starved = false;
            lastSeq = -1;
            ShownSeq = -1;
        }

        /// <summary>The stream sent `end`: the last frame holds without counting as an underrun.</summary>
        public void MarkEnded() { ended = true; }

        /// <summary>Ended and the last frame is on screen.</summary>
        public bool Finished
        {
            get { return ended && frames.Count <= 1 && (frames.Count == 0 || ShownSeq == frames.First.Value.Seq); }
        }

        public void Push(RsmtFrame frame, double now)
        {
            if (frame.Seq <= lastSeq) return;  // duplicate or out of order: the stream is ordered, so drop it
            lastSeq = frame.Seq;
            if (!anchored || starved)
            {
                anchor = now + Delay - frame.T;
                anchored = true;
                starved = false;
            }
            frames.AddLast(frame);
            while (frames.Count > maxFrames) frames.RemoveFirst();
        }

        /// <summary>The pose to show at `now`; false until the first frame is due.</summary>
        public bool Sample(double now, out RsmtPose pose)
        {
            pose = null;
            if (!anchored || frames.Count == 0)
            {
                if (!hasShown) return false;
                pose = shown;
                return true;
            }
            double tau = now - anchor;
            while (frames.Count >= 2 && frames.First.Next.Value.T <= tau) frames.RemoveFirst();
            var a = frames.First.Value;
            if (tau < a.T)  // not due yet (start, or re-buffering): hold what is on screen
            {
                if (!hasShown) return false;
                pose = shown;
                return true;
            }
            if (frames.Count >= 2)
            {
                var b = frames.First.Next.Value;
                double span = b.T - a.T;
                double alpha = span > 0 ? Math.Min(1, Math.Max(0, (tau - a.T) / span)) : 1;
                pose = new RsmtPose(a.Pose.Rotations.Length) { Root = RsmtVec3.Lerp(a.Pose.Root, b.Pose.Root, alpha) };
                for (int j = 0; j < pose.Rotations.Length; j++)
                    pose.Rotations[j] = RsmtQuat.Nlerp(a.Pose.Rotations[j], b.Pose.Rotations[j], alpha);
            }
            else
            {
                pose = a.Pose;
                if (!ended && tau > a.T + 1.0 / Fps && !starved)
                {
                    starved = true;
                    Underruns++;
                }
            }
            ShownSeq = a.Seq;
            shown = pose;
            hasShown = true;
            return true;
        }
    }
}
