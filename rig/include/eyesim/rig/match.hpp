#pragma once
/// \file
/// Scoring detections against the rendered truth: the one matching rule the benchmarks, `eyesim fpga` and
/// `eyesim validate` share, so their figures count the same markers the same way.

#include "eyesim/rig/truth.hpp"

#include <Eigen/Core>

#include <cstddef>
#include <span>
#include <vector>

namespace eyesim::rig {

/// A marker found in one camera's field: colour class and centroid in field pixels.
struct DetectedMarker {
    int colour_class = 0;
    Eigen::Vector2d centroid_px = Eigen::Vector2d::Zero();
};

/// Outcome for one truth marker the caller chose to score.
struct MarkerMatch {
    const MarkerTruth* marker = nullptr;       ///< the truth marker
    const MarkerCameraTruth* view = nullptr;   ///< its view in the camera
    int detection = -1;                        ///< index into the detections, −1 when none is within the gate
    double distance_px = 0.0;                  ///< centroid error when matched
};

/// Greedy matching in truth order: every marker of camera `cam` that `take(marker, view)` accepts gets the unused
/// detection of its colour class whose centroid is nearest to the rendered centroid, if closer than `gate_px`
/// (first found on ties). `on(match)` is called for every accepted marker, matched or not; `used` ends with one
/// flag per detection.
template <class Take, class On>
void match_markers(const FieldTruth& truth, int cam, std::span<const DetectedMarker> detections, double gate_px,
                   Take take, On on, std::vector<bool>& used) {
    used.assign(detections.size(), false);
    for (const MarkerTruth& m : truth.markers) {
        if (cam < 0 || static_cast<std::size_t>(cam) >= m.cams.size()) continue;
        const MarkerCameraTruth& view = m.cams[static_cast<std::size_t>(cam)];
        if (!take(m, view)) continue;
        MarkerMatch match{&m, &view, -1, gate_px};
        for (std::size_t j = 0; j < detections.size(); ++j) {
            if (used[j] || detections[j].colour_class != m.colour_class) continue;
            const double d = (detections[j].centroid_px - view.centroid_px).norm();
            if (d < match.distance_px) {
                match.distance_px = d;
                match.detection = static_cast<int>(j);
            }
        }
        if (match.detection >= 0) used[static_cast<std::size_t>(match.detection)] = true;
        on(match);
    }
}

}  // namespace eyesim::rig
