#pragma once
/// \file
/// A synthetic marker stream for tracker tests: the rig's default cameras (unsynchronised PAL clocks) and the
/// bodies file, an analytic motion of the eye and two instruments through their trocars, and FieldMarkers
/// messages with projected marker centres (+ optional noise) stamped with the rig's field timing.

#include "eyesim/tracking/body_model.hpp"
#include "eyesim/tracking/tracker.hpp"

#include "eyesim/protocol/messages.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/camera.hpp"

#include <Eigen/Geometry>

#include <algorithm>
#include <random>
#include <vector>

namespace eyesim::tracking::test {

/// Ground truth of the synthetic scene at one instant.
struct SceneTruth {
    Eigen::Quaterniond q_eye_to_rig = Eigen::Quaterniond::Identity();
    std::vector<Eigen::Vector3d> tip_rig_mm, axis_rig, tip_eye_mm;  ///< per instrument (axis tip → handle)
    std::vector<double> insertion_mm;                               ///< per instrument
    std::vector<Eigen::Vector3d> markers_rig_mm;                    ///< eye markers then instrument markers
    std::vector<int> marker_class;                                  ///< per marker
};

/// Distance (mm) from `X_rig_mm` to the nearest truth marker of `colour_class`: a reported marker's error.
inline double nearest_marker_error_mm(const SceneTruth& truth, int colour_class, const Eigen::Vector3d& X_rig_mm) {
    double best = 1e9;
    for (std::size_t k = 0; k < truth.markers_rig_mm.size(); ++k)
        if (truth.marker_class[k] == colour_class) best = std::min(best, (truth.markers_rig_mm[k] - X_rig_mm).norm());
    return best;
}

/// The scene: forceps through trocar 0 and the light pipe through trocar 1.
class SyntheticScene {
public:
    /// `speed` scales all motion (1 = a slow sweep).
    explicit SyntheticScene(double speed = 1.0);
    /// Truth at recording time t_us.
    SceneTruth at(double t_us) const;
    /// The tracker configuration for this rig and scene.
    TrackerConfig tracker_config() const;
    /// The rig cameras.
    const std::vector<rig::CameraModel>& cameras() const { return cams_; }
    /// The bodies.
    const rig::Bodies& bodies() const { return bodies_; }
    /// FieldMarkers messages of fields [0, n) of every camera in device send order (by field end), with
    /// Gaussian centroid noise `sigma_px` (field pixels). `drop(cam, field)` removes a whole field when true.
    template <typename Drop>
    std::vector<protocol::FieldMarkers> stream(int n, double sigma_px, std::mt19937_64& rng, Drop drop) const;

private:
    double speed_;
    std::vector<rig::CameraModel> cams_;
    rig::Bodies bodies_;
    BodySet set_;
};

/// Builds one field's message (no noise) of camera `cam`, field `index`.
protocol::FieldMarkers field_message(const SyntheticScene& scene, int cam, int index, double sigma_px,
                                     std::mt19937_64& rng);

template <typename Drop>
std::vector<protocol::FieldMarkers> SyntheticScene::stream(int n, double sigma_px, std::mt19937_64& rng,
                                                           Drop drop) const {
    std::vector<protocol::FieldMarkers> out;
    for (int i = 0; i < n; ++i)
        for (int c = 0; c < int(cams_.size()); ++c)
            if (!drop(c, i)) out.push_back(field_message(*this, c, i, sigma_px, rng));
    std::stable_sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.field_end_us < b.field_end_us; });
    return out;
}

}  // namespace eyesim::tracking::test
