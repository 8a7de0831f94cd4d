#include "RsmtFailover.h"

#include <algorithm>
#include <cmath>

namespace rsmt {

bool Failover::Resumable(int closeCode) {
    return closeCode != 1003 && closeCode != 1007 && closeCode != 1008 && closeCode != 1009;
}

double Failover::ReconnectDelay(int attempt, double baseSeconds, double maxSeconds) {
    return std::min(maxSeconds, baseSeconds * std::pow(2.0, std::min(attempt, 30)));
}

void Failover::SetModel(const ModelInfo& model) {
    if (model.contextFrames > 0) contextFrames_ = model.contextFrames;
    fps_ = model.fps;
    joints_ = static_cast<int>(model.joints.size());
}

bool Failover::Live() const {
    for (const auto& it : characters_)
        if (!it.second.cancelled) return true;
    return false;
}

void Failover::RememberStyle(const std::string& styleId, const std::string& body) { styles_[styleId] = body; }

void Failover::SentStart(const StartOptions& options) {
    Character c;
    c.start = options;
    c.remaining = options.frames;
    c.lastStart = BuildStart(options);
    characters_[options.character] = c;
}

void Failover::SentRetarget(const std::string& character, const std::string& targetJson, int frames) {
    auto it = characters_.find(character);
    if (it == characters_.end()) return;
    if (!targetJson.empty()) {
        it->second.start.targetJson = targetJson;
        it->second.start.targetAtJson.clear();  // a pose now: a start names one target or the other
        it->second.retargeted = true;
    }
    if (frames > 0) {
        it->second.retargetFrames = frames;
        it->second.retargetFrom = -1;
    }
}

void Failover::SentStyle(const std::string& character, const std::string& styleId) {
    auto it = characters_.find(character);
    if (it == characters_.end()) return;
    it->second.start.styleId = styleId;
    it->second.start.styleJson.clear();
    it->second.lastStyle = BuildStyle(character, styleId);
}

void Failover::SentCancel(const std::string& character) {
    auto it = characters_.find(character);
    if (it != characters_.end()) it->second.cancelled = true;
}

void Failover::Forget(const std::string& character) { characters_.erase(character); }

FailoverAction Failover::Received(Message& m) {
    FailoverAction action;
    const std::string& cid = m.kind == MessageKind::Frame ? m.frame.character : m.character;
    auto it = characters_.find(cid);
    if (cid.empty() || it == characters_.end()) return action;
    Character& c = it->second;
    switch (m.kind) {
    case MessageKind::Frame: {
        Frame& f = m.frame;
        if (c.retargetFrames >= 0 && c.retargetFrom >= 0 && f.seq >= c.retargetFrom)
            c.retargetFrames = c.retargetFrom = -1;  // the frame's remaining counts the retarget now
        const int seq = c.base + f.seq;
        if (c.base > 0) {
            f.seq = seq;
            f.t = (seq + 1) / fps_;
        }
        c.recent.push_back(f.pose);
        while (static_cast<int>(c.recent.size()) > contextFrames_) c.recent.pop_front();
        c.delivered = seq + 1;
        c.remaining = f.remaining;
        break;
    }
    case MessageKind::Started:
        m.resumed = c.awaitingStart && c.resent;
        c.awaitingStart = c.resent = false;
        break;
    case MessageKind::Retargeted:
        if (c.retargetFrames >= 0) c.retargetFrom = m.fromSeq;
        break;
    case MessageKind::End:
        m.frames = c.delivered;
        characters_.erase(it);
        break;
    case MessageKind::Error: {
        if (m.code == "validation_error" && c.awaitingStart && c.resent && c.lastResume.retargeted) {
            // A replica older than the "retargeted" option (a rolling upgrade): the resume again, without it.
            c.lastResume.retargeted = false;
            c.lastStart = BuildStart(c.lastResume);
            action.deliver = false;
            action.resend = c.lastStart;
            return action;
        }
        if (m.code == "unknown_style") {
            const std::string& named = c.awaitingStart ? c.lastStart : c.lastStyle;
            const auto style = styles_.find(c.start.styleId);
            if (!named.empty() && style != styles_.end() && c.reregistered < 2) {
                ++c.reregistered;
                ++reregistrations_;
                action.deliver = false;
                action.registerStyleBody = style->second;
                action.resend = named;
                return action;
            }
        }
        if (c.awaitingStart) characters_.erase(it);  // the start failed: nothing to resume
        break;
    }
    default:
        break;
    }
    return action;
}

std::vector<std::string> Failover::ResumeMessages() {
    std::vector<std::string> out;
    for (auto it = characters_.begin(); it != characters_.end();) {
        Character& c = it->second;
        const int remaining = c.retargetFrames >= 0 ? c.retargetFrames : c.remaining;
        c.retargetFrames = c.retargetFrom = -1;
        if (c.cancelled || (c.delivered > 0 && remaining <= 0)) {
            it = characters_.erase(it);  // cancelled, or every frame arrived and only the end was lost
            continue;
        }
        StartOptions o = c.start;
        if (c.delivered > 0) {
            o.contextJson = Context(c);
            o.frames = remaining;
            o.retargeted = c.retargeted;  // mid-motion: the new server finishes its facing as a retargeted one's
        }
        c.base = c.delivered;
        c.remaining = remaining;
        c.awaitingStart = c.resent = true;
        c.reregistered = 0;
        c.lastStart = BuildStart(o);
        c.lastResume = o;
        out.push_back(c.lastStart);
        ++it;
    }
    if (!out.empty()) ++resumes_;
    return out;
}

// The last context_frames poses received; when fewer arrived, the original context's last poses before them
// if it is a pose payload on this model, else the first received pose held.
std::string Failover::Context(const Character& c) const {
    std::vector<Pose> poses(c.recent.begin(), c.recent.end());
    const int need = contextFrames_ - static_cast<int>(poses.size());
    if (need > 0) {
        std::vector<Pose> before;
        const bool usable = OriginalPoses(c.start.contextJson, before) && static_cast<int>(before.size()) >= need;
        std::vector<Pose> head;
        for (int i = 0; i < need; ++i)
            head.push_back(usable ? before[before.size() - static_cast<std::size_t>(need - i)] : poses.front());
        poses.insert(poses.begin(), head.begin(), head.end());
    }
    std::vector<Vec3> roots;
    std::vector<std::vector<Quat>> rotations;
    for (const Pose& p : poses) {
        roots.push_back(p.root);
        rotations.push_back(p.rotations);
    }
    return PoseMotionJson(roots, rotations);
}

bool Failover::OriginalPoses(const std::string& contextJson, std::vector<Pose>& out) const {
    JsonValue motion;
    if (contextJson.empty() || !ParseJson(contextJson, motion) || !motion.IsObject()) return false;
    const JsonValue* roots = motion.Find("root_positions");
    const JsonValue* rots = motion.Find("rotations");
    if (roots == nullptr || rots == nullptr || !roots->IsArray() || !rots->IsArray()) return false;
    if (motion.Find("joints") != nullptr || std::fabs(motion.NumberOr("fps", fps_) - fps_) > 1e-6) return false;
    if (roots->array.size() != rots->array.size()) return false;
    const std::size_t joints = static_cast<std::size_t>(joints_);
    for (std::size_t i = 0; i < roots->array.size(); ++i) {
        const JsonValue& r = roots->array[i];
        const JsonValue& q = rots->array[i];
        if (!r.IsArray() || r.array.size() != 3 || !q.IsArray() || q.array.size() != joints) return false;
        Pose p;
        p.root = Vec3{r.array[0].number, r.array[1].number, r.array[2].number};
        for (std::size_t j = 0; j < joints; ++j) {
            const JsonValue& a = q.array[j];
            if (!a.IsArray() || a.array.size() != 4) return false;
            p.rotations.push_back(Quat{a.array[0].number, a.array[1].number, a.array[2].number, a.array[3].number});
        }
        out.push_back(p);
    }
    return true;
}

}  // namespace rsmt
