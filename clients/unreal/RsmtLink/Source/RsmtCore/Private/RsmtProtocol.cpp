#include "RsmtProtocol.h"

#include <cmath>
#include <cstring>

namespace rsmt {

namespace {

bool Fail(std::string* error, const std::string& what) {
    if (error != nullptr) *error = what;
    return false;
}

bool ReadVec3(const JsonValue* v, Vec3& out) {
    if (v == nullptr || !v->IsArray() || v->array.size() != 3) return false;
    for (const JsonValue& e : v->array) {
        if (!e.IsNumber()) return false;
    }
    out = Vec3{v->array[0].number, v->array[1].number, v->array[2].number};
    return true;
}

// Pose values are float32 on the server, written as the shortest text that reads back to them: rounding
// to float32 gives exactly what a binary frame carries.
double F32(double v) { return static_cast<double>(static_cast<float>(v)); }

bool ReadQuat(const JsonValue& v, Quat& out) {
    if (!v.IsArray() || v.array.size() != 4) return false;
    for (const JsonValue& e : v.array) {
        if (!e.IsNumber()) return false;
    }
    out = Quat{F32(v.array[0].number), F32(v.array[1].number), F32(v.array[2].number), F32(v.array[3].number)};
    return true;
}

int IntOr(const JsonValue& v, const char* key, int fallback) {
    return static_cast<int>(std::lround(v.NumberOr(key, fallback)));
}

MessageKind KindOf(const std::string& type) {
    if (type == "hello") return MessageKind::Hello;
    if (type == "started") return MessageKind::Started;
    if (type == "frame") return MessageKind::Frame;
    if (type == "end") return MessageKind::End;
    if (type == "retargeted") return MessageKind::Retargeted;
    if (type == "style_changed") return MessageKind::StyleChanged;
    if (type == "error") return MessageKind::Error;
    if (type == "pong") return MessageKind::Pong;
    return MessageKind::Unknown;
}

}  // namespace

bool FrameLayout::Read(const JsonValue& layout, int jointCount, std::string* error) {
    joints = jointCount;
    if (!layout.IsObject()) return Fail(error, "frame_layout is not an object");
    if (layout.StringOr("encoding", "") != "float32-le") {
        return Fail(error, "frame_layout.encoding is '" + layout.StringOr("encoding", "") + "', this client reads float32-le");
    }
    floatsPerFrame = IntOr(layout, "floats_per_frame", 0);
    const JsonValue* fields = layout.Find("fields");
    if (floatsPerFrame <= 0 || fields == nullptr || !fields->IsArray()) return Fail(error, "frame_layout lacks fields");
    slot = seq = t = rootPosition = rotations = remaining = -1;
    for (const JsonValue& f : fields->array) {
        const std::string name = f.StringOr("name", "");
        const int offset = IntOr(f, "offset", -1);
        const int count = IntOr(f, "count", -1);
        if (offset < 0 || count < 0 || offset + count > floatsPerFrame) {
            return Fail(error, "frame_layout field '" + name + "' lies outside the frame");
        }
        struct Want { const char* name; int count; int* slotOf; };
        const Want wants[] = {{"slot", 1, &slot}, {"seq", 1, &seq}, {"t", 1, &t}, {"root_position", 3, &rootPosition},
                              {"rotations", 4 * jointCount, &rotations}, {"remaining", 1, &remaining}};
        for (const Want& w : wants) {
            if (name == w.name) {
                if (count != w.count) {
                    return Fail(error, "frame_layout field '" + name + "' holds " + std::to_string(count) +
                                           " floats, expected " + std::to_string(w.count));
                }
                *w.slotOf = offset;
            }
        }
    }
    if (slot < 0 || seq < 0 || t < 0 || rootPosition < 0 || rotations < 0 || remaining < 0) {
        return Fail(error, "frame_layout lacks one of slot, seq, t, root_position, rotations, remaining");
    }
    return true;
}

bool FrameLayout::Resized(int newFloatsPerFrame, FrameLayout& out) const {
    const int delta = newFloatsPerFrame - floatsPerFrame;
    if (delta % 4 != 0 || joints + delta / 4 < 1) return false;
    out = *this;
    out.floatsPerFrame = newFloatsPerFrame;
    out.joints = joints + delta / 4;
    int* fields[] = {&out.slot, &out.seq, &out.t, &out.rootPosition, &out.remaining};
    for (int* f : fields) {
        if (*f > rotations) *f += delta;
    }
    return true;
}

bool ReadHello(const JsonValue& json, Hello& out, std::string* error) {
    if (json.StringOr("type", "") != "hello") return Fail(error, "the first message is not hello");
    out = Hello();
    out.protocol = IntOr(json, "protocol", 0);
    if (out.protocol != kProtocolVersion) {
        return Fail(error, "server speaks protocol " + std::to_string(out.protocol) + ", this client speaks 1");
    }
    const JsonValue* model = json.Find("model");
    const JsonValue* skeleton = model != nullptr ? model->Find("skeleton") : nullptr;
    const JsonValue* joints = skeleton != nullptr ? skeleton->Find("joints") : nullptr;
    if (joints == nullptr || !joints->IsArray() || joints->array.empty()) return Fail(error, "hello.model.skeleton.joints missing");
    ModelInfo& m = out.model;
    m.name = model->StringOr("name", "");
    m.version = model->StringOr("version", "");
    m.fps = model->NumberOr("fps", 30.0);
    m.contextFrames = IntOr(*model, "context_frames", 0);
    m.maxTransitionFrames = IntOr(*model, "max_transition_frames", 0);
    if (const JsonValue* style = model->Find("style_clip_frames")) {
        m.styleMinFrames = IntOr(*style, "min", 0);
        m.styleMaxFrames = IntOr(*style, "max", 0);
    }
    m.units = skeleton->StringOr("units", "cm");
    m.upAxis = skeleton->StringOr("up_axis", "y");
    m.handedness = skeleton->StringOr("handedness", "right");
    for (const JsonValue& j : joints->array) {
        Joint joint;
        joint.name = j.StringOr("name", "");
        joint.parent = IntOr(j, "parent", -1);
        if (joint.name.empty() || !ReadVec3(j.Find("offset"), joint.offset)) return Fail(error, "bad joint in hello");
        if (joint.parent >= static_cast<int>(m.joints.size())) return Fail(error, "joints are not in topological order");
        m.joints.push_back(joint);
    }
    if (!(m.fps > 0.0)) return Fail(error, "hello.model.fps must be positive");
    const JsonValue* layout = json.Find("frame_layout");
    if (layout == nullptr || !out.layout.Read(*layout, static_cast<int>(m.joints.size()), error)) {
        if (layout == nullptr) return Fail(error, "hello.frame_layout missing");
        return false;
    }
    out.encoding = json.StringOr("encoding", "json");
    if (const JsonValue* limits = json.Find("limits")) {
        out.maxCharacters = IntOr(*limits, "max_characters", 0);
        out.sendQueueFrames = IntOr(*limits, "send_queue_frames", 0);
        out.idleTimeoutS = limits->NumberOr("idle_timeout_s", 0.0);
        out.maxMessageBytes = IntOr(*limits, "max_message_bytes", 0);
    }
    return true;
}

bool ReadFrameJson(const JsonValue& json, int joints, Frame& out, std::string* error) {
    const JsonValue* pose = json.Find("pose");
    const JsonValue* rots = pose != nullptr ? pose->Find("rotations") : nullptr;
    out = Frame();
    out.character = json.StringOr("character", "");
    out.slot = IntOr(json, "slot", -1);
    out.seq = IntOr(json, "seq", 0);
    out.t = F32(json.NumberOr("t", 0.0));
    out.remaining = IntOr(json, "remaining", 0);
    if (pose == nullptr || !ReadVec3(pose->Find("root_position"), out.pose.root)) return Fail(error, "frame without pose.root_position");
    out.pose.root = Vec3{F32(out.pose.root.x), F32(out.pose.root.y), F32(out.pose.root.z)};
    if (rots == nullptr || !rots->IsArray() || static_cast<int>(rots->array.size()) != joints) {
        return Fail(error, "frame pose.rotations must hold " + std::to_string(joints) + " quaternions");
    }
    out.pose.rotations.resize(rots->array.size());
    for (std::size_t i = 0; i < rots->array.size(); ++i) {
        if (!ReadQuat(rots->array[i], out.pose.rotations[i])) return Fail(error, "a rotation is not [x, y, z, w]");
    }
    return true;
}

float ReadFloat32LE(const std::uint8_t* bytes) {
    const std::uint32_t bits = static_cast<std::uint32_t>(bytes[0]) | (static_cast<std::uint32_t>(bytes[1]) << 8) |
                               (static_cast<std::uint32_t>(bytes[2]) << 16) | (static_cast<std::uint32_t>(bytes[3]) << 24);
    float value;
    std::memcpy(&value, &bits, sizeof value);
    return value;
}

bool DecodeBinaryFrame(const void* data, std::size_t size, const FrameLayout& layout, int joints, Frame& out,
                       std::string* error) {
    if (layout.floatsPerFrame <= 0) return Fail(error, "no frame layout (hello not read)");
    if (size != layout.BytesPerFrame()) {
        return Fail(error, "binary frame of " + std::to_string(size) + " bytes, the layout says " +
                               std::to_string(layout.BytesPerFrame()));
    }
    const std::uint8_t* b = static_cast<const std::uint8_t*>(data);
    auto at = [b](int index) { return static_cast<double>(ReadFloat32LE(b + 4 * index)); };
    out = Frame();
    out.slot = static_cast<int>(std::lround(at(layout.slot)));
    out.seq = static_cast<int>(std::lround(at(layout.seq)));
    out.t = at(layout.t);
    out.remaining = static_cast<int>(std::lround(at(layout.remaining)));
    out.pose.root = Vec3{at(layout.rootPosition), at(layout.rootPosition + 1), at(layout.rootPosition + 2)};
    out.pose.rotations.resize(static_cast<std::size_t>(joints));
    for (int j = 0; j < joints; ++j) {
        const int o = layout.rotations + 4 * j;
        out.pose.rotations[static_cast<std::size_t>(j)] = Quat{at(o), at(o + 1), at(o + 2), at(o + 3)};
    }
    return true;
}

bool Session::HandleText(const char* data, std::size_t size, Message& out, std::string* error) {
    out = Message();
    if (!ParseJson(data, size, out.json, error)) return false;
    if (!out.json.IsObject()) return Fail(error, "a message must be a JSON object");
    out.type = out.json.StringOr("type", "");
    out.kind = KindOf(out.type);
    out.character = out.json.StringOr("character", "");
    out.slot = IntOr(out.json, "slot", -1);
    if (!hasHello_) {
        if (out.kind != MessageKind::Hello) return Fail(error, "expected hello first, got '" + out.type + "'");
        if (!ReadHello(out.json, hello_, error)) return false;
        hasHello_ = true;
        return true;
    }
    switch (out.kind) {
        case MessageKind::Started: {
            slots_[out.slot] = out.character;
            const int fpf = IntOr(out.json, "floats_per_frame", hello_.layout.floatsPerFrame);
            FrameLayout resized;
            if (fpf == hello_.layout.floatsPerFrame) {
                slotLayouts_.erase(out.slot);
            } else if (hello_.layout.Resized(fpf, resized)) {
                slotLayouts_[out.slot] = resized;
            } else {
                return Fail(error, "started.floats_per_frame " + std::to_string(fpf) + " does not fit the layout");
            }
            out.frames = IntOr(out.json, "frames", 0);
            out.fps = out.json.NumberOr("fps", hello_.model.fps);
            out.styleId = out.json.StringOr("style_id", "");
            break;
        }
        case MessageKind::Frame:
            if (!ReadFrameJson(out.json, LayoutOf(out.slot).joints, out.frame, error)) return false;
            break;
        case MessageKind::End:
            out.frames = IntOr(out.json, "frames", 0);
            out.reason = out.json.StringOr("reason", "");
            break;
        case MessageKind::Retargeted:
        case MessageKind::StyleChanged:
            out.fromSeq = IntOr(out.json, "from_seq", -1);
            out.styleId = out.json.StringOr("style_id", "");
            break;
        case MessageKind::Error:
            out.code = out.json.StringOr("code", "");
            out.message = out.json.StringOr("message", "");
            break;
        default:
            break;
    }
    return true;
}

bool Session::HandleBinary(const void* data, std::size_t size, Message& out, std::string* error) {
    out = Message();
    if (!hasHello_) return Fail(error, "a binary message before hello");
    const std::size_t slotEnd = 4u * static_cast<std::size_t>(hello_.layout.slot + 1);
    const FrameLayout& layout =
        size >= slotEnd ? LayoutOf(static_cast<int>(std::lround(ReadFloat32LE(static_cast<const std::uint8_t*>(data) + slotEnd - 4))))
                        : hello_.layout;
    if (!DecodeBinaryFrame(data, size, layout, layout.joints, out.frame, error)) return false;
    out.kind = MessageKind::Frame;
    out.type = "frame";
    out.slot = out.frame.slot;
    const auto it = slots_.find(out.frame.slot);
    if (it != slots_.end()) out.frame.character = it->second;
    out.character = out.frame.character;
    return true;
}

const FrameLayout& Session::LayoutOf(int slot) const {
    const auto it = slotLayouts_.find(slot);
    return it != slotLayouts_.end() ? it->second : hello_.layout;
}

// ---------------------------------------------------------------- client messages

std::string BvhMotionJson(const std::string& bvhText) {
    return "{\"bvh\":" + JsonQuote(bvhText) + "}";
}

std::string PoseMotionJson(const std::vector<Vec3>& roots, const std::vector<std::vector<Quat>>& rotations) {
    std::string s = "{\"root_positions\":[";
    for (std::size_t i = 0; i < roots.size(); ++i) {
        if (i) s += ',';
        s += "[" + JsonNumber(roots[i].x) + "," + JsonNumber(roots[i].y) + "," + JsonNumber(roots[i].z) + "]";
    }
    s += "],\"rotations\":[";
    for (std::size_t i = 0; i < rotations.size(); ++i) {
        if (i) s += ',';
        s += '[';
        for (std::size_t j = 0; j < rotations[i].size(); ++j) {
            const Quat& q = rotations[i][j];
            if (j) s += ',';
            s += "[" + JsonNumber(q.x) + "," + JsonNumber(q.y) + "," + JsonNumber(q.z) + "," + JsonNumber(q.w) + "]";
        }
        s += ']';
    }
    return s + "]}";
}

std::string TargetAtJson(double x, double z, double yaw) {
    return "{\"x\":" + JsonNumber(x) + ",\"z\":" + JsonNumber(z) + ",\"yaw\":" + JsonNumber(yaw) + "}";
}

std::string BuildStart(const StartOptions& o) {
    std::string s = "{\"type\":\"start\"";
    if (!o.character.empty()) s += ",\"character\":" + JsonQuote(o.character);
    s += ",\"context\":" + o.contextJson;
    if (!o.targetAtJson.empty()) s += ",\"target_at\":" + o.targetAtJson;
    else s += ",\"target\":" + o.targetJson;
    s += ",\"frames\":" + std::to_string(o.frames);
    if (!o.styleId.empty()) s += ",\"style_id\":" + JsonQuote(o.styleId);
    else s += ",\"style\":" + o.styleJson;
    if (o.hasSeed) s += ",\"seed\":" + std::to_string(o.seed);
    s += std::string(",\"deterministic\":") + (o.deterministic ? "true" : "false");
    if (o.exactArrival) s += ",\"exact_arrival\":true";
    if (o.retargeted) s += ",\"retargeted\":true";
    if (o.hasStyleStrength) s += ",\"style_strength\":" + JsonNumber(o.styleStrength);
    s += ",\"pace\":" + JsonQuote(o.pace);
    if (!o.model.empty()) s += ",\"model\":" + JsonQuote(o.model);
    if (!o.requestId.empty()) s += ",\"request_id\":" + JsonQuote(o.requestId);
    return s + "}";
}

std::string BuildRetarget(const std::string& character, const std::string& targetJson, int frames) {
    std::string s = "{\"type\":\"retarget\",\"character\":" + JsonQuote(character);
    if (!targetJson.empty()) s += ",\"target\":" + targetJson;
    if (frames > 0) s += ",\"frames\":" + std::to_string(frames);
    return s + "}";
}

std::string BuildStyle(const std::string& character, const std::string& styleId) {
    return "{\"type\":\"style\",\"character\":" + JsonQuote(character) + ",\"style_id\":" + JsonQuote(styleId) + "}";
}

std::string BuildCancel(const std::string& character) {
    return "{\"type\":\"cancel\",\"character\":" + JsonQuote(character) + "}";
}

std::string BuildPing(const std::string& id) {
    return "{\"type\":\"ping\",\"id\":" + JsonQuote(id) + "}";
}

std::string BuildStyleRegistration(const std::string& name, const std::vector<std::string>& motionsJson) {
    if (motionsJson.empty() || motionsJson.size() > kMaxStyleClips) return std::string();
    std::string s = "{\"name\":" + JsonQuote(name) + ",\"motions\":[";
    for (std::size_t i = 0; i < motionsJson.size(); ++i) {
        if (i) s += ',';
        s += motionsJson[i];
    }
    return s + "]}";
}

}  // namespace rsmt
