#pragma once
/// \file
/// Test helper: a rig recording rendered into a temporary directory (removed with the fixture) and its truth.

#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/rig/truth.hpp"

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace eyesim::fpga::test {

struct RigRecording {
    std::string dir;
    rig::Recording rec;
    std::vector<rig::FieldTruth> truth;

    /// `format`: "uyvy" (raw fields) or a video format (rig/video.hpp), as `eyesim synth --format`.
    RigRecording(const std::string& name, const std::string& scenario, double seconds, double noise_sigma,
                 uint64_t seed = 1, const std::string& format = "uyvy")
        : dir(make(name, scenario, seconds, noise_sigma, seed, format)), rec(rig::Recording::open(dir)),
          truth(rig::read_truth(rec.truth_path())) {}
    ~RigRecording() {
        std::error_code ec;
        std::filesystem::remove_all(dir, ec);
    }
    RigRecording(const RigRecording&) = delete;
    RigRecording& operator=(const RigRecording&) = delete;

private:
    static std::string make(const std::string& name, const std::string& scenario, double seconds, double noise,
                            uint64_t seed, const std::string& format) {
        const std::string d = (std::filesystem::temp_directory_path() / name).string();
        std::filesystem::remove_all(d);
        rig::SynthRequest req;
        req.out_dir = d;
        req.scenario = scenario;
        req.seconds = seconds;
        req.seed = seed;
        req.format = format;
        req.render.noise_sigma = noise;
        rig::write_recording(req);
        return d;
    }
};

}  // namespace eyesim::fpga::test
