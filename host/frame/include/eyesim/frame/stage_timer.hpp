#pragma once
/// \file
/// Per-stage wall-clock timers of the host frame loop, recorded per frame into pre-reserved arrays, summarised
/// as percentiles (the paper's Table 4 rows: tracking, collision, tissue, geometry transfer, misc, render).

#include <array>
#include <chrono>
#include <cstddef>
#include <vector>

namespace eyesim::frame {

/// The Table-4 stages.
enum class Stage : int { kTracking = 0, kCollision, kTissue, kTransfer, kMisc, kRender, kCount };

/// Name of a stage ("tracking", "collision", …).
const char* to_string(Stage s);

/// Percentiles of one stage, µs.
struct StageSummary {
    double p50_us = 0, p90_us = 0, p99_us = 0, max_us = 0, mean_us = 0;
};

/// Records one time per stage per frame.
class StageTimer {
public:
    using Clock = std::chrono::steady_clock;

    /// Reserves room for `frames` frames (recording beyond it still works but allocates).
    explicit StageTimer(size_t frames = 1 << 16);

    /// Starts a new frame row (all stages zero).
    void begin_frame();
    /// Adds `us` to a stage of the current frame.
    void add(Stage s, double us) { current_[size_t(s)] += us; }
    /// Closes the current frame row.
    void end_frame();
    /// Adds `us` to a stage of closed frame `frame` (e.g. a picture of that frame rendered later).
    void add_to_row(size_t frame, Stage s, double us) {
        if (frame < rows_.size()) rows_[frame][size_t(s)] += us;
    }

    /// Frames recorded.
    size_t frames() const { return rows_.size(); }
    /// Stage times of frame i, µs.
    const std::array<double, size_t(Stage::kCount)>& row(size_t i) const { return rows_[i]; }
    /// Percentiles of one stage over all frames.
    StageSummary summary(Stage s) const;
    /// Percentiles of one stage over the frames where it ran (time > 0), e.g. rendering on snapshot frames.
    StageSummary summary_where_ran(Stage s) const;
    /// Percentiles of the sum of the given stages per frame.
    StageSummary summary_of_sum(std::initializer_list<Stage> stages) const;

private:
    std::vector<std::array<double, size_t(Stage::kCount)>> rows_;
    std::array<double, size_t(Stage::kCount)> current_{};
};

/// Measures a scope and adds it to a stage.
class ScopedStage {
public:
    ScopedStage(StageTimer& t, Stage s) : t_(t), s_(s), start_(StageTimer::Clock::now()) {}
    ~ScopedStage() {
        t_.add(s_, std::chrono::duration<double, std::micro>(StageTimer::Clock::now() - start_).count());
    }
    ScopedStage(const ScopedStage&) = delete;
    ScopedStage& operator=(const ScopedStage&) = delete;

private:
    StageTimer& t_;
    Stage s_;
    StageTimer::Clock::time_point start_;
};

/// Percentile (0..100) of values by linear interpolation; 0 for an empty set. Sorts a copy.
double percentile(std::vector<double> values, double pct);

}  // namespace eyesim::frame
