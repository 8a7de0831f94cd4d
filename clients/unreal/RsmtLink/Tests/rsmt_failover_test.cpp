// The failover of RsmtCore (rsmt::Failover) against live servers, built with g++ by tests/clients/test_engine_failover.py.
//
//   rsmt_failover_test --context a.bvh --target b.bvh --target2 c.bvh --style-id ID --style-body body.json --frames 60
//                      [--characters 2] [--kill-after 12] [--failover] [--attempts 60]
//
// RsmtCore has no sockets (in Unreal, URsmtLinkComponent owns an IWebSocket), so the test's Python driver is the
// socket: it hands every received message over stdin, one line each ("T <hex>" text, "B <hex>" binary,
// "C <code>" the connection closed, "X" a reconnection attempt failed) and does what this program answers, one
// JSON line each, ending with {"next": true}: {"send": text}, {"register": body, "then": text} (POST /v1/styles,
// then send), {"reconnect": attempt, "delay": s} (wait, connect again to the same URL), {"kill": true} (the
// first character passed --kill-after frames), {"frame": ...} (Unreal axes, as delivered), {"started": ...},
// and last {"done": {...}}. Every decision (resume or not, backoff, what to resend, numbering) is RsmtCore's.
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <iterator>
#include <map>
#include <string>
#include <vector>

#include "RsmtConvert.h"
#include "RsmtFailover.h"
#include "RsmtJson.h"
#include "RsmtProtocol.h"

using namespace rsmt;

