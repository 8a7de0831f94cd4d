// Check of RsmtPoseCapture without Unreal (built with g++ by tests/clients/test_pose_capture.py).
//
//   rsmt_pose_test CASE.json     prints one JSON object:
//     exact:       Motion JSON of FromUnrealLocal(case.unreal_local, case.unreal_root)
//     unreal_fk:   component-space positions by forward kinematics over case.unreal_offsets and case.unreal_local
//     retarget:    Motion JSON of FromUnrealWorld(case.game_world, ...) with RetargetOffsets(case.game_reference_world,
//                  the reference pose read from case.reference_path)
//     turn_left:   FromUnrealLocal of one joint turned -90 degrees about Z (a +Y-facing character toward its left, +X)
//     history:     the history's Motion JSON after adding case.history poses
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "RsmtJson.h"
#include "RsmtPoseCapture.h"
#include "RsmtProtocol.h"

using namespace rsmt;

static Quat Q(const JsonValue& v) { return Quat{v.array[0].number, v.array[1].number, v.array[2].number, v.array[3].number}; }
static Vec3 V(const JsonValue& v) { return Vec3{v.array[0].number, v.array[1].number, v.array[2].number}; }

static std::vector<Quat> Quats(const JsonValue* v) {
    std::vector<Quat> out;
    for (const JsonValue& q : v->array) out.push_back(Q(q));
    return out;
}

static std::string Motion(const Pose& p) {
    return PoseMotionJson({p.root}, {p.rotations});
}

static std::string ReadFile(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

int main(int argc, char** argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: rsmt_pose_test CASE.json\n");
        return 2;
    }
    JsonValue c;
    std::string error;
    if (!ParseJson(ReadFile(argv[1]), c, &error)) {
        std::fprintf(stderr, "bad case: %s\n", error.c_str());
        return 2;
    }
    const double s = c.NumberOr("cm_per_unit", 1.0);
    std::vector<int> parents;
    for (const JsonValue& p : c.Find("parents")->array) parents.push_back(static_cast<int>(p.number));
    std::string out = "{";

    const std::vector<Quat> local = Quats(c.Find("unreal_local"));
    const Vec3 root = V(*c.Find("unreal_root"));
    out += "\"exact\":" + Motion(FromUnrealLocal(local, root, s));

    const std::vector<Quat> world = WorldRotations(local, parents);
    const std::vector<JsonValue>& offsets = c.Find("unreal_offsets")->array;
    std::vector<Vec3> pos(local.size());
    out += ",\"unreal_fk\":[";
    for (std::size_t j = 0; j < local.size(); ++j) {
        if (parents[j] < 0) {
            pos[j] = root;
        } else {
            const std::size_t p = static_cast<std::size_t>(parents[j]);
            const Vec3 o = Rotate(world[p], V(offsets[j]));
            pos[j] = Vec3{pos[p].x + o.x, pos[p].y + o.y, pos[p].z + o.z};
        }
        out += std::string(j ? "," : "") + "[" + JsonNumber(pos[j].x) + "," + JsonNumber(pos[j].y) + "," + JsonNumber(pos[j].z) + "]";
    }
    out += "]";

    ReferencePose ref;
    if (!ParseReferencePose(ReadFile(c.StringOr("reference_path", "")), ref, &error)) {
        std::fprintf(stderr, "bad reference pose: %s\n", error.c_str());
        return 1;
    }
    const std::vector<Quat> offsetsC = RetargetOffsets(Quats(c.Find("game_reference_world")), ref.worldRotations);
    out += ",\"retarget\":" + Motion(FromUnrealWorld(Quats(c.Find("game_world")), V(*c.Find("game_root")), ref.parents, offsetsC, s));
    out += ",\"reference_names\":[";
    for (std::size_t j = 0; j < ref.names.size(); ++j) out += std::string(j ? "," : "") + JsonQuote(ref.names[j]);
    out += "]";

    const double h = -std::acos(-1.0) / 4.0;
    out += ",\"turn_left\":" + Motion(FromUnrealLocal({Quat{0.0, 0.0, std::sin(h), std::cos(h)}}, Vec3{10.0, 30.0, 20.0}, s));

    PoseHistory history(c.NumberOr("history_fps", 30.0), 16);
    for (const JsonValue& item : c.Find("history")->array) {
        Pose p;
        p.root = V(*item.Find("root"));
        p.rotations = Quats(item.Find("rotations"));
        history.Add(item.NumberOr("t", 0.0), p);
    }
    out += ",\"history_count\":" + std::to_string(history.Count());
    out += ",\"history\":" + history.MotionJson(static_cast<int>(c.NumberOr("history_frames", 10.0)));
    std::printf("%s}\n", out.c_str());
    return 0;
}
