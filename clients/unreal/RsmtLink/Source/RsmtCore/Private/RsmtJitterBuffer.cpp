#include "RsmtJitterBuffer.h"

#include <algorithm>

namespace rsmt {

void JitterBuffer::Reset() {
    frames_.clear();
    anchored_ = false;
    ended_ = false;
    starved_ = false;
    lastSeq_ = -1;
    shownSeq_ = -1;
}

void JitterBuffer::Push(const Frame& frame, double now) {
    if (frame.seq <= lastSeq_) return;  // duplicate or out of order: the stream is ordered, so drop it
    lastSeq_ = frame.seq;
    if (!anchored_ || starved_) {
        anchor_ = now + delay_ - frame.t;
        anchored_ = true;
        starved_ = false;
    }
    frames_.push_back(frame);
    while (frames_.size() > maxFrames_) frames_.pop_front();
}

bool JitterBuffer::Sample(double now, Pose& out) {
    if (!anchored_ || frames_.empty()) {
        if (!hasShown_) return false;
        out = shown_;
        return true;
    }
    const double tau = now - anchor_;
    while (frames_.size() >= 2 && frames_[1].t <= tau) frames_.pop_front();
    const Frame& a = frames_.front();
    if (tau < a.t) {  // not due yet (start, or re-buffering): hold what is on screen
        if (!hasShown_) return false;
        out = shown_;
        return true;
    }
    if (frames_.size() >= 2) {
        const Frame& b = frames_[1];
        const double span = b.t - a.t;
        const double alpha = span > 0.0 ? std::min(1.0, std::max(0.0, (tau - a.t) / span)) : 1.0;
        out.root = Lerp(a.pose.root, b.pose.root, alpha);
        out.rotations.resize(a.pose.rotations.size());
        for (std::size_t j = 0; j < a.pose.rotations.size() && j < b.pose.rotations.size(); ++j) {
            out.rotations[j] = Nlerp(a.pose.rotations[j], b.pose.rotations[j], alpha);
        }
    } else {
        out = a.pose;
        if (!ended_ && tau > a.t + 1.0 / fps_ && !starved_) {
            starved_ = true;
            ++underruns_;
        }
    }
    shownSeq_ = a.seq;
    shown_ = out;
    hasShown_ = true;
    return true;
}

bool JitterBuffer::Finished() const {
    return ended_ && frames_.size() <= 1 && (frames_.empty() || shownSeq_ == frames_.front().seq);
}

}  // namespace rsmt
