#include "eyesim/tracking/rig_adapter.hpp"

#include <algorithm>
#include <stdexcept>

namespace eyesim::tracking {

CameraGeometry camera_geometry(const rig::CameraModel& cam) {
    CameraGeometry g;
    g.fx = cam.fx;
    g.fy = cam.fy;
    g.cx = cam.cx;
    g.cy = cam.cy;
    g.dist = {cam.dist[0], cam.dist[1], cam.dist[2], cam.dist[3], cam.dist[4], 0.0, 0.0, 0.0};
    g.R_cam_rig = cam.R_cam_rig;
    g.t_cam_rig_mm = cam.t_cam_rig_mm;
    return g;
}

CameraTiming camera_timing(const rig::CameraModel& cam) {
    CameraTiming t;
    for (int index = 0; index < 2; ++index) {
        const rig::FieldTiming ft = cam.field_timing(index);
        t.end_to_sample_us[std::size_t(ft.parity)] = ft.end_us - ft.exposure_mid_us;
    }
    return t;
}

BodySet body_set(const rig::Bodies& bodies, const std::vector<SceneInstrument>& scene) {
    BodySet set;
    set.eye.centre_rig_mm = bodies.eye.center_rig_mm;
    set.eye.radius_mm = bodies.eye.radius_mm;
    if (bodies.eye.markers.size() > std::size_t(kMaxBodyMarkers))
        throw std::invalid_argument("bodies: eye: more than " + std::to_string(kMaxBodyMarkers) + " markers");
    for (const rig::EyeMarker& m : bodies.eye.markers) {
        set.marker_radius_mm = std::max(set.marker_radius_mm, m.radius_mm);
        BodyMarker& b = set.eye.markers[std::size_t(set.eye.marker_count++)];
        b.colour_class = std::uint8_t(m.colour_class);
        b.pos_body_mm = m.position_eye_mm;
        b.radius_mm = m.radius_mm;
    }
    if (scene.size() > std::size_t(kMaxInstruments))
        throw std::invalid_argument("scene: more than " + std::to_string(kMaxInstruments) + " instruments");
    for (const SceneInstrument& si : scene) {
        const rig::InstrumentBody* body = nullptr;
        for (const rig::InstrumentBody& ib : bodies.instruments)
            if (ib.kind == si.kind) body = &ib;
        if (!body)
            throw std::invalid_argument(std::string("bodies: instruments: no kind \"") +
                                        rig::instrument_kind_name(si.kind) + "\"");
        if (body->markers.size() > std::size_t(kMaxBodyMarkers))
            throw std::invalid_argument("bodies: " + body->name + ": more than " +
                                        std::to_string(kMaxBodyMarkers) + " markers");
        InstrumentModel& im = set.instruments[std::size_t(set.instrument_count++)];
        im.name = rig::instrument_kind_name(si.kind);
        im.tip_body_mm = Eigen::Vector3d::Zero();  // instrument frame: origin at the tip, +z tip → handle
        im.axis_body = Eigen::Vector3d::UnitZ();
        im.shaft_radius_mm = body->shaft_radius_mm;
        im.shaft_length_mm = body->shaft_length_mm;
        for (std::size_t i = 0; i < body->markers.size(); ++i) {
            BodyMarker& b = im.markers[std::size_t(im.marker_count++)];
            b.colour_class = std::uint8_t(body->markers[i].colour_class);
            b.pos_body_mm = body->marker_position_mm(i);
            b.radius_mm = body->markers[i].radius_mm;
            set.marker_radius_mm = std::max(set.marker_radius_mm, body->markers[i].radius_mm);
        }
        if (si.trocar >= 0) {
            bool found = false;
            for (const rig::Trocar& t : bodies.eye.trocars)
                if (t.id == si.trocar) {
                    im.trocar_eye_mm = t.position_eye_mm;
                    found = true;
                }
            if (!found) throw std::invalid_argument("bodies: eye: trocars: no id " + std::to_string(si.trocar));
            im.has_trocar = true;
        }
    }
    return set;
}

std::vector<SceneInstrument> all_instruments(const rig::Bodies& bodies) {
    std::vector<SceneInstrument> out;
    for (const rig::InstrumentBody& ib : bodies.instruments) {
        if (out.size() >= std::size_t(kMaxInstruments)) break;
        out.push_back({ib.kind, ib.kind == rig::InstrumentKind::kLightPipe ? 1 : 0});
    }
    return out;
}

int truth_poses(const rig::FieldTruth& truth, EyePose& eye, std::span<InstrumentPose> instruments) {
    eye = EyePose{};
    eye.centre_rig_mm = truth.eye_center_rig_mm;
    eye.rotation_eye_to_rig = truth.q_eye_to_rig;
    eye.flags = kPoseOk;
    const std::size_t n = std::min(truth.instruments.size(), instruments.size());
    for (std::size_t b = 0; b < n; ++b) {
        InstrumentPose& p = instruments[b];
        p = InstrumentPose{};
        p.tip_rig_mm = truth.instruments[b].tip_rig_mm;
        p.axis_rig = truth.instruments[b].axis_rig;
        p.rotation_body_to_rig = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), p.axis_rig);
        p.flags = kPoseOk;
    }
    return static_cast<int>(n);
}

}  // namespace eyesim::tracking
