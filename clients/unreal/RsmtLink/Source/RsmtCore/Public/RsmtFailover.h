// Failover that resumes, without I/O: what to resend when the stream connection is lost.
//
// The connection's owner (URsmtLinkComponent with bFailover, or any other) tells it what it sends (SentStart,
// SentRetarget, SentStyle, SentCancel) and what it receives (Received, before converting poses to engine axes).
// It keeps, per live character, its start as it stands now (target and frames of later retargets, style of
// later style changes), the last context_frames poses received and how many frames were delivered. When the
// connection is lost (Resumable(close code)), the owner connects again to the same URL (ReconnectDelay between
// attempts); after the new hello, ResumeMessages() gives a start per live character whose context is the poses
// received last, with the same target, style, pace and model and the frames still to come ("retargeted" when
// its target changed mid-motion, so the new server finishes its facing as it does after a retarget). Received() numbers
// the new frames on from the count delivered, so the animation layer sees one continuous transition.
// Mirrors clients/python/rsmt_client/stream_failover.py.
#pragma once

#include <deque>
#include <map>
#include <string>
#include <vector>

#include "RsmtCoreApi.h"
#include "RsmtProtocol.h"

namespace rsmt {

// What the owner does with one received message.
struct FailoverAction {
    bool deliver = true;            // false: swallow it (its style is being registered again, or resend replaces it)
    std::string registerStyleBody;  // non-empty: POST /v1/styles with this body, then send resend; empty: just send it
    std::string resend;
};

class RSMTCORE_API Failover {
public:
    // Resuming after 1003, 1007, 1008 or 1009 would only repeat the failure (the client's own faults).
    static bool Resumable(int closeCode);
    // Seconds to wait before reconnection attempt `attempt` (0-based): base doubling, at most maxSeconds.
    static double ReconnectDelay(int attempt, double baseSeconds = 0.25, double maxSeconds = 4.0);

    void SetModel(const ModelInfo& model);
    bool Live() const;
    int Resumes() const { return resumes_; }
    int Reregistrations() const { return reregistrations_; }

    // The POST /v1/styles body of a registered style, to register it again on unknown_style.
    void RememberStyle(const std::string& styleId, const std::string& body);
    void SentStart(const StartOptions& options);
    void SentRetarget(const std::string& character, const std::string& targetJson, int frames);
    void SentStyle(const std::string& character, const std::string& styleId);
    void SentCancel(const std::string& character);
    void Forget(const std::string& character);

    // A received message, model axes: renumbers a resumed character's frames (seq, t) and end.frames, marks a
    // resumed started, and answers unknown_style with a registration and a resend when it holds the clip.
    FailoverAction Received(Message& message);
    // After the new connection's hello: a start per live character; cancelled and finished ones are dropped.
    std::vector<std::string> ResumeMessages();

private:
    struct Character {
        StartOptions start;  // as it stands now
        std::deque<Pose> recent;
        int delivered = 0;
        int base = 0;
        int remaining = 0;
        int retargetFrames = -1;
        int retargetFrom = -1;
        bool awaitingStart = true;
        bool resent = false;
        bool cancelled = false;
        bool retargeted = false;  // given a new target after its start: a resume says so
        int reregistered = 0;
        std::string lastStart;  // the start (or resume) sent last
        StartOptions lastResume;  // the options of the resume sent last
        std::string lastStyle;  // the style message sent last
    };

    std::string Context(const Character& c) const;
    bool OriginalPoses(const std::string& contextJson, std::vector<Pose>& out) const;

    std::map<std::string, Character> characters_;
    std::map<std::string, std::string> styles_;
    int contextFrames_ = 10;
    double fps_ = 30.0;
    int joints_ = 0;
    int resumes_ = 0;
    int reregistrations_ = 0;
};

}  // namespace rsmt
