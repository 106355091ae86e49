#pragma once
/// \file
/// Test helper: a rig recording rendered into a temporary directory (removed with the fixture) and its truth.

#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/rig/truth.hpp"

#include <filesystem>
#include <string>
#include <vector>

namespace eyesim::fpga::test {

struct RigRecording {
    std::string dir;
    rig::Recording rec;
    std::vector<rig::FieldTruth> truth;

    RigRecording(const std::string& name, const std::string& scenario, double seconds, double noise_sigma)
        : dir(make(name, scenario, seconds, noise_sigma)), rec(rig::Recording::open(dir)),
          truth(rig::read_truth(rec.truth_path())) {}
    ~RigRecording() {
        std::error_code ec;
        std::filesystem::remove_all(dir, ec);
    }
    RigRecording(const RigRecording&) = delete;
    RigRecording& operator=(const RigRecording&) = delete;

private:
    static std::string make(const std::string& name, const std::string& scenario, double seconds, double noise) {
        const std::string d = (std::filesystem::temp_directory_path() / name).string();
        std::filesystem::remove_all(d);
        rig::SynthRequest req;
        req.out_dir = d;
        req.scenario = scenario;
        req.seconds = seconds;
        req.render.noise_sigma = noise;
        rig::write_recording(req);
        return d;
    }
};

}  // namespace eyesim::fpga::test
