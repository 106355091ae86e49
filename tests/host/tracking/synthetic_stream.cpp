#include "synthetic_stream.hpp"

#include "eyesim/tracking/rig_adapter.hpp"

#include <cmath>
#include <numbers>

namespace eyesim::tracking::test {

SyntheticScene::SyntheticScene(double speed)
    : speed_(speed), cams_(rig::default_rig()),
      bodies_(rig::load_bodies(std::string(EYESIM_SOURCE_DIR) + "/scenes/bodies.json")) {
    set_ = body_set(bodies_, {{rig::InstrumentKind::kForceps, 0}, {rig::InstrumentKind::kLightPipe, 1}});
}

TrackerConfig SyntheticScene::tracker_config() const {
    TrackerConfig cfg;
    for (const auto& c : cams_) {
        cfg.cameras.push_back(camera_geometry(c));
        cfg.timing.push_back(camera_timing(c));
    }
    cfg.bodies = set_;
    // The synthetic stream carries exact projected centres (no shaft or eye hides part of a marker, no image is
    // sampled): no correction.
    cfg.shaft_occlusion_correction = false;
    cfg.eye_occlusion_correction = false;
    cfg.marker_image_model = false;
    return cfg;
}

SceneTruth SyntheticScene::at(double t_us) const {
    const double t = t_us * 1e-6 * speed_;
    SceneTruth s;
    const double deg = std::numbers::pi / 180.0;
    const Eigen::Vector3d rv(8.0 * deg * std::sin(2.0 * std::numbers::pi * 0.31 * t),
                             6.0 * deg * std::sin(2.0 * std::numbers::pi * 0.23 * t + 1.0),
                             4.0 * deg * std::sin(2.0 * std::numbers::pi * 0.17 * t + 2.0));
    s.q_eye_to_rig = rv.norm() > 0 ? Eigen::Quaterniond(Eigen::AngleAxisd(rv.norm(), rv.normalized()))
                                   : Eigen::Quaterniond::Identity();
    const Eigen::Vector3d c = bodies_.eye.center_rig_mm;
    for (const auto& m : bodies_.eye.markers) {
        s.markers_rig_mm.push_back(c + s.q_eye_to_rig * m.position_eye_mm);
        s.marker_class.push_back(m.colour_class);
    }
    for (int b = 0; b < set_.instrument_count; ++b) {
        const InstrumentModel& im = set_.instruments[std::size_t(b)];
        const Eigen::Vector3d normal = im.trocar_eye_mm.normalized();
        // Tilt about the trocar within a 25° cone, insertion 4..14 mm.
        Eigen::Vector3d u = normal.unitOrthogonal(), v = normal.cross(u);
        const double ph = b * 1.7;
        const double tx = 0.35 * std::sin(2.0 * std::numbers::pi * 0.21 * t + ph);
        const double ty = 0.35 * std::sin(2.0 * std::numbers::pi * 0.13 * t + 2.0 * ph);
        const Eigen::Vector3d axis_eye = (normal + tx * u + ty * v).normalized();
        const double depth = 9.0 + 5.0 * std::sin(2.0 * std::numbers::pi * 0.19 * t + ph);
        const Eigen::Vector3d tip_eye = im.trocar_eye_mm - depth * axis_eye;
        const Eigen::Vector3d tip_rig = c + s.q_eye_to_rig * tip_eye;
        const Eigen::Vector3d axis_rig = s.q_eye_to_rig * axis_eye;
        s.tip_rig_mm.push_back(tip_rig);
        s.axis_rig.push_back(axis_rig);
        s.tip_eye_mm.push_back(tip_eye);
        s.insertion_mm.push_back(depth);
        for (int k = 0; k < im.marker_count; ++k) {
            s.markers_rig_mm.push_back(tip_rig + im.markers[std::size_t(k)].pos_body_mm.z() * axis_rig);
            s.marker_class.push_back(im.markers[std::size_t(k)].colour_class);
        }
    }
    return s;
}

protocol::FieldMarkers field_message(const SyntheticScene& scene, int cam, int index, double sigma_px,
                                     std::mt19937_64& rng) {
    const rig::CameraModel& cm = scene.cameras()[std::size_t(cam)];
    const rig::FieldTiming ft = cm.field_timing(index);
    const SceneTruth s = scene.at(ft.exposure_mid_us);
    protocol::FieldMarkers msg;
    msg.camera_id = std::uint8_t(cam);
    msg.field_parity = std::uint8_t(ft.parity);
    msg.field_counter = std::uint32_t(index);
    msg.field_end_us = std::uint64_t(std::llround(ft.end_us + 1e6));  // device clock = recording clock + 1 s
    std::normal_distribution<double> n(0.0, 1.0);
    for (std::size_t k = 0; k < s.markers_rig_mm.size(); ++k) {
        const auto px = cm.project_field(s.markers_rig_mm[k], ft.parity);
        if (!px) continue;
        const Eigen::Vector2d p = *px + sigma_px * Eigen::Vector2d(n(rng), n(rng));
        if (p.x() < 2 || p.x() > 717 || p.y() < 1 || p.y() > 286) continue;
        if (msg.marker_count == protocol::kMaxMarkersPerMessage) break;
        protocol::Marker& m = msg.markers[msg.marker_count++];
        m.colour_class = std::uint8_t(s.marker_class[k]);
        m.x_q16 = std::uint32_t(std::llround(p.x() * protocol::kCoordScale));
        m.y_q16 = std::uint32_t(std::llround(p.y() * protocol::kCoordScale));
        m.area_px = 30;
        m.complete_us = msg.field_end_us;
    }
    return msg;
}

}  // namespace eyesim::tracking::test
