#pragma once
/// \file
/// Scoring tracking frames against the synthetic rig's ground truth (truth.jsonl), and error summaries
/// (RMS, percentiles, max) for `eyesim validate` and the tests.

#include "eyesim/tracking/body_model.hpp"
#include "eyesim/tracking/tracker.hpp"

#include "eyesim/rig/truth.hpp"

#include <Eigen/Core>

#include <string>
#include <vector>

namespace eyesim::tracking {

/// Summary of a set of non-negative errors.
struct ErrorSummary {
    std::size_t count = 0;  ///< samples
    double rms = 0;         ///< root mean square
    double mean = 0;        ///< mean
    double p50 = 0;         ///< median (nearest rank)
    double p95 = 0;         ///< 95th percentile (nearest rank)
    double p99 = 0;         ///< 99th percentile (nearest rank)
    double max = 0;         ///< largest
};

/// Summarises `values` (order irrelevant; the vector is sorted in place). Empty → all zeros.
ErrorSummary summarise(std::vector<double>& values);

/// One triangulated marker scored against the truth.
struct MarkerScore {
    int body = -1;              ///< −1 unassigned (scored against the nearest truth marker of its class), 0 eye, 1+i
    int id = -1;                ///< marker index in its body (truth id), −1 when no truth marker was within reach
    int colour_class = 0;       ///< 1..4
    int views = 0;              ///< cameras used
    bool occluded = false;      ///< the tracker flagged it partly occluded (biased; not used for the eye)
    bool truth_eye = false;     ///< the truth marker it was scored against is an eye marker
    Eigen::Vector3d truth_rig_mm = Eigen::Vector3d::Zero();  ///< truth centre at the frame time
    double error_mm = 0;        ///< |measured − truth|
};

/// One frame scored against its truth line.
struct FrameScore {
    double t_us = 0;                          ///< truth time (reference exposure mid-time)
    std::vector<MarkerScore> markers;         ///< every triangulated marker
    int ghosts = 0;                           ///< triangulated markers with no truth marker within `reach_mm`
    std::vector<double> tip_error_mm;         ///< per instrument (NaN-free; −1 when the pose was not measured)
    std::vector<double> tip_eye_error_mm;     ///< per instrument, tip in the eye frame (−1 when not measured)
    std::vector<double> axis_error_deg;       ///< per instrument (−1 when not measured)
    std::vector<double> insertion_error_mm;   ///< per instrument (−1 when not measured or no trocar)
    /// Per instrument: the truth's tip is past its trocar (inside the eye, where the instrument meets tissue); false
    /// for a withdrawn one or one without a trocar.
    std::vector<bool> tip_in_eye;
    double eye_error_deg = -1;                ///< eye rotation error (−1 when not measured)
    int truth_markers_visible2 = 0;           ///< truth markers visible in ≥ 2 cameras (what could be found)
};

/// Scores `frame` against `truth` (the truth line of the frame's reference field). Instrument i of the frame is
/// compared with the truth instrument of the same kind name (`bodies.instruments[i].name`). `reach_mm`: an
/// unassigned marker farther than this from every truth marker of its class counts as a ghost.
FrameScore score_frame(const TrackingFrame& frame, const BodySet& bodies, const rig::FieldTruth& truth,
                       double reach_mm = 1.0);

}  // namespace eyesim::tracking
