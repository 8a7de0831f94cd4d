// A jitter buffer that plays one character's frames at the model's frame rate.
//
// Frames carry t = (seq + 1) / fps. The first frame to arrive is shown `delay` seconds after it
// arrived; every later frame at the same offset from its t, so network and generation jitter
// smaller than `delay` never shows. Between frames the pose is interpolated (root lerp, rotation
// nlerp), so any render rate works. When the buffer runs dry the last pose holds and the next
// frame re-buffers (it plays `delay` after it arrives) instead of fast-forwarding. Frames that
// are already in the past when they arrive (a window that was not updated for a while) are
// skipped, never replayed in a burst. Time is whatever clock the caller passes, in seconds.
#pragma once

#include <cstddef>
#include <deque>

#include "RsmtCoreApi.h"
#include "RsmtProtocol.h"

namespace rsmt {

class RSMTCORE_API JitterBuffer {
public:
    explicit JitterBuffer(double delaySeconds = 0.1, double fps = 30.0, std::size_t maxFrames = 1024)
        : delay_(delaySeconds), fps_(fps), maxFrames_(maxFrames) {}

    void SetDelay(double seconds) { delay_ = seconds; }
    void SetFps(double fps) { fps_ = fps; }
    double Delay() const { return delay_; }

    // A new transition for this character (`started`): forget frames and timing, keep the shown pose.
    void Reset();
    void Push(const Frame& frame, double now);
    // The stream sent `end`: the last frame holds without counting as an underrun.
    void MarkEnded() { ended_ = true; }

    // The pose to show at `now`; false until the first frame is due.
    bool Sample(double now, Pose& out);

    std::size_t Buffered() const { return frames_.size(); }
    int Underruns() const { return underruns_; }
    int ShownSeq() const { return shownSeq_; }
    bool Finished() const;  // ended and the last frame is on screen

private:
    std::deque<Frame> frames_;
    double delay_;
    double fps_;
    std::size_t maxFrames_;
    double anchor_ = 0.0;  // playback time = now - anchor_
    bool anchored_ = false;
    bool ended_ = false;
    bool starved_ = false;
    int underruns_ = 0;
    int lastSeq_ = -1;
    int shownSeq_ = -1;
    Pose shown_;
    bool hasShown_ = false;
};

}  // namespace rsmt
