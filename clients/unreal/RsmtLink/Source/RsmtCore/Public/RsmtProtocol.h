// The RSMT WebSocket protocol v1 (docs/protocol.md): hello, frames (JSON and binary float32), the
// other server messages, and the client messages. No engine types; no exceptions.
#pragma once

#include <cstddef>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "RsmtCoreApi.h"
#include "RsmtJson.h"
#include "RsmtMath.h"

namespace rsmt {

constexpr int kProtocolVersion = 1;

struct Joint {
    std::string name;
    int parent = -1;
    Vec3 offset;  // in the parent's frame, model units
};

struct ModelInfo {
    std::string name;
    std::string version;
    double fps = 30.0;
    int contextFrames = 0;
    int maxTransitionFrames = 0;
    int styleMinFrames = 0;  // style_clip_frames (0 when the server does not say)
    int styleMaxFrames = 0;
    std::vector<Joint> joints;
    std::string units = "cm";
    std::string upAxis = "y";
    std::string handedness = "right";
};

// Where each field of a binary frame sits, in float32 units (hello.frame_layout).
struct RSMTCORE_API FrameLayout {
    int floatsPerFrame = 0;
    int joints = 0;
    int slot = -1;
    int seq = -1;
    int t = -1;
    int rootPosition = -1;
    int rotations = -1;
    int remaining = -1;

    bool Read(const JsonValue& layout, int jointCount, std::string* error);
    // The layout of a model with another joint count (started.floats_per_frame): fields after the rotations
    // move by the difference, the others stay where hello put them.
    bool Resized(int newFloatsPerFrame, FrameLayout& out) const;
    std::size_t BytesPerFrame() const { return static_cast<std::size_t>(floatsPerFrame) * 4u; }
};

struct Hello {
    int protocol = 0;
    ModelInfo model;
    FrameLayout layout;
    std::string encoding = "json";
    int maxCharacters = 0;
    int sendQueueFrames = 0;
    double idleTimeoutS = 0.0;
    int maxMessageBytes = 0;
};

struct Pose {
    Vec3 root;                   // world position of joint 0
    std::vector<Quat> rotations;  // local rotation per joint, skeleton order
};

struct Frame {
    std::string character;  // empty for a binary frame whose slot has no `started` yet
    int slot = -1;
    int seq = 0;
    double t = 0.0;  // seconds since the start: (seq + 1) / fps
    int remaining = 0;
    Pose pose;
};

enum class MessageKind { Hello, Started, Frame, End, Retargeted, StyleChanged, Error, Pong, Unknown };

struct Message {
    MessageKind kind = MessageKind::Unknown;
    std::string type;
    std::string character;
    int slot = -1;
    Frame frame;            // kind == Frame
    int frames = 0;         // started: frames to come; end: frames sent
    double fps = 0.0;       // started
    int fromSeq = -1;       // retargeted / style_changed
    std::string styleId;    // started / style_changed
    std::string reason;     // end: "arrived" or "cancelled"
    std::string code;       // error
    std::string message;    // error
    bool resumed = false;   // started: a character resumed on a new connection (rsmt::Failover)
    JsonValue json;         // the whole text message (empty for binary frames)
};

RSMTCORE_API bool ReadHello(const JsonValue& json, Hello& out, std::string* error);
RSMTCORE_API bool ReadFrameJson(const JsonValue& json, int joints, Frame& out, std::string* error);
// One binary frame: exactly layout.BytesPerFrame() little-endian float32 values.
RSMTCORE_API bool DecodeBinaryFrame(const void* data, std::size_t size, const FrameLayout& layout, int joints,
                                    Frame& out, std::string* error);
RSMTCORE_API float ReadFloat32LE(const std::uint8_t* bytes);

// The state of one connection: reads hello first, then maps binary slots to characters.
class RSMTCORE_API Session {
public:
    // A text (JSON) message. The first must be hello.
    bool HandleText(const char* data, std::size_t size, Message& out, std::string* error);
    // A complete binary message (a frame).
    bool HandleBinary(const void* data, std::size_t size, Message& out, std::string* error);

    bool HasHello() const { return hasHello_; }
    const Hello& GetHello() const { return hello_; }
    int Joints() const { return static_cast<int>(hello_.model.joints.size()); }
    // The binary layout of a slot's character (hello's, unless it runs another model).
    const FrameLayout& LayoutOf(int slot) const;

private:
    Hello hello_;
    bool hasHello_ = false;
    std::map<int, std::string> slots_;
    std::map<int, FrameLayout> slotLayouts_;
};

// ---------------------------------------------------------------- client messages
// A Motion payload: BVH text, or root positions + local rotations (model units and axes).
RSMTCORE_API std::string BvhMotionJson(const std::string& bvhText);
RSMTCORE_API std::string PoseMotionJson(const std::vector<Vec3>& roots, const std::vector<std::vector<Quat>>& rotations);
// A target given as a place and a facing (a start's "target_at"), in the model's units and axes: the root arrives
// over (x, z) facing yaw degrees about +Y (0: +Z, 90: +X). From Unreal component space (the mesh facing +Y):
// x = X / s, z = Y / s (s = centimetres per model unit), yaw = 90 - Yaw.
RSMTCORE_API std::string TargetAtJson(double x, double z, double yaw);

struct StartOptions {
    std::string character;    // optional
    std::string contextJson;  // a Motion payload (BvhMotionJson / PoseMotionJson)
    std::string targetJson;         // one of targetJson / targetAtJson
    std::string targetAtJson;       // a place and facing (TargetAtJson): the server picks the pose, arrives exactly
    int frames = 30;
    std::string styleId;      // one of styleId / styleJson
    std::string styleJson;
    bool hasSeed = false;
    std::uint64_t seed = 0;
    bool deterministic = false;
    bool exactArrival = false;      // bend the last frames so the arrival frame equals the target pose
    bool retargeted = false;        // a resume of a character retargeted mid-motion (Failover sets it)
    bool hasStyleStrength = false;  // false: the server's style strength (not sent)
    double styleStrength = 1.0;     // 0 to 4: the style moved from the model's neutral style by this factor
    std::string pace = "realtime";  // or "asap"
    std::string model;              // optional: a model of GET /v1/models
    std::string requestId;          // optional
};

RSMTCORE_API std::string BuildStart(const StartOptions& options);
// targetJson empty: frames only; frames <= 0: target only.
RSMTCORE_API std::string BuildRetarget(const std::string& character, const std::string& targetJson, int frames);
RSMTCORE_API std::string BuildStyle(const std::string& character, const std::string& styleId);
RSMTCORE_API std::string BuildCancel(const std::string& character);
RSMTCORE_API std::string BuildPing(const std::string& id);

// ---------------------------------------------------------------- HTTP bodies
// The most clips one style is registered from (POST /v1/styles, "motions").
constexpr std::size_t kMaxStyleClips = 5;
// POST /v1/styles for 1 to kMaxStyleClips clips of one style (Motion payloads: BvhMotionJson / PoseMotionJson),
// encoded together into one style whose id does not depend on their order; empty when the count is out of range.
RSMTCORE_API std::string BuildStyleRegistration(const std::string& name, const std::vector<std::string>& motionsJson);

}  // namespace rsmt
