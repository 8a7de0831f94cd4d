// Tests of RsmtCore without Unreal (built with g++ by tests/clients/test_unreal_core.py).
//
//   rsmt_core_test selftest                 unit checks: JSON, conversion, binary frames, reassembly, jitter buffer,
//                                           failover (rsmt::Failover on hand-made traffic)
//   rsmt_core_test replay FILE.rec [CHUNK]  replay a recorded session: every message cut into CHUNK-byte pieces
//                                           (OnRawMessage style), reassembled, classified, decoded; prints one JSON
//                                           line per frame with the pose converted to Unreal axes
//   rsmt_core_test style-body NAME CLIP.bvh...   the POST /v1/styles body of these clips
//   rsmt_core_test start-at CHARACTER CONTEXT.bvh FRAMES STYLE_ID SEED X Z YAW
//                                           the start message (BuildStart, pace asap) to a place and facing
//                                           (TargetAtJson, the model's units and axes)
//
// A .rec file is what the Python tests captured from a live server: records of
// [kind: 'T' text | 'B' binary][length: uint32 little-endian][payload], hello first.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "RsmtConvert.h"
#include "RsmtFailover.h"
#include "RsmtJitterBuffer.h"
#include "RsmtJson.h"
#include "RsmtProtocol.h"
#include "RsmtReassembler.h"

using namespace rsmt;

static int g_failures = 0;
static int g_checks = 0;