namespace {

std::string ReadFile(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

std::vector<std::uint8_t> Unhex(const std::string& hex) {
    std::vector<std::uint8_t> out;
    for (std::size_t i = 0; i + 1 < hex.size(); i += 2)
        out.push_back(static_cast<std::uint8_t>(std::strtoul(hex.substr(i, 2).c_str(), nullptr, 16)));
    return out;
}

void Emit(const std::string& line) {
    std::fputs(line.c_str(), stdout);
    std::fputc('\n', stdout);
}

std::string FrameJson(const Frame& f, double cmPerUnit) {
    const Pose ue = ModelToUnrealPose(f.pose, cmPerUnit);
    std::string s = "{\"frame\":{\"character\":" + JsonQuote(f.character) + ",\"seq\":" + std::to_string(f.seq) +
                    ",\"t\":" + JsonNumber(f.t) + ",\"remaining\":" + std::to_string(f.remaining) + ",\"root\":[" +
                    JsonNumber(ue.root.x) + "," + JsonNumber(ue.root.y) + "," + JsonNumber(ue.root.z) + "],\"rotations\":[";
    for (std::size_t j = 0; j < ue.rotations.size(); ++j) {
        const Quat& q = ue.rotations[j];
        s += (j ? ",[" : "[") + JsonNumber(q.x) + "," + JsonNumber(q.y) + "," + JsonNumber(q.z) + "," + JsonNumber(q.w) + "]";
    }
    return s + "]}}";
}

}  // namespace

int main(int argc, char** argv) {
    std::map<std::string, std::string> a;
    for (int i = 1; i < argc; ++i) {
        const std::string key = argv[i] + 2;
        a[key] = (i + 1 < argc && std::strncmp(argv[i + 1], "--", 2) != 0) ? argv[++i] : "true";
    }
    const std::string targets[2] = {ReadFile(a["target"]), ReadFile(a.count("target2") ? a["target2"] : a["target"])};
    const std::string context = ReadFile(a["context"]);
    const int frames = std::atoi(a["frames"].c_str());
    const int count = a.count("characters") ? std::atoi(a["characters"].c_str()) : 2;
    const int killAfter = a.count("kill-after") ? std::atoi(a["kill-after"].c_str()) : 12;
    const int attempts = a.count("attempts") ? std::atoi(a["attempts"].c_str()) : 8;
    const bool failover = a.count("failover") > 0;

    Failover state;
    state.RememberStyle(a["style-id"], ReadFile(a["style-body"]));
    Session session;
    double cmPerUnit = 1.0;
    bool started = false, killed = false, resumeOnHello = false;
    int attempt = 0, ended = 0, closed = 0, received0 = 0;
    std::vector<std::string> errors;

    std::string line;
    while (std::getline(std::cin, line)) {
        const char kind = line.empty() ? '?' : line[0];
        if (kind == 'C' || kind == 'X') {
            const int code = kind == 'C' ? std::atoi(line.c_str() + 2) : 1006;
            if (kind == 'C') attempt = 0;
            if (failover && Failover::Resumable(code) && state.Live() && attempt < attempts) {
                session = Session();  // the new connection begins with its own hello
                resumeOnHello = true;
                Emit("{\"reconnect\":" + std::to_string(attempt) + ",\"delay\":" +
                     JsonNumber(Failover::ReconnectDelay(attempt, 0.25, 1.0)) + "}");
                ++attempt;
            } else {
                closed = code;
                break;
            }
            Emit("{\"next\":true}");
            std::fflush(stdout);
            continue;
        }
        const std::vector<std::uint8_t> data = Unhex(line.size() > 2 ? line.substr(2) : std::string());
        Message m;
        std::string err;
        const bool ok = kind == 'T' ? session.HandleText(reinterpret_cast<const char*>(data.data()), data.size(), m, &err)
                                    : session.HandleBinary(data.data(), data.size(), m, &err);
        if (!ok) {
            errors.push_back("protocol: " + err);
            break;
        }
        if (m.kind == MessageKind::Hello) {
            cmPerUnit = CentimetresPerUnit(session.GetHello().model.units);
            state.SetModel(session.GetHello().model);
            if (!started) {
                started = true;
                for (int i = 0; i < count; ++i) {
                    StartOptions o;
                    o.character = "f" + std::to_string(i);
                    o.contextJson = BvhMotionJson(context);
                    o.targetJson = BvhMotionJson(targets[i % 2]);
                    o.frames = frames;
                    o.styleId = a["style-id"];
                    o.hasSeed = true;
                    o.seed = static_cast<std::uint64_t>(i);
                    o.exactArrival = true;
                    if (failover) state.SentStart(o);
                    Emit("{\"send\":" + JsonQuote(BuildStart(o)) + "}");
                }
            } else if (resumeOnHello) {
                for (const std::string& text : state.ResumeMessages()) Emit("{\"send\":" + JsonQuote(text) + "}");
            }
            resumeOnHello = false;
        } else {
            FailoverAction action;
            if (failover) action = state.Received(m);
            if (!action.deliver) {
                Emit("{\"register\":" + JsonQuote(action.registerStyleBody) + ",\"then\":" + JsonQuote(action.resend) + "}");
            } else if (m.kind == MessageKind::Frame) {
                Emit(FrameJson(m.frame, cmPerUnit));
                if (m.frame.character == "f0" && ++received0 >= killAfter && !killed) {
                    killed = true;
                    Emit("{\"kill\":true}");
                }
            } else if (m.kind == MessageKind::Started) {
                Emit("{\"started\":{\"character\":" + JsonQuote(m.character) + ",\"resumed\":" + (m.resumed ? "true" : "false") + "}}");
            } else if (m.kind == MessageKind::End) {
                Emit("{\"end\":{\"character\":" + JsonQuote(m.character) + ",\"frames\":" + std::to_string(m.frames) +
                     ",\"reason\":" + JsonQuote(m.reason) + "}}");
                if (++ended == count) break;
            } else if (m.kind == MessageKind::Error) {
                errors.push_back(m.character + " " + m.code + ": " + m.message);
                break;
            }
        }
        Emit("{\"next\":true}");
        std::fflush(stdout);
    }
    std::string errs = "[";
    for (std::size_t i = 0; i < errors.size(); ++i) errs += (i ? "," : "") + JsonQuote(errors[i]);
    Emit("{\"done\":{\"resumes\":" + std::to_string(state.Resumes()) + ",\"reregistrations\":" +
         std::to_string(state.Reregistrations()) + ",\"closed\":" + (closed ? std::to_string(closed) : "null") +
         ",\"errors\":" + errs + "]}}");
    std::fflush(stdout);
    return 0;
}
