#include "eyesim/frame/pose_source.hpp"

#include <cmath>

namespace eyesim::frame {

Eigen::Isometry3f instrument_pose_eye(const Eigen::Vector3d& tip_eye_mm, const Eigen::Vector3d& axis_tip_to_handle) {
    const Eigen::Vector3f z = (-axis_tip_to_handle).cast<float>().normalized();
    const Eigen::Vector3f a = std::fabs(z.x()) < 0.9f ? Eigen::Vector3f::UnitX() : Eigen::Vector3f::UnitY();
    const Eigen::Vector3f x = (a - a.dot(z) * z).normalized();
    Eigen::Isometry3f pose = Eigen::Isometry3f::Identity();
    pose.linear().col(0) = x;
    pose.linear().col(1) = z.cross(x);
    pose.linear().col(2) = z;
    pose.translation() = tip_eye_mm.cast<float>();
    return pose;
}

TrackingPoseAdapter::TrackingPoseAdapter(const tracking::BodySet& bodies) {
    for (int i = 0; i < bodies.instrument_count; ++i) {
        is_light_[size_t(i)] = bodies.instruments[size_t(i)].name == "light_pipe";
        if (is_light_[size_t(i)] && light_ < 0) light_ = i;
    }
}

void TrackingPoseAdapter::convert(const tracking::TrackingFrame& f, FramePoses& out) {
    out = FramePoses{};
    out.time_s = f.time_device_us * 1e-6;
    out.tracking_us = f.timing.compute_us;
    // The working hand: the first non-light instrument measured (a live body set lists every kind; only the
    // instruments present are ever measured). Sticky once chosen.
    for (int i = 0; hand_ < 0 && i < f.instrument_count; ++i)
        if (!is_light_[size_t(i)] && f.instruments[size_t(i)].measured()) hand_ = i;
    auto take = [&](int i, bool& valid, Eigen::Isometry3f& pose) {
        if (i < 0 || i >= f.instrument_count) return;
        const tracking::InstrumentPose& p = f.instruments[size_t(i)];
        if (p.measured()) ever_[size_t(i)] = true;
        if (!ever_[size_t(i)] || !p.tip_eye_mm.allFinite() || !p.axis_eye.allFinite()) return;
        valid = true;
        pose = instrument_pose_eye(p.tip_eye_mm, p.axis_eye);
    };
    take(hand_, out.tissue_valid, out.tissue_to_eye);
    take(light_, out.light_valid, out.light_to_eye);
    if (hand_ >= 0 && hand_ < f.instrument_count) out.pedal = float(f.instruments[size_t(hand_)].opening);
}

FramePoses poses_from_truth(const rig::SceneState& s) {
    FramePoses out;
    out.time_s = s.t_us * 1e-6;
    for (const auto& inst : s.instruments) {
        const bool light = inst.kind == rig::InstrumentKind::kLightPipe;
        if (light && !out.light_valid) {
            out.light_valid = true;
            out.light_to_eye = instrument_pose_eye(inst.tip_eye_mm, inst.axis_eye);
        } else if (!light && !out.tissue_valid) {
            out.tissue_valid = true;
            out.tissue_to_eye = instrument_pose_eye(inst.tip_eye_mm, inst.axis_eye);
        }
    }
    out.pedal = float(s.pedal.axes[0]);
    return out;
}

}  // namespace eyesim::frame