#define CHECK(cond)                                                              \
    do {                                                                         \
        ++g_checks;                                                              \
        if (!(cond)) {                                                           \
            ++g_failures;                                                        \
            std::fprintf(stderr, "FAILED %s:%d: %s\n", __FILE__, __LINE__, #cond); \
        }                                                                        \
    } while (0)

static bool Near(double a, double b, double tol = 1e-9) { return std::fabs(a - b) <= tol; }
static bool NearV(const Vec3& a, const Vec3& b, double tol = 1e-9) {
    return Near(a.x, b.x, tol) && Near(a.y, b.y, tol) && Near(a.z, b.z, tol);
}
static bool NearQ(const Quat& a, const Quat& b, double tol = 1e-9) {
    return Near(a.x, b.x, tol) && Near(a.y, b.y, tol) && Near(a.z, b.z, tol) && Near(a.w, b.w, tol);
}

static std::string MakeHello(int joints) {
    std::string s = "{\"type\":\"hello\",\"protocol\":1,\"encoding\":\"binary\",\"model\":{\"name\":\"m\",\"version\":\"v\","
                    "\"fps\":30.0,\"context_frames\":10,\"max_transition_frames\":60,\"skeleton\":{\"joints\":[";
    for (int j = 0; j < joints; ++j) {
        if (j) s += ",";
        s += "{\"name\":\"J" + std::to_string(j) + "\",\"parent\":" + std::to_string(j - 1) + ",\"offset\":[1,2,3]}";
    }
    const int rot = 4 * joints;
    s += "],\"units\":\"cm\",\"up_axis\":\"y\",\"handedness\":\"right\"}},\"frame_layout\":{\"encoding\":\"float32-le\","
         "\"floats_per_frame\":" + std::to_string(7 + rot) + ",\"fields\":[{\"name\":\"slot\",\"offset\":0,\"count\":1},"
         "{\"name\":\"seq\",\"offset\":1,\"count\":1},{\"name\":\"t\",\"offset\":2,\"count\":1},"
         "{\"name\":\"root_position\",\"offset\":3,\"count\":3},{\"name\":\"rotations\",\"offset\":6,\"count\":" +
         std::to_string(rot) + "},{\"name\":\"remaining\",\"offset\":" + std::to_string(6 + rot) + ",\"count\":1}]},"
         "\"limits\":{\"max_characters\":64,\"send_queue_frames\":16,\"idle_timeout_s\":60,\"max_message_bytes\":65536}}";
    return s;
}

static std::vector<std::uint8_t> MakeBinaryFrame(int joints, float slot, float seq, float t, const float* root,
                                                 const std::vector<float>& rotations, float remaining) {
    std::vector<float> v;
    v.push_back(slot);
    v.push_back(seq);
    v.push_back(t);
    v.insert(v.end(), root, root + 3);
    v.insert(v.end(), rotations.begin(), rotations.end());
    v.push_back(remaining);
    (void)joints;
    std::vector<std::uint8_t> out(v.size() * 4);
    for (std::size_t i = 0; i < v.size(); ++i) {
        std::uint32_t bits;
        std::memcpy(&bits, &v[i], 4);
        for (int k = 0; k < 4; ++k) out[4 * i + static_cast<std::size_t>(k)] = static_cast<std::uint8_t>(bits >> (8 * k));
    }
    return out;
}

static void TestJson() {
    JsonValue v;
    std::string err;
    CHECK(ParseJson("{\"a\": [1, -2.5e2, true, false, null], \"s\": \"q\\\"\\\\\\n\\u00e9\\ud83d\\ude00\"}", v, &err));
    CHECK(v.IsObject() && v.Find("a") != nullptr && v.Find("a")->array.size() == 5);
    CHECK(Near(v.Find("a")->array[1].number, -250.0));
    CHECK(v.Find("a")->array[2].boolean && !v.Find("a")->array[3].boolean && v.Find("a")->array[4].IsNull());
    CHECK(v.StringOr("s", "") == std::string("q\"\\\n\xc3\xa9\xf0\x9f\x98\x80"));
    CHECK(!ParseJson("{\"a\": 1,}", v, &err) && err.find("byte") != std::string::npos);
    CHECK(!ParseJson("[1 2]", v, &err));
    CHECK(!ParseJson("\"unterminated", v, &err));
    CHECK(!ParseJson("{} extra", v, &err));
    CHECK(!ParseJson("01x", v, &err));
    CHECK(ParseJson(" [0.1, 1e-7, 123456789012] ", v, &err) && Near(v.array[0].number, 0.1, 0) &&
          Near(v.array[1].number, 1e-7, 0));
    CHECK(JsonQuote("a\"b\\c\n\x01") == "\"a\\\"b\\\\c\\n\\u0001\"");
    CHECK(JsonNumber(0.1) == "0.10000000000000001" || JsonNumber(0.1) == "0.1");
    CHECK(std::strtod(JsonNumber(1.0 / 3.0).c_str(), nullptr) == 1.0 / 3.0);
    std::string deep(100, '[');
    CHECK(!ParseJson(deep, v, &err));
}

static void TestConversion() {
    // Known values: positions swap y and z; units scale.
    CHECK(NearV(ModelToUnrealPosition(Vec3{1, 2, 3}), Vec3{1, 3, 2}));
    CHECK(NearV(ModelToUnrealPosition(Vec3{1, 2, 3}, 100.0), Vec3{100, 300, 200}));
    CHECK(NearV(UnrealToModelPosition(Vec3{1, 3, 2}), Vec3{1, 2, 3}));
    // 90 degrees about the model's up axis (+Y) turns a character from facing +Z to facing +X (its left).
    const double h = std::sqrt(0.5);
    const Quat yaw90{0, h, 0, h};
    CHECK(NearV(Rotate(yaw90, Vec3{0, 0, 1}), Vec3{1, 0, 0}, 1e-12));
    // In Unreal it is -90 degrees about +Z (left-handed yaw), turning forward (+Y) to +X: the same left.
    const Quat ue = ModelToUnrealRotation(yaw90);
    CHECK(NearQ(ue, Quat{0, 0, -h, h}, 1e-12));
    CHECK(NearV(Rotate(ue, Vec3{0, 1, 0}), Vec3{1, 0, 0}, 1e-12));
    // Rotations and positions convert consistently: M (q v) == q' (M v) for random q, v.
    std::mt19937 rng(7);
    std::normal_distribution<double> n01(0.0, 1.0);
    for (int i = 0; i < 200; ++i) {
        const Quat q = Normalize(Quat{n01(rng), n01(rng), n01(rng), n01(rng)});
        const Vec3 v{n01(rng), n01(rng), n01(rng)};
        CHECK(NearV(ModelToUnrealPosition(Rotate(q, v)), Rotate(ModelToUnrealRotation(q), ModelToUnrealPosition(v)), 1e-9));
        CHECK(NearQ(UnrealToModelRotation(ModelToUnrealRotation(q)), q, 0));
        // and composition: (q1 q2)' == q1' q2'
        const Quat r = Normalize(Quat{n01(rng), n01(rng), n01(rng), n01(rng)});
        CHECK(NearQ(ModelToUnrealRotation(Multiply(q, r)), Multiply(ModelToUnrealRotation(q), ModelToUnrealRotation(r)), 1e-12));
    }
    CHECK(Near(CentimetresPerUnit("m"), 100.0) && Near(CentimetresPerUnit("cm"), 1.0) && CentimetresPerUnit("furlong") == 0.0);
}

static void TestProtocol() {
    Session session;
    Message m;
    std::string err;
    const int joints = 3;
    const std::string hello = MakeHello(joints);
    CHECK(!session.HandleBinary("x", 1, m, &err));
    CHECK(session.HandleText(hello.data(), hello.size(), m, &err));
    CHECK(session.HasHello() && session.Joints() == joints && session.GetHello().layout.floatsPerFrame == 19);
    CHECK(session.GetHello().maxMessageBytes == 65536 && Near(session.GetHello().model.fps, 30.0));
    CHECK(CheckModelConventions(session.GetHello().model));
    const std::string started = "{\"type\":\"started\",\"character\":\"hero\",\"slot\":5,\"frames\":40,\"fps\":30.0,\"style_id\":\"sty_x\"}";
    CHECK(session.HandleText(started.data(), started.size(), m, &err) && m.kind == MessageKind::Started && m.slot == 5 &&
          m.frames == 40 && m.styleId == "sty_x");
    const float root[3] = {1.5f, 92.25f, -3.0f};
    std::vector<float> rots = {0, 0, 0, 1, 0.5f, 0.5f, 0.5f, 0.5f, 0, 1, 0, 0};
    const auto bin = MakeBinaryFrame(joints, 5, 7, 8.0f / 30.0f, root, rots, 32);
    CHECK(session.HandleBinary(bin.data(), bin.size(), m, &err));
    CHECK(m.kind == MessageKind::Frame && m.frame.character == "hero" && m.frame.seq == 7 && m.frame.remaining == 32);
    CHECK(Near(m.frame.t, static_cast<double>(8.0f / 30.0f)) && NearV(m.frame.pose.root, Vec3{1.5, 92.25, -3.0}));
    CHECK(NearQ(m.frame.pose.rotations[1], Quat{0.5, 0.5, 0.5, 0.5}));
    CHECK(!session.HandleBinary(bin.data(), bin.size() - 4, m, &err) && err.find("bytes") != std::string::npos);
    const std::string frame = "{\"type\":\"frame\",\"character\":\"hero\",\"slot\":5,\"seq\":7,\"t\":0.26666668,\"remaining\":32,"
                              "\"pose\":{\"root_position\":[1.5,92.25,-3.0],\"rotations\":[[0,0,0,1],[0.5,0.5,0.5,0.5],[0,1,0,0]]}}";
    CHECK(session.HandleText(frame.data(), frame.size(), m, &err) && m.kind == MessageKind::Frame &&
          NearQ(m.frame.pose.rotations[2], Quat{0, 1, 0, 0}));
    const std::string bad = "{\"type\":\"frame\",\"pose\":{\"root_position\":[1,2],\"rotations\":[]}}";
    CHECK(!session.HandleText(bad.data(), bad.size(), m, &err));
    // A character of another model (5 joints): its layout comes from started.floats_per_frame.
    const std::string other5 = "{\"type\":\"started\",\"character\":\"big\",\"slot\":9,\"frames\":3,\"fps\":30.0,"
                               "\"style_id\":\"s\",\"floats_per_frame\":27}";
    CHECK(session.HandleText(other5.data(), other5.size(), m, &err) && session.LayoutOf(9).joints == 5 &&
          session.LayoutOf(9).remaining == 26 && session.LayoutOf(5).joints == 3);
    std::vector<float> rots5(20, 0.0f);
    for (int j = 0; j < 5; ++j) rots5[static_cast<std::size_t>(4 * j + 3)] = 1.0f;
    rots5[18] = 1.0f;  // joint 4: (0, 0, 1, 1) before normalization, whatever: it is decoded as sent
    const auto bin5 = MakeBinaryFrame(5, 9, 0, 1.0f / 30.0f, root, rots5, 2);
    CHECK(session.HandleBinary(bin5.data(), bin5.size(), m, &err) && m.frame.character == "big" &&
          m.frame.pose.rotations.size() == 5 && m.frame.remaining == 2 && Near(m.frame.pose.rotations[4].z, 1.0));
    CHECK(session.HandleBinary(bin.data(), bin.size(), m, &err) && m.frame.pose.rotations.size() == 3);  // slot 5 as before
    const std::string frame5 = "{\"type\":\"frame\",\"character\":\"big\",\"slot\":9,\"seq\":1,\"t\":0.06666667,\"remaining\":1,"
                               "\"pose\":{\"root_position\":[0,1,2],\"rotations\":[[0,0,0,1],[0,0,0,1],[0,0,0,1],[0,0,0,1],[0,0,0,1]]}}";
    CHECK(session.HandleText(frame5.data(), frame5.size(), m, &err) && m.frame.pose.rotations.size() == 5);
    const std::string error = "{\"type\":\"error\",\"code\":\"unknown_style\",\"message\":\"no style\",\"character\":\"hero\"}";
    CHECK(session.HandleText(error.data(), error.size(), m, &err) && m.kind == MessageKind::Error && m.code == "unknown_style");
    // Client messages are valid JSON with the fields the server expects.
    StartOptions o;
    o.character = "hero";
    o.contextJson = BvhMotionJson("HIERARCHY\nROOT \"x\"\n");
    o.targetJson = PoseMotionJson({Vec3{0, 90, 0}}, {{Quat{0, 0, 0, 1}}});
    o.frames = 40;
    o.styleId = "sty_1";
    o.hasSeed = true;
    o.seed = 12345678901234ull;
    o.deterministic = true;
    o.exactArrival = true;
    JsonValue v;
    CHECK(ParseJson(BuildStart(o), v, &err));
    CHECK(v.StringOr("type", "") == "start" && v.Find("context")->StringOr("bvh", "") == "HIERARCHY\nROOT \"x\"\n");
    CHECK(Near(v.NumberOr("seed", 0), 12345678901234.0) && v.Find("deterministic")->boolean && v.Find("exact_arrival")->boolean);
    CHECK(v.Find("style_strength") == nullptr);  // not set: the server's
    o.hasStyleStrength = true;
    o.styleStrength = 1.25;
    CHECK(ParseJson(BuildStart(o), v, &err) && Near(v.NumberOr("style_strength", 0), 1.25));
    o.hasStyleStrength = false;
    o.targetAtJson = TargetAtJson(120.0, -30.5, 90.0);  // a place and facing instead of a pose
    CHECK(ParseJson(BuildStart(o), v, &err) && v.Find("target") == nullptr && v.Find("target_at") != nullptr);
    CHECK(Near(v.Find("target_at")->NumberOr("x", 0), 120.0) && Near(v.Find("target_at")->NumberOr("z", 0), -30.5));
    CHECK(Near(v.Find("target_at")->NumberOr("yaw", 0), 90.0));
    o.targetAtJson.clear();
    CHECK(ParseJson(BuildStart(o), v, &err));  // the pose target again, for the checks below
    CHECK(Near(v.Find("target")->Find("rotations")->array[0].array[0].array[3].number, 1.0));
    CHECK(ParseJson(BuildRetarget("hero", "", 20), v, &err) && v.Find("target") == nullptr && Near(v.NumberOr("frames", 0), 20));
    CHECK(ParseJson(BuildCancel("hero"), v, &err) && v.StringOr("type", "") == "cancel");
    CHECK(ParseJson(BuildPing("p1"), v, &err) && v.StringOr("id", "") == "p1");
    CHECK(ParseJson(BuildStyleRegistration("two", {BvhMotionJson("A"), BvhMotionJson("B")}), v, &err) &&
          v.StringOr("name", "") == "two" && v.Find("motions") != nullptr && v.Find("motions")->array.size() == 2 &&
          v.Find("motions")->array[1].StringOr("bvh", "") == "B" && v.Find("motion") == nullptr);
    CHECK(BuildStyleRegistration("none", {}).empty());
    CHECK(BuildStyleRegistration("six", std::vector<std::string>(6, BvhMotionJson("A"))).empty());
    // A layout that does not fit the skeleton is refused.
    Session other;
    std::string wrong = MakeHello(2);
    const std::string from = "\"count\":8}";
    wrong.replace(wrong.find(from), from.size(), "\"count\":9}");
    CHECK(!other.HandleText(wrong.data(), wrong.size(), m, &err));
}

static void TestReassembly() {
    MessageAssembler a(64);
    const std::string msg = "{\"type\":\"pong\",\"id\":\"0123456789\"}";
    MessageAssembler::Result r = MessageAssembler::Result::Partial;
    for (std::size_t i = 0; i < msg.size(); i += 5) {
        const std::size_t n = std::min<std::size_t>(5, msg.size() - i);
        r = a.Feed(msg.data() + i, n, msg.size() - i - n);
        CHECK((r == MessageAssembler::Result::Complete) == (i + n == msg.size()));
    }
    CHECK(r == MessageAssembler::Result::Complete && std::string(a.Data().begin(), a.Data().end()) == msg);
    CHECK(ClassifyMessage(a.Data().data(), a.Data().size()) == PayloadKind::Text);
    // The next message starts afresh.
    const std::uint8_t bin[8] = {0, 0, 0x80, 0x3f, 1, 2, 3, 4};
    CHECK(a.Feed(bin, 8, 0) == MessageAssembler::Result::Complete && a.Data().size() == 8);
    CHECK(ClassifyMessage(a.Data().data(), a.Data().size()) == PayloadKind::Binary);
    // Too large: dropped, reported once, and the assembler recovers.
    std::vector<std::uint8_t> big(100, 0);
    CHECK(a.Feed(big.data(), 50, 50) == MessageAssembler::Result::Partial);
    CHECK(a.Feed(big.data() + 50, 50, 0) == MessageAssembler::Result::TooLarge);
    CHECK(a.Feed(bin, 8, 0) == MessageAssembler::Result::Complete && a.Data().size() == 8);
    CHECK(a.FeedFragment(bin, 4, false) == MessageAssembler::Result::Partial);
    CHECK(a.FeedFragment(bin + 4, 4, true) == MessageAssembler::Result::Complete && a.Data().size() == 8);
    // Every float32 slot below 2^16 starts with a zero byte, never '{'.
    for (int slot = 0; slot < 65536; slot += 1) {
        const float f = static_cast<float>(slot);
        std::uint32_t bits;
        std::memcpy(&bits, &f, 4);
        if ((bits & 0xFFu) != 0u) {
            CHECK(false);
            break;
        }
    }
}

static Frame F(int seq, double x) {
    Frame f;
    f.seq = seq;
    f.t = (seq + 1) / 30.0;
    f.pose.root = Vec3{x, 0, 0};
    f.pose.rotations = {Quat{0, 0, 0, 1}};
    return f;
}

static void TestJitter() {
    JitterBuffer jb(0.1, 30.0);
    Pose p;
    CHECK(!jb.Sample(0.0, p));
    // Frames arrive in bursts and late; playback is steady at 30 fps, 0.1 s behind the first arrival.
    jb.Push(F(0, 0), 1.0);
    CHECK(!jb.Sample(1.05, p));                        // not due before 1.1
    CHECK(jb.Sample(1.1001, p) && Near(p.root.x, 0.0));  // frame 0 at 1.1
    jb.Push(F(1, 10), 1.12);
    jb.Push(F(2, 20), 1.13);
    CHECK(jb.Sample(1.1 + 0.5 / 30.0, p) && Near(p.root.x, 5.0, 1e-9));  // halfway 0 -> 1
    CHECK(jb.Sample(1.1 + 2.0 / 30.0 + 1e-6, p) && Near(p.root.x, 20.0, 1e-9) && jb.ShownSeq() == 2);
    CHECK(jb.Underruns() == 0);
    // Starved: hold the last pose, count one underrun, then re-buffer on the next frame.
    CHECK(jb.Sample(1.1 + 4.0 / 30.0, p) && Near(p.root.x, 20.0) && jb.Underruns() == 1);
    CHECK(jb.Sample(1.1 + 6.0 / 30.0, p) && jb.Underruns() == 1);
    const double now = 1.5;
    jb.Push(F(3, 30), now);
    CHECK(jb.Sample(now + 0.05, p) && Near(p.root.x, 20.0));        // re-buffering: still holding
    CHECK(jb.Sample(now + 0.1 + 1e-6, p) && Near(p.root.x, 30.0, 1e-9));  // frame 3 plays 0.1 s after it came
    // A long pause in updates (unfocused window): late frames are skipped, not replayed in a burst.
    for (int s = 4; s < 40; ++s) jb.Push(F(s, 10.0 * s), now + 0.1 + (s - 3) / 30.0);
    CHECK(jb.Sample(now + 0.1 + 30.0 / 30.0 + 1e-6, p) && jb.ShownSeq() == 33 && jb.Buffered() <= 7);
    jb.MarkEnded();
    CHECK(jb.Sample(now + 5.0, p) && jb.ShownSeq() == 39 && jb.Finished() && jb.Underruns() == 1);
    // A new transition starts over.
    jb.Reset();
    jb.Push(F(0, -1), 10.0);
    CHECK(jb.Sample(10.0, p) && Near(p.root.x, 390.0));  // holds the old pose until the new one is due
    CHECK(jb.Sample(10.1001, p) && Near(p.root.x, -1.0));
    // Duplicates and stale frames are dropped.
    jb.Push(F(0, 99), 10.2);
    CHECK(jb.Buffered() == 1);
}

// Failover without I/O (rsmt::Failover): what is resent after a lost connection, how resumed frames are numbered.
static Message FrameMsg(const std::string& cid, int seq, int remaining, double x) {
    Message m;
    m.kind = MessageKind::Frame;
    m.character = m.frame.character = cid;
    m.frame.seq = seq;
    m.frame.remaining = remaining;
    m.frame.pose.root = Vec3{x, 0, 0};
    m.frame.pose.rotations = {Quat{}};
    return m;
}

static Message Msg(MessageKind kind, const std::string& cid, const std::string& code = "") {
    Message m;
    m.kind = kind;
    m.character = cid;
    m.code = code;
    return m;
}

static std::vector<double> ContextXs(const std::string& start) {
    JsonValue v;
    std::vector<double> xs;
    if (!ParseJson(start, v)) return xs;
    for (const JsonValue& r : v.Find("context")->Find("root_positions")->array) xs.push_back(r.array[0].number);
    return xs;
}

static Failover MakeFailover() {
    Failover f;
    ModelInfo model;
    model.contextFrames = 4;
    model.joints.resize(1);
    f.SetModel(model);
    return f;
}

static void TestFailover() {
    std::vector<Vec3> roots;
    std::vector<std::vector<Quat>> rots;
    for (int i = 0; i < 6; ++i) {
        roots.push_back(Vec3{static_cast<double>(i), 0, 0});
        rots.push_back({Quat{}});
    }
    auto opts = [&](const std::string& cid, int n) {
        StartOptions o;
        o.character = cid;
        o.contextJson = PoseMotionJson(roots, rots);
        o.targetJson = "{\"bvh\":\"T\"}";
        o.frames = n;
        o.styleId = "sty_a";
        o.model = "m2";
        o.exactArrival = true;
        o.hasStyleStrength = true;
        o.styleStrength = 1.25;
        return o;
    };
    Failover f = MakeFailover();
    f.SentStart(opts("hero", 10));
    Message st = Msg(MessageKind::Started, "hero");
    f.Received(st);
    CHECK(!st.resumed && f.Live());
    for (int seq = 0; seq < 6; ++seq) {
        Message fm = FrameMsg("hero", seq, 9 - seq, 100.0 + seq);
        f.Received(fm);
    }
    std::vector<std::string> resume = f.ResumeMessages();
    CHECK(resume.size() == 1 && f.Resumes() == 1);
    JsonValue r;
    CHECK(ParseJson(resume[0], r));
    CHECK(r.NumberOr("frames", 0) == 4 && r.Find("target")->StringOr("bvh", "") == "T" && r.StringOr("style_id", "") == "sty_a");
    CHECK(r.StringOr("model", "") == "m2" && r.StringOr("character", "") == "hero" && r.Find("exact_arrival") != nullptr);
    CHECK(Near(r.NumberOr("style_strength", 0), 1.25));  // the resume keeps the style strength
    CHECK(r.Find("retargeted") == nullptr);  // never retargeted: a plain start
    CHECK((ContextXs(resume[0]) == std::vector<double>{102, 103, 104, 105}));
    st = Msg(MessageKind::Started, "hero");
    f.Received(st);
    CHECK(st.resumed);
    Message last;
    for (int seq = 0; seq < 4; ++seq) {
        last = FrameMsg("hero", seq, 3 - seq, 0);
        f.Received(last);
    }
    CHECK(last.frame.seq == 9 && std::fabs(last.frame.t - 10 / 30.0) < 1e-12);
    Message end = Msg(MessageKind::End, "hero");
    end.frames = 4;
    f.Received(end);
    CHECK(end.frames == 10 && !f.Live() && f.ResumeMessages().empty());

    Failover g = MakeFailover();  // fewer frames than the context: the original context's last poses first
    g.SentStart(opts("hero", 10));
    Message g0 = FrameMsg("hero", 0, 9, 50);
    g.Received(g0);
    CHECK((ContextXs(g.ResumeMessages()[0]) == std::vector<double>{3, 4, 5, 50}));
    Failover h = MakeFailover();  // a BVH context: the first received pose held
    StartOptions bvh = opts("hero", 10);
    bvh.contextJson = BvhMotionJson("HIERARCHY");
    h.SentStart(bvh);
    Message h0 = FrameMsg("hero", 0, 9, 50);
    h.Received(h0);
    CHECK((ContextXs(h.ResumeMessages()[0]) == std::vector<double>{50, 50, 50, 50}));

    Failover k = MakeFailover();  // retarget, style and cancel carried over
    k.SentStart(opts("a", 10));
    k.SentStart(opts("b", 10));
    k.SentCancel("b");
    for (int seq = 0; seq < 5; ++seq) {
        Message km = FrameMsg("a", seq, 9 - seq, seq);
        k.Received(km);
    }
    k.SentRetarget("a", "{\"bvh\":\"T2\"}", 20);
    k.SentStyle("a", "sty_b");
    std::vector<std::string> kr = k.ResumeMessages();
    JsonValue krj;
    CHECK(kr.size() == 1 && ParseJson(kr[0], krj) && krj.NumberOr("frames", 0) == 20 &&
          krj.Find("target")->StringOr("bvh", "") == "T2" && krj.StringOr("style_id", "") == "sty_b");
    CHECK(krj.Find("retargeted") != nullptr && krj.Find("retargeted")->boolean);  // a target changed mid-motion
    Message ke = Msg(MessageKind::Error, "a", "validation_error");  // a replica older than the option
    FailoverAction older = k.Received(ke);
    JsonValue oj;
    CHECK(!older.deliver && older.registerStyleBody.empty() && ParseJson(older.resend, oj) && oj.Find("retargeted") == nullptr &&
          oj.NumberOr("frames", 0) == 20 && oj.Find("target")->StringOr("bvh", "") == "T2");
    Message ke2 = Msg(MessageKind::Error, "a", "validation_error");
    CHECK(k.Received(ke2).deliver && !k.Live());  // refused again: the error is delivered
    Failover n = MakeFailover();  // a new target before any frame: resumed as a start to it, not a retarget
    n.SentStart(opts("a", 10));
    n.SentRetarget("a", "{\"bvh\":\"T2\"}", 0);
    JsonValue nj;
    CHECK(ParseJson(n.ResumeMessages()[0], nj) && nj.Find("target")->StringOr("bvh", "") == "T2" &&
          nj.Find("retargeted") == nullptr);
    Failover at = MakeFailover();  // a start to a place resumes to it; a pose retarget replaces the place
    StartOptions placed = opts("a", 10);
    placed.targetAtJson = TargetAtJson(50.0, 60.0, 90.0);
    at.SentStart(placed);
    JsonValue aj;
    CHECK(ParseJson(at.ResumeMessages()[0], aj) && aj.Find("target") == nullptr && Near(aj.Find("target_at")->NumberOr("yaw", 0), 90.0));
    at.SentRetarget("a", "{\"bvh\":\"T2\"}", 0);
    CHECK(ParseJson(at.ResumeMessages()[0], aj) && aj.Find("target_at") == nullptr && aj.Find("target")->StringOr("bvh", "") == "T2");

    Failover u = MakeFailover();  // unknown_style: register again, resend the start
    u.RememberStyle("sty_a", "{\"name\":\"walk\"}");
    u.SentStart(opts("hero", 10));
    Message ue = Msg(MessageKind::Error, "hero", "unknown_style");
    FailoverAction act = u.Received(ue);
    CHECK(!act.deliver && act.registerStyleBody == "{\"name\":\"walk\"}" && act.resend == BuildStart(opts("hero", 10)));
    Failover w = MakeFailover();  // a clip it never held: the error goes to the caller, nothing to resume
    w.SentStart(opts("hero", 10));
    Message we = Msg(MessageKind::Error, "hero", "unknown_style");
    CHECK(w.Received(we).deliver && !w.Live());
    CHECK(!Failover::Resumable(1008) && !Failover::Resumable(1009) && Failover::Resumable(1006) && Failover::Resumable(1001));
    CHECK(Failover::ReconnectDelay(0) == 0.25 && Failover::ReconnectDelay(1) == 0.5 && Failover::ReconnectDelay(40) == 4.0);
}

static int SelfTest() {
    TestFailover();
    TestJson();
    TestConversion();
    TestProtocol();
    TestReassembly();
    TestJitter();
    std::printf("{\"selftest\": {\"checks\": %d, \"failures\": %d}}\n", g_checks, g_failures);
    return g_failures == 0 ? 0 : 1;
}

static void PrintNumber(double v) { std::printf("%.17g", v); }  // round-trips exactly

static int Replay(const char* path, std::size_t chunk) {
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        std::fprintf(stderr, "cannot open %s\n", path);
        return 2;
    }
    const std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    Session session;
    MessageAssembler assembler(1u << 20);
    std::string err;
    std::size_t pos = 0;
    int frames = 0, texts = 0, binaries = 0, records = 0;
    double cmPerUnit = 1.0;
    while (pos + 5 <= bytes.size()) {
        const char kind = bytes[pos];
        const std::uint8_t* lp = reinterpret_cast<const std::uint8_t*>(&bytes[pos + 1]);
        const std::size_t length = static_cast<std::size_t>(lp[0]) | (static_cast<std::size_t>(lp[1]) << 8) |
                                   (static_cast<std::size_t>(lp[2]) << 16) | (static_cast<std::size_t>(lp[3]) << 24);
        pos += 5;
        if (pos + length > bytes.size()) {
            std::fprintf(stderr, "truncated record at byte %zu\n", pos);
            return 2;
        }
        const char* payload = &bytes[pos];
        pos += length;
        ++records;
        // Deliver it the way OnRawMessage does: pieces with the bytes still to come.
        MessageAssembler::Result r = MessageAssembler::Result::Partial;
        for (std::size_t off = 0; off < length || length == 0; off += chunk) {
            const std::size_t n = std::min(chunk, length - off);
            r = assembler.Feed(payload + off, n, length - off - n);
            if (length == 0) break;
        }
        if (r != MessageAssembler::Result::Complete) {
            std::fprintf(stderr, "record %d did not reassemble\n", records);
            return 1;
        }
        const std::vector<std::uint8_t>& msg = assembler.Data();
        const PayloadKind pk = ClassifyMessage(msg.data(), msg.size());
        if ((pk == PayloadKind::Text) != (kind == 'T')) {
            std::fprintf(stderr, "record %d classified wrongly\n", records);
            return 1;
        }
        Message m;
        const bool ok = pk == PayloadKind::Text
                            ? session.HandleText(reinterpret_cast<const char*>(msg.data()), msg.size(), m, &err)
                            : session.HandleBinary(msg.data(), msg.size(), m, &err);
        if (!ok) {
            std::fprintf(stderr, "record %d: %s\n", records, err.c_str());
            return 1;
        }
        if (pk == PayloadKind::Text) ++texts; else ++binaries;
        if (m.kind == MessageKind::Hello) {
            std::string why;
            if (!CheckModelConventions(session.GetHello().model, &why)) {
                std::fprintf(stderr, "unsupported model conventions: %s\n", why.c_str());
                return 1;
            }
            cmPerUnit = CentimetresPerUnit(session.GetHello().model.units);
            continue;
        }
        if (m.kind != MessageKind::Frame) {
            std::printf("{\"event\": \"%s\", \"character\": %s}\n", m.type.c_str(), JsonQuote(m.character).c_str());
            continue;
        }
        ++frames;
        const Pose ue = ModelToUnrealPose(m.frame.pose, cmPerUnit);
        std::printf("{\"frame\": %d, \"binary\": %s, \"character\": %s, \"slot\": %d, \"seq\": %d, \"t\": ", frames,
                    pk == PayloadKind::Binary ? "true" : "false", JsonQuote(m.frame.character).c_str(), m.frame.slot,
                    m.frame.seq);
        PrintNumber(m.frame.t);
        std::printf(", \"remaining\": %d, \"root\": [", m.frame.remaining);
        PrintNumber(ue.root.x); std::printf(", "); PrintNumber(ue.root.y); std::printf(", "); PrintNumber(ue.root.z);
        std::printf("], \"rotations\": [");
        for (std::size_t j = 0; j < ue.rotations.size(); ++j) {
            const Quat& q = ue.rotations[j];
            std::printf(j ? ", [" : "[");
            PrintNumber(q.x); std::printf(", "); PrintNumber(q.y); std::printf(", "); PrintNumber(q.z);
            std::printf(", "); PrintNumber(q.w); std::printf("]");
        }
        std::printf("]}\n");
    }
    std::printf("{\"summary\": {\"records\": %d, \"text\": %d, \"binary\": %d, \"frames\": %d, \"joints\": %d}}\n", records,
                texts, binaries, frames, session.Joints());
    return 0;
}

