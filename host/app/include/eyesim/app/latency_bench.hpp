#pragma once
/// \file
/// The latency regression harness behind `eyesim bench latency`: fixed scenes driven by the synthetic rig's
/// marker images (truth centroids with sensor-like noise, framed as FieldMarkers) through the real tracker and
/// simulator, every stage timed per frame, the result expressed as ratios to a calibration workload measured in
/// the same run and compared with a committed baseline.
///
/// The statistic is built to reject interference from other processes, which only ever adds time, and to
/// follow the machine's changes of speed (on a shared VM, up to 1.5× for stretches of a tenth of a second to many
/// seconds, and unequal for different kinds of code):
/// - the scenes run round robin, one pass of each per round, with calibration runs after every pass, so every
///   scene and the calibration sample the same stretch of time (a tiny scene run in one block would see one state);
/// - a pass is deterministic (same marker images, fresh tracker and simulator), so frame i of every pass does the
///   same work: each frame's fastest pass is kept, and a stage's figure is the mean over frames of those minima;
/// - before every pass, blocks of pseudo-random sizes are allocated and held, so that the passes' arrays land at
///   other addresses each time (without it a process whose allocations land badly is 10–25 % slower in a stage
///   in every pass, which no minimum over passes can reject; 4 of 30 unchanged runs showed it);
/// - each stage is a ratio to the calibration kernel whose speed follows that stage's most closely (CalKernel),
///   taken as the fastest of all its runs;
/// - the gate (run_latency_gate) measures a scene with a regression again, in a fresh process from the command
///   line, and fails only when every measurement shows it.

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include <array>
#include <cstddef>
#include <functional>
#include <string>
#include <vector>

namespace eyesim::app {

/// Settings of one harness run.
struct LatencyBenchOptions {
    std::vector<std::string> scenes;     ///< scene files (default: the four shipped scenes)
    double seconds = 2.0;                ///< simulated time per scene (50 frames per second)
    int repeats = 40;                    ///< passes per scene (round robin); each frame's fastest pass is kept
    int calibration_pieces = 4;          ///< calibration pieces after every scene pass
    double inject_collision_us = 0.0;    ///< fault injection: busy time added to every frame's collision stage
    double inject_slowdown = 0.0;        ///< fault injection: after the clean passes, the same number of passes
                                         ///< again with real work (dense matrix-vector products, timed beside
                                         ///< the kernels) in the collision stage taking this fraction of each
                                         ///< frame's clean host compute (0.3: every frame 30 % slower); real work
                                         ///< slows down with the machine as code does, a busy wait would not;
                                         ///< the result is the slowed passes
    bool shuffle_heap = true;            ///< hold blocks of pseudo-random sizes during each pass (off: diagnosis)
};

/// Measures; returns a JSON object: `calibration` (per kernel the fastest run `us`), per scene per stage
/// (tracking, collision, tissue, geometry_transfer, misc) the mean over frames of the per-frame minima `us`, the
/// p50/p99 of those minima, the kernel it is compared with and its `ratio` (us ÷ that kernel's us); per scene
/// `host_compute` (tracking + collision + tissue): `us` the sum of the three, p50/p99 of the per-frame minima of
/// the sum, and `ratio` = us ÷ the sum of the three kernels' us; the scene's `ratio` is host_compute's; with fault
/// injection, `injected_us` (the mean busy time per frame); `file`, the scene file.
nlohmann::json run_latency_bench(const LatencyBenchOptions& opt);

/// One row of the gate: a stage of a scene (or its host compute), now and in the baseline.
struct LatencyComparison {
    std::string scene;
    std::string stage;         ///< "host_compute", "tracking", "collision" or "tissue"
    double baseline_ratio = 0; ///< the baseline's ratio
    double current_ratio = 0;  ///< this run's ratio; for host compute the stages' ratios are weighted with the
                               ///< baseline's kernel times, so that a change of one stage moves host compute by
                               ///< its share of the baseline's host compute
    double baseline_us = 0;    ///< the baseline's time
    double current_us = 0;     ///< this run's time at the baseline's speed (ratio × the baseline's kernel time)
    bool gated = false;        ///< whether the row can fail the gate (host compute; stages of a large enough share)
    bool regression = false;   ///< gated and grown by more than the tolerance
    /// Relative change (0.05 = +5 %); 0 when both are 0, +inf when only the baseline is 0.
    double change() const;
};

/// A stage is gated on its own when its baseline time is at least this share of the scene's host compute.
inline constexpr double kStageGateShare = 0.10;

/// Compares `current` with `baseline`, scene by scene (the baseline's scenes that were measured): host compute
/// (always gated), then tracking, collision and tissue (gated when at least kStageGateShare of the baseline's host
/// compute). Throws Error on a baseline without the fields of this harness's output.
std::vector<LatencyComparison> compare_latency(const nlohmann::json& current, const nlohmann::json& baseline,
                                               double tolerance);

/// The gate: one line per regression and per baseline scene not measured; empty when it passes.
std::vector<std::string> latency_regressions(const nlohmann::json& current, const nlohmann::json& baseline,
                                             double tolerance);

/// The gate's verdict after confirmation.
struct LatencyGateResult {
    nlohmann::json current;                  ///< the measurement (per stage, the attempt with the lower ratio)
    std::vector<LatencyComparison> rows;     ///< compare_latency(current, baseline)
    std::vector<std::string> regressions;    ///< latency_regressions(current, baseline); empty: passed
    int attempts = 1;                        ///< measurements made
};

/// Measures one set of scenes (the options' scenes, their other settings unchanged).
using LatencyMeasure = std::function<nlohmann::json(const LatencyBenchOptions&)>;

/// The gate: measures with `measure`; while a gated row has regressed and fewer than `attempts` measurements were
/// made, measures the scenes with a regression again and keeps, for each of their stages, the lower of the
/// ratios. A slow stretch of the machine or an unlucky placement in memory only ever adds time and rarely lasts
/// into the next measurement, while a real slowdown is there in every one. `measure` defaults to
/// run_latency_bench in this process; `eyesim bench latency` measures the repeats in a fresh process.
LatencyGateResult run_latency_gate(const LatencyBenchOptions& opt, const nlohmann::json& baseline, double tolerance,
                                   int attempts, const LatencyMeasure& measure = run_latency_bench);

/// The calibration workload: three fixed kernels, independent of eyesim's code. A slow stretch of the machine slows
/// memory-bound code more than compute-bound code, so one kernel cannot stand for every stage; each stage is
/// compared with the kernel whose speed followed it most closely over runs on the loaded development machine:
/// - `dense`: a 48×48 dense LU solve (collision, geometry transfer);
/// - `geometry`: sorting 2048 floats and 600 small rotation updates (atan2, sin, 3×3 products) (tracking, misc);
/// - `springs`: one force pass of 9000 springs over 3000 shuffled nodes, gathers and scatters (tissue).
enum class CalKernel : int { kDense = 0, kGeometry, kSprings, kCount };

/// Name of a kernel ("dense", "geometry", "springs").
const char* to_string(CalKernel k);

class CalibrationWorkload {
public:
    CalibrationWorkload();
    /// Runs every kernel once; their wall times, µs.
    std::array<double, size_t(CalKernel::kCount)> run_us();

private:
    Eigen::MatrixXd a0_, a_;
    Eigen::VectorXd b0_, b_;
    std::vector<float> v0_, v_;
    std::vector<float> px_, py_, pz_, fx_, fy_, fz_;
    std::vector<unsigned> si_, sj_;
    double sink_ = 0;
};

}  // namespace eyesim::app
