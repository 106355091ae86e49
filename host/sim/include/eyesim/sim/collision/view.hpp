#pragma once
/// \file
/// ZCOLL's rendering camera and the interaction volume V it bounds (paper §3.3, Fig. 5).

#include "eyesim/sim/mesh.hpp"

#include <Eigen/Geometry>

#include <cstdint>

namespace eyesim::sim::collision {

struct Instrument;

/// Parallel projection (push and boolean ZCOLL) or central projection (vitrector suction cone).
enum class Projection : uint8_t { Parallel, Central };

/// A square R×R viewport looking along π. Camera frame: x = right, y = up, z = π (into the scene); depth is
/// the distance along π from the camera, in mm. Pixel (i, j) has its sample at window coordinates
/// (i + ½, j + ½), row j = 0 at the bottom (the OpenGL convention, so both back-ends index buffers alike).
struct ZcollView {
    Projection projection = Projection::Parallel;  ///< projection kind
    Vec3f origin_eye_mm{0, 0, 0};                  ///< camera position, eye frame
    Eigen::Matrix3f camera_to_eye = Eigen::Matrix3f::Identity();  ///< columns: right, up, π (unit vectors)
    float half_width_mm = 1.0f;     ///< parallel: V spans ±half_width_mm in x and y
    float tan_half_angle = 0.5f;    ///< central: tangent of the frustum's half opening angle
    float near_mm = 0.0f;           ///< depth range of V along π: [near_mm, far_mm]
    float far_mm = 2.0f;            ///< far end of V along π
    int resolution_px = 32;         ///< lateral resolution R (viewport R×R)

    /// Direction π (unit, eye frame).
    Vec3f direction_eye() const { return camera_to_eye.col(2); }
    /// Eye-frame point → camera frame (x right, y up, z depth), mm.
    Vec3f to_camera(const Vec3f& p_eye_mm) const { return camera_to_eye.transpose() * (p_eye_mm - origin_eye_mm); }
    /// Pixel size of a parallel view, mm.
    float pixel_mm() const { return 2.0f * half_width_mm / float(resolution_px); }
};

/// Oriented box in the eye frame (centre, rotation box→eye, half extents), e.g. the volume V.
struct OrientedBox {
    Vec3f centre_eye_mm{0, 0, 0};                             ///< box centre
    Eigen::Matrix3f box_to_eye = Eigen::Matrix3f::Identity();  ///< columns: box axes in the eye frame
    Vec3f half_extent_mm{0, 0, 0};                            ///< half side lengths along the box axes
};

/// Push/boolean view: V is a box around the instrument tip, `half_width_mm` laterally, from `behind_mm` back
/// along the shaft to `ahead_mm` in front of the tip. The camera sits on V's front face (ahead of the tip)
/// and looks back at the instrument: π = −forward. Membrane pierced by the tip is then behind the
/// instrument's front surface as seen from the camera (ZI < ZM), which is the paper's collision condition.
ZcollView make_tip_view(const Eigen::Isometry3f& instrument_to_eye, float half_width_mm, float ahead_mm,
                        float behind_mm, int resolution_px);

/// Push/boolean view with a chosen direction π (eye frame, unit): V is centred laterally on the tip and spans
/// from `ahead_mm` before the tip to `behind_mm` behind it along π; the camera sits `ahead_mm` before the tip
/// on −π. For membrane interaction choose π along the membrane normal at the contact, pointing from the side
/// the instrument pierces into towards the side it comes from: the membrane is then a height field in V
/// (π-convex) even when the instrument approaches at a grazing angle. `up_hint` orients the image.
ZcollView make_tip_view_along(const Vec3f& tip_eye_mm, const Vec3f& pi_eye, const Vec3f& up_hint,
                              float half_width_mm, float ahead_mm, float behind_mm, int resolution_px);

/// Suction view of a vitrector: central projection from the side opening along its outward normal, the
/// frustum approximating the suction cone of half angle `half_angle_deg` and length `length_mm`.
ZcollView make_suction_view(const Eigen::Isometry3f& instrument_to_eye, const Instrument& vitrector,
                            float half_angle_deg, float length_mm, int resolution_px);

/// V as an oriented box (central views: the box bounding the frustum).
OrientedBox view_volume(const ZcollView& view);

/// Separating-axis test of an oriented box against an axis-aligned box [lo, hi] (both eye frame).
bool box_overlaps_aabb(const OrientedBox& box, const Vec3f& lo_eye_mm, const Vec3f& hi_eye_mm);

}  // namespace eyesim::sim::collision