int main(int argc, char** argv) {
    if (argc >= 2 && std::strcmp(argv[1], "selftest") == 0) return SelfTest();
    if (argc >= 3 && std::strcmp(argv[1], "replay") == 0) {
        const std::size_t chunk = argc >= 4 ? static_cast<std::size_t>(std::strtoul(argv[3], nullptr, 10)) : 64;
        return Replay(argv[2], chunk > 0 ? chunk : 64);
    }
    if (argc >= 4 && std::strcmp(argv[1], "style-body") == 0) {  // the POST /v1/styles body of BVH files
        std::vector<std::string> motions;
        for (int i = 3; i < argc; ++i) {
            std::ifstream in(argv[i], std::ios::binary);
            motions.push_back(BvhMotionJson(std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>())));
        }
        const std::string body = BuildStyleRegistration(argv[2], motions);
        std::fwrite(body.data(), 1, body.size(), stdout);
        return body.empty() ? 1 : 0;
    }
    if (argc == 10 && std::strcmp(argv[1], "start-at") == 0) {  // a start message to a place and facing (pace asap)
        std::ifstream in(argv[3], std::ios::binary);
        if (!in) {
            std::fprintf(stderr, "cannot open %s\n", argv[3]);
            return 2;
        }
        StartOptions o;
        o.character = argv[2];
        o.contextJson = BvhMotionJson(std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()));
        o.frames = std::atoi(argv[4]);
        o.styleId = argv[5];
        o.hasSeed = true;
        o.seed = std::strtoull(argv[6], nullptr, 10);
        o.targetAtJson = TargetAtJson(std::strtod(argv[7], nullptr), std::strtod(argv[8], nullptr), std::strtod(argv[9], nullptr));
        o.pace = "asap";
        const std::string start = BuildStart(o);
        std::fwrite(start.data(), 1, start.size(), stdout);
        return 0;
    }
    std::fprintf(stderr, "usage: %s selftest | replay FILE.rec [CHUNK] | style-body NAME CLIP.bvh... | start-at CHARACTER "
                 "CONTEXT.bvh FRAMES STYLE_ID SEED X Z YAW\n", argv[0]);
    return 2;
}
