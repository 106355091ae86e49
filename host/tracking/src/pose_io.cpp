#include "eyesim/tracking/pose_io.hpp"

#include <nlohmann/json.hpp>

#include <cmath>

namespace eyesim::tracking {

namespace {

nlohmann::json vec(const Eigen::Vector3d& v) { return nlohmann::json::array({v.x(), v.y(), v.z()}); }
nlohmann::json quat(const Eigen::Quaterniond& q) { return nlohmann::json::array({q.w(), q.x(), q.y(), q.z()}); }

}  // namespace

std::string frame_json_line(const TrackingFrame& f, const BodySet& bodies) {
    nlohmann::json j;
    j["frame"] = f.index;
    j["reference_field"] = f.reference_field;
    j["t_device_us"] = f.time_device_us;
    j["flags"] = f.flags;
    j["cameras_used"] = f.cameras_used;
    j["timing"] = {{"sample_host_us", f.timing.sample_host_us},
                   {"field_end_host_us", f.timing.field_end_host_us},
                   {"received_host_us", f.timing.received_host_us},
                   {"poses_ready_host_us", f.timing.poses_ready_host_us},
                   {"compute_us", f.timing.compute_us}};
    j["eye"] = {{"measured", f.eye.measured()},
                {"q_eye_to_rig", quat(f.eye.rotation_eye_to_rig)},
                {"fit_rms_mm", f.eye.fit_rms_mm},
                {"markers", f.eye.markers_used}};
    nlohmann::json inst = nlohmann::json::array();
    for (int b = 0; b < f.instrument_count; ++b) {
        const InstrumentPose& p = f.instruments[std::size_t(b)];
        inst.push_back({{"name", bodies.instruments[std::size_t(b)].name},
                        {"measured", p.measured()},
                        {"no_roll", (p.flags & kPoseNoRoll) != 0},
                        {"tip_rig_mm", vec(p.tip_rig_mm)},
                        {"axis_rig", vec(p.axis_rig)},
                        {"tip_eye_mm", vec(p.tip_eye_mm)},
                        {"axis_eye", vec(p.axis_eye)},
                        {"insertion_mm", p.insertion_depth_mm},
                        {"opening", p.opening},
                        {"fit_rms_mm", p.fit_rms_mm},
                        {"markers", p.markers_used}});
    }
    j["instruments"] = inst;
    nlohmann::json mk = nlohmann::json::array();
    for (int k = 0; k < f.markers.count; ++k) {
        const MatchedMarker& m = f.markers.markers[std::size_t(k)];
        const int body = f.assignment.body[std::size_t(k)];
        mk.push_back({{"class", m.colour_class},
                      {"body", body == 0 ? "eye" : body > 0 ? bodies.instruments[std::size_t(body - 1)].name : ""},
                      {"id", f.assignment.marker[std::size_t(k)]},
                      {"x_rig_mm", vec(m.point.X_rig_mm)},
                      {"sigma_mm", std::sqrt(std::max(0.0, m.point.cov_mm2.trace()))},
                      {"views", m.point.views},
                      {"rms_px", m.point.rms_px}});
    }
    j["markers"] = mk;
    return j.dump();
}

}  // namespace eyesim::tracking
