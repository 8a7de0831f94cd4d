// RsmtCore's motion cuts from the command line, for tests/clients/test_motion_cuts.py:
//   rsmt_cut_tool context|target|style FPS CONTEXT_FRAMES STYLE_MAX IN.bvh OUT.bvh
// writes the cut BVH, prints {"frames": N, "bytes": B} and, on stderr, the notice (once, for a style clip cut twice).
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>

#include "RsmtMotionCut.h"

int main(int argc, char** argv) {
    if (argc != 7) {
        std::cerr << "usage: rsmt_cut_tool context|target|style FPS CONTEXT_FRAMES STYLE_MAX IN.bvh OUT.bvh\n";
        return 2;
    }
    rsmt::MotionLimits limits;
    limits.valid = true;
    limits.fps = std::strtod(argv[2], nullptr);
    limits.contextFrames = static_cast<int>(std::strtol(argv[3], nullptr, 10));
    limits.styleMaxFrames = static_cast<int>(std::strtol(argv[4], nullptr, 10));
    std::ifstream in(argv[5], std::ios::binary);
    std::stringstream text;
    text << in.rdbuf();
    rsmt::MotionCutter cutter(limits);
    cutter.SetNotice([](const std::string& note) { std::cerr << "notice: " << note << "\n"; });
    const std::string what = argv[1], bvh = text.str();
    std::string cut;
    if (what == "context") cut = cutter.Context(bvh);
    else if (what == "target") cut = cutter.Target(bvh);
    else {
        cutter.Style(bvh);  // twice: the notice comes once
        cut = cutter.Style(bvh);
    }
    std::ofstream(argv[6], std::ios::binary) << cut;
    int frames = 0;
    double fps = 0.0;
    std::string error;
    if (!rsmt::BvhMeasure(cut, frames, fps, &error)) {
        std::cerr << error << "\n";
        return 1;
    }
    std::cout << "{\"frames\": " << frames << ", \"bytes\": " << cut.size() << "}\n";
    return 0;
}
