#include "RsmtMotionCut.h"

#include <cmath>
#include <cstdlib>
#include <sstream>
#include <vector>

#include "RsmtProtocol.h"

namespace rsmt {
namespace {

struct BvhParts {
    std::string header;     // HIERARCHY ... up to MOTION
    std::string frameTime;  // the number as written
    std::vector<std::string> frames;
};

std::string Trim(const std::string& s) {
    std::size_t a = s.find_first_not_of(" \t\r");
    if (a == std::string::npos) return std::string();
    std::size_t b = s.find_last_not_of(" \t\r");
    return s.substr(a, b - a + 1);
}

std::string Lower(std::string s) {
    for (char& c : s) {
        if (c >= 'A' && c <= 'Z') c = static_cast<char>(c - 'A' + 'a');
    }
    return s;
}

bool Fail(std::string* error, const std::string& why) {
    if (error) *error = "BVH: " + why;
    return false;
}

bool Split(const std::string& bvh, BvhParts& parts, std::string* error) {
    std::vector<std::string> lines;
    std::size_t at = 0;
    while (at <= bvh.size()) {
        std::size_t nl = bvh.find('\n', at);
        if (nl == std::string::npos) nl = bvh.size();
        std::string line = bvh.substr(at, nl - at);
        if (!line.empty() && line.back() == '\r') line.pop_back();
        lines.push_back(line);
        at = nl + 1;
    }
    std::size_t motion = lines.size();
    for (std::size_t i = 0; i < lines.size(); ++i) {
        if (Lower(Trim(lines[i])) == "motion") {
            motion = i;
            break;
        }
    }
    if (motion == lines.size()) return Fail(error, "no MOTION line");
    long channels = 0;
    for (std::size_t i = 0; i < motion; ++i) {
        std::istringstream words(lines[i]);
        std::string word, count;
        if (words >> word && Lower(word) == "channels" && words >> count) channels += std::strtol(count.c_str(), nullptr, 10);
        parts.header += (i ? "\n" : "") + lines[i];
    }
    long declared = -1;
    std::size_t i = motion + 1;
    for (; i < lines.size() && (declared < 0 || parts.frameTime.empty()); ++i) {
        std::string line = Trim(lines[i]);
        if (line.empty()) continue;
        std::size_t colon = line.find(':');
        if (colon == std::string::npos) return Fail(error, "expected Frames: and Frame Time:");
        std::string key;
        for (char c : line.substr(0, colon)) {
            if (c != ' ' && c != '\t') key += c;
        }
        std::string value = Trim(line.substr(colon + 1));
        if (Lower(key) == "frames") declared = std::strtol(value.c_str(), nullptr, 10);
        else if (Lower(key) == "frametime") parts.frameTime = value;
        else return Fail(error, "unexpected " + line);
    }
    if (declared < 0 || parts.frameTime.empty()) return Fail(error, "no Frames: or Frame Time: line");
    std::vector<std::string> tokens;
    for (; i < lines.size(); ++i) {
        std::istringstream words(lines[i]);
        std::string word;
        while (words >> word) tokens.push_back(word);
    }
    if (channels > 0 && static_cast<long>(tokens.size()) < declared * channels) return Fail(error, "fewer values than Frames: says");
    for (long f = 0; f < declared; ++f) {
        std::string row;
        for (long c = 0; c < channels; ++c) {
            if (c) row += ' ';
            row += tokens[static_cast<std::size_t>(f * channels + c)];
        }
        parts.frames.push_back(row);
    }
    return true;
}

double FpsOf(const std::string& frameTime) {
    double fps = 1.0 / std::strtod(frameTime.c_str(), nullptr);
    double whole = std::round(fps);
    return whole >= 1.0 && std::fabs(fps - whole) <= 1e-4 * fps ? whole : fps;
}

}  // namespace

MotionLimits LimitsOf(const ModelInfo& model) {
    MotionLimits out;
    out.fps = model.fps;
    out.contextFrames = model.contextFrames;
    out.styleMaxFrames = model.styleMaxFrames;
    out.valid = model.contextFrames > 0 && model.styleMaxFrames > 0 && model.fps > 0.0;
    return out;
}

bool BvhMeasure(const std::string& bvh, int& frames, double& fps, std::string* error) {
    BvhParts parts;
    if (!Split(bvh, parts, error)) return false;
    frames = static_cast<int>(parts.frames.size());
    fps = FpsOf(parts.frameTime);
    if (!(fps > 0.0) || !std::isfinite(fps)) return Fail(error, "Frame Time must be a positive number");
    return true;
}

bool BvhWindow(const std::string& bvh, int start, int count, std::string& out, std::string* error) {
    BvhParts parts;
    if (!Split(bvh, parts, error)) return false;
    if (start < 0 || count < 1 || static_cast<std::size_t>(start + count) > parts.frames.size())
        return Fail(error, "frames outside the take");
    out = parts.header + "\nMOTION\nFrames: " + std::to_string(count) + "\nFrame Time: " + parts.frameTime + "\n";
    for (int f = start; f < start + count; ++f) out += parts.frames[static_cast<std::size_t>(f)] + "\n";
    return true;
}

int ResampledFrames(int frames, double sourceFps, double fps) {
    return frames > 0 ? static_cast<int>(std::floor((frames - 1) * fps / sourceFps + 1e-9)) + 1 : 0;
}

int FramesFor(int frames, double sourceFps, double fps) {
    int n = static_cast<int>(std::ceil((frames - 1) * sourceFps / fps - 1e-9)) + 1;
    if (n < 1) n = 1;
    while (ResampledFrames(n, sourceFps, fps) < frames) ++n;
    return n;
}

int FramesWithin(int frames, double sourceFps, double fps) {
    int n = static_cast<int>(std::floor(frames * sourceFps / fps + 1e-9));
    if (n < 1) n = 1;
    while (n > 1 && ResampledFrames(n, sourceFps, fps) > frames) --n;
    return n;
}

std::string MotionCutter::Context(const std::string& bvh) const {
    return limits_.valid ? Tail(bvh, limits_.contextFrames) : bvh;
}

std::string MotionCutter::Target(const std::string& bvh) const {
    return limits_.valid ? Tail(bvh, kTargetFrames) : bvh;
}

std::string MotionCutter::Tail(const std::string& bvh, int want) const {
    int total = 0;
    double fps = 0.0;
    if (!BvhMeasure(bvh, total, fps, nullptr)) return bvh;
    int keep = FramesFor(want, fps, limits_.fps);
    std::string out;
    return total > keep && BvhWindow(bvh, total - keep, keep, out, nullptr) ? out : bvh;
}

std::string MotionCutter::Style(const std::string& bvh) {
    int total = 0;
    double fps = 0.0;
    if (!limits_.valid || !BvhMeasure(bvh, total, fps, nullptr)) return bvh;
    if (ResampledFrames(total, fps, limits_.fps) <= limits_.styleMaxFrames) return bvh;
    int keep = FramesWithin(limits_.styleMaxFrames, fps, limits_.fps);
    int start = (total - keep) / 2;
    std::string out;
    if (!BvhWindow(bvh, start, keep, out, nullptr)) return bvh;
    if (!noticed_) {
        noticed_ = true;
        if (notice_) {
            std::ostringstream say;
            say << "style clip of " << total << " frames at " << fps << " fps: the model reads at most "
                << limits_.styleMaxFrames << " at " << limits_.fps << " fps; sending the middle " << keep << " (frames "
                << start << "-" << (start + keep - 1) << "). Cut it yourself to choose the part (rsmt::BvhWindow); said once.";
            notice_(say.str());
        }
    }
    return out;
}

}  // namespace rsmt
