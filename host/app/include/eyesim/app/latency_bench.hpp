#pragma once
/// \file
/// The latency regression harness behind `eyesim bench latency`: fixed scenes driven by the synthetic rig's
/// marker images (truth centroids with sensor-like noise, framed as FieldMarkers) through the real tracker and
/// simulator; every stage timed per frame; the result expressed as ratios to a calibration workload measured in
/// the same run, so a slower or faster machine does not move the ratios; compared with a committed baseline.

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace eyesim::app {

/// Settings of one harness run.
struct LatencyBenchOptions {
    std::vector<std::string> scenes;     ///< scene files (default: the four shipped scenes)
    double seconds = 2.0;                ///< simulated time per scene (50 frames per second)
    int repeats = 3;                     ///< each scene is run this often; the fastest repeat is kept
    double inject_collision_us = 0.0;    ///< fault injection for the harness's own test: busy time added to
                                         ///< the collision stage of every frame
};

/// Measures; returns a JSON object: calibration_us, per scene per stage p50/p99 µs and the ratio
/// host-compute-p50 / calibration.
nlohmann::json run_latency_bench(const LatencyBenchOptions& opt);

/// Compares `current` with `baseline`; returns the scenes whose ratio grew by more than `tolerance` (0.3 =
/// 30 %) as one line each, empty when none did.
std::vector<std::string> latency_regressions(const nlohmann::json& current, const nlohmann::json& baseline,
                                             double tolerance);

/// The calibration workload (fixed, independent of eyesim's code): the fastest of 31 runs of a dense 96×96 LU
/// solve and a 32k-element sort, µs.
double calibration_us();

}  // namespace eyesim::app
