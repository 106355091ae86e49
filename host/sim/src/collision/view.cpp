#include "eyesim/sim/collision/view.hpp"

#include "eyesim/sim/collision/instrument.hpp"

#include <cmath>

namespace eyesim::sim::collision {

ZcollView make_tip_view(const Eigen::Isometry3f& instrument_to_eye, float half_width_mm, float ahead_mm,
                        float behind_mm, int resolution_px) {
    ZcollView v;
    v.projection = Projection::Parallel;
    const Eigen::Matrix3f r = instrument_to_eye.linear();
    const Vec3f forward = r.col(2);
    v.origin_eye_mm = instrument_to_eye.translation() + forward * ahead_mm;
    v.camera_to_eye.col(0) = r.col(0);
    v.camera_to_eye.col(1) = r.col(1);
    v.camera_to_eye.col(2) = -forward;
    v.half_width_mm = half_width_mm;
    v.near_mm = 0.0f;
    v.far_mm = ahead_mm + behind_mm;
    v.resolution_px = resolution_px;
    return v;
}

ZcollView make_tip_view_along(const Vec3f& tip_eye_mm, const Vec3f& pi_eye, const Vec3f& up_hint,
                              float half_width_mm, float ahead_mm, float behind_mm, int resolution_px) {
    ZcollView v;
    v.projection = Projection::Parallel;
    const Vec3f pi = pi_eye.normalized();
    Vec3f up = up_hint - pi * pi.dot(up_hint);
    if (up.squaredNorm() < 1e-12f) up = std::fabs(pi.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY();
    up = (up - pi * pi.dot(up)).normalized();
    v.origin_eye_mm = tip_eye_mm - pi * ahead_mm;
    v.camera_to_eye.col(0) = up.cross(pi);
    v.camera_to_eye.col(1) = up;
    v.camera_to_eye.col(2) = pi;
    v.half_width_mm = half_width_mm;
    v.near_mm = 0.0f;
    v.far_mm = ahead_mm + behind_mm;
    v.resolution_px = resolution_px;
    return v;
}

ZcollView make_suction_view(const Eigen::Isometry3f& instrument_to_eye, const Instrument& vitrector,
                            float half_angle_deg, float length_mm, int resolution_px) {
    ZcollView v;
    v.projection = Projection::Central;
    const Vec3f dir = (instrument_to_eye.linear() * vitrector.port_dir_local).normalized();
    Vec3f up = instrument_to_eye.linear().col(2);
    up = (up - dir * dir.dot(up)).normalized();
    v.origin_eye_mm = instrument_to_eye * vitrector.port_local_mm;
    v.camera_to_eye.col(0) = up.cross(dir);
    v.camera_to_eye.col(1) = up;
    v.camera_to_eye.col(2) = dir;
    v.tan_half_angle = std::tan(half_angle_deg * 3.14159265358979f / 180.0f);
    v.near_mm = 0.01f;
    v.far_mm = length_mm;
    v.resolution_px = resolution_px;
    return v;
}

OrientedBox view_volume(const ZcollView& view) {
    OrientedBox b;
    b.box_to_eye = view.camera_to_eye;
    const float mid = 0.5f * (view.near_mm + view.far_mm);
    b.centre_eye_mm = view.origin_eye_mm + view.direction_eye() * mid;
    const float lateral =
        view.projection == Projection::Parallel ? view.half_width_mm : view.far_mm * view.tan_half_angle;
    b.half_extent_mm = Vec3f(lateral, lateral, 0.5f * (view.far_mm - view.near_mm));
    return b;
}

bool box_overlaps_aabb(const OrientedBox& box, const Vec3f& lo_eye_mm, const Vec3f& hi_eye_mm) {
    // Separating axes: the three world axes and the three box axes (conservative: no edge–edge axes).
    const Vec3f c = 0.5f * (lo_eye_mm + hi_eye_mm), h = 0.5f * (hi_eye_mm - lo_eye_mm);
    const Vec3f d = box.centre_eye_mm - c;
    const Eigen::Matrix3f& r = box.box_to_eye;
    const Eigen::Matrix3f a = r.cwiseAbs();
    for (int k = 0; k < 3; ++k) {
        const float rb = a.row(k).dot(box.half_extent_mm);
        if (std::fabs(d[k]) > h[k] + rb) return false;
    }
    for (int k = 0; k < 3; ++k) {
        const float ra = a.col(k).dot(h);
        if (std::fabs(r.col(k).dot(d)) > ra + box.half_extent_mm[k]) return false;
    }
    return true;
}

}  // namespace eyesim::sim::collision
