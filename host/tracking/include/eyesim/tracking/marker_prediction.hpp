#pragma once
/// \file
/// What a body's pose predicts about one marker's image in one camera, for the refinement's occlusion-aware fit
/// (refine.hpp MarkerHint): the outline the sphere projects to (through the full camera model, distortion
/// included) and what hides part of it: for an instrument marker the shaft it is threaded on, for an eye marker
/// near the eye's outline the eye itself.

#include "eyesim/tracking/body_model.hpp"
#include "eyesim/tracking/camera_geometry.hpp"
#include "eyesim/tracking/pose.hpp"
#include "eyesim/tracking/refine.hpp"

#include <Eigen/Core>

#include <array>
#include <span>

namespace eyesim::tracking {

/// The sphere's projected outline in the fit's convention (frame px): centre (x, v = frame row), and
/// (1 + e1)·dx² + 2·e2·dx·dv + (1 − e1)·dv² = r². False when the sphere does not project whole.
struct ProjectedOutline {
    double x_px = 0, v_px = 0, r_px = 0, e1 = 0, e2 = 0;
};
bool project_sphere_outline(const CameraGeometry& cam, const Eigen::Vector3d& centre_rig_mm, double radius_mm,
                            ProjectedOutline& out);

/// MarkerHint of an instrument marker of radius `radius_mm` at `centre_rig_mm` threaded on a shaft of radius
/// `shaft_radius_mm` along `axis_rig` (unit), with the outline prior from project_sphere_outline(). False when the
/// marker does not project.
bool predict_shaft_hint(const CameraGeometry& cam, const Eigen::Vector3d& centre_rig_mm, double radius_mm,
                        const Eigen::Vector3d& axis_rig, double shaft_radius_mm, MarkerHint& out);

/// MarkerHint of a marker nothing hides (radius `radius_mm`, at `centre_rig_mm`): its outline alone. False when the
/// marker does not project.
bool predict_clear_hint(const CameraGeometry& cam, const Eigen::Vector3d& centre_rig_mm, double radius_mm,
                        MarkerHint& out);

/// MarkerHint of an eye marker (radius `radius_mm`, at `centre_rig_mm`) with the eye's sphere as the occluder; false
/// when the marker does not project or the eye hides none of it (a plain fit).
bool predict_eye_hint(const CameraGeometry& cam, const Eigen::Vector3d& centre_rig_mm, double radius_mm,
                      const Eigen::Vector3d& eye_centre_rig_mm, double eye_radius_mm, MarkerHint& out);

/// predict_shaft_hint() with the eye's sphere as the occluder as well; false when the marker does not project or
/// the eye hides none of it.
bool predict_shaft_eye_hint(const CameraGeometry& cam, const Eigen::Vector3d& centre_rig_mm, double radius_mm,
                            const Eigen::Vector3d& axis_rig, double shaft_radius_mm,
                            const Eigen::Vector3d& eye_centre_rig_mm, double eye_radius_mm, MarkerHint& out);

struct TrackingFrame;

/// Hints for the refinement from the tracker's newest poses (eye and instruments): which marker a blob is (its
/// class, and the marker's predicted projection nearest the blob's centroid), and the occluders and outline the
/// poses predict for it in that camera. Fixed capacity, no allocation after construction.
class MarkerHintSource {
public:
    /// A blob further than this from every predicted marker of its class gets no hint (frame px): a pose one or
    /// two fields old, and the visible part's centroid up to a radius from the centre.
    static constexpr double kGatePx = 6.0;
    /// A blob on the image's edge (its first or last line or column): the gate is this much wider, the visible
    /// part's centroid of a marker the edge cuts lying further from its centre (sweep seed 153, a pick marker's
    /// centre above the image 4–5.3 px from the centroid of its sliver on 4:2:0 video, whose chroma holds it 0.7 px
    /// low: beyond the gate with a pose one or two fields old, its fit was plain and refused).
    static constexpr double kEdgeGatePx = 4.0;
    /// A pose not measured for this many updates gives no hints.
    static constexpr int kMaxAgeFrames = 5;

    MarkerHintSource() = default;
    /// The cameras (at most kMaxCameras) and bodies of the tracker whose frames update() gets.
    MarkerHintSource(std::span<const CameraGeometry> cameras, const BodySet& bodies);

    /// The poses of a new frame: measured instrument poses replace the held ones.
    void update(const TrackingFrame& frame);
    /// The same from the eye's pose and the instrument poses in BodySet order (measured() ones count).
    void update(const EyePose& eye, std::span<const InstrumentPose> instruments);
    /// Poses predicted to the time of the field about to be fitted (Tracker::pose_at): they replace the held poses
    /// of the bodies that still give hints, whose ages stay (a prediction is no measurement).
    void predict(const EyePose& eye, std::span<const InstrumentPose> instruments);

    /// The hint for `blob` of camera `camera` (its class, parity and centroid): the marker of its class predicted
    /// nearest, within kGatePx (and kEdgeGatePx more on the image's edge: `field_lines` > 0, the field's height,
    /// for its last line). An instrument marker's hint holds its shaft; an eye marker's the eye's sphere, and
    /// only where the eye hides part of it. False: no marker near, or nothing hides it (a plain fit).
    /// An instrument marker's occluding sphere is the eye where the eye hides part of it and `eye_in_front` (the
    /// eye's outline crosses the patch: SphereFitConfig::hint_with_outline), else the nearest marker in front.
    bool hint(int camera, const BlobBox& blob, MarkerHint& out, bool eye_in_front = true, int field_lines = 0) const;

    /// What else the poses put in `blob`'s patch (camera `camera`), for the fit to leave out: the other instruments'
    /// shafts and the other markers within kForeignReachPx of the blob's marker, none in front of it where it
    /// crosses it (a shaft hiding part of the marker is not modelled; a marker doing so is the hint's occluder).
    /// False: nothing.
    bool patch_mask(int camera, const BlobBox& blob, PatchMask& out, int field_lines = 0) const;
    /// A foreign shaft's strip is widened by this much each side (frame px): its pose is a field or two old.
    static constexpr double kForeignMarginPx = 1.0;
    /// Shafts further than this from the marker's image are outside any patch (frame px).
    static constexpr double kForeignReachPx = 24.0;

    /// Whether any instrument pose is at hand.
    bool ready() const;

    /// fit_sphere() of `blob` of camera `camera` with the hint this source gives it, or plain where it gives none;
    /// `hinted` says which. A null source: always plain.
    static SphereFitResult fit(const MarkerHintSource* source, const uint8_t* field, int height, const BlobBox& blob,
                               int camera, const SphereFitConfig& config, SphereFitWorkspace& work, bool& hinted);

private:
    // The marker of the blob's class predicted nearest the blob within kGatePx (kEdgeGatePx more on the image's
    // edge; field_lines 0: its last line unknown): its body (−1: the eye), index and centre (rig). False: none.
    bool nearest(int camera, const BlobBox& blob, int& body, int& marker, Eigen::Vector3d& centre,
                 int field_lines) const;
    // Where the pose predicts the blob's centroid (field px): with `hint`, its marker's visible part's; else the
    // centre of the marker nearest() the blob. False: no prediction.
    bool predicted_centroid(int camera, const BlobBox& blob, const MarkerHint* hint, const SphereFitConfig& config,
                            int field_lines, double& cx_px, double& cy_px) const;
    // f(body, marker, its BodyMarker, its centre in the rig) for every marker of every instrument with a fresh pose,
    // then (body −1) of the eye if its pose is fresh.
    template <class F>
    void for_each_marker(F&& f) const {
        for (int b = 0; b < bodies_.instrument_count; ++b) {
            if (age_[static_cast<std::size_t>(b)] > kMaxAgeFrames) continue;
            const InstrumentModel& im = bodies_.instruments[static_cast<std::size_t>(b)];
            const InstrumentPose& pose = poses_[static_cast<std::size_t>(b)];
            const Eigen::Matrix3d r = pose.rotation_body_to_rig.toRotationMatrix();
            for (int k = 0; k < im.marker_count; ++k) {
                const BodyMarker& bm = im.markers[static_cast<std::size_t>(k)];
                f(b, k, bm, Eigen::Vector3d(pose.tip_rig_mm + r * (bm.pos_body_mm - im.tip_body_mm)));
            }
        }
        if (eye_age_ > kMaxAgeFrames) return;
        const Eigen::Matrix3d r = eye_.rotation_eye_to_rig.toRotationMatrix();
        for (int k = 0; k < bodies_.eye.marker_count; ++k) {
            const BodyMarker& bm = bodies_.eye.markers[static_cast<std::size_t>(k)];
            f(-1, k, bm, Eigen::Vector3d(eye_.centre_rig_mm + r * bm.pos_body_mm));
        }
    }

    int ncam_ = 0;
    std::array<CameraGeometry, kMaxCameras> cams_{};
    BodySet bodies_;
    std::array<InstrumentPose, kMaxInstruments> poses_{};
    std::array<int, kMaxInstruments> age_{};  // updates since measured; > kMaxAgeFrames: none
    EyePose eye_;
    int eye_age_ = kMaxAgeFrames + 1;
};

}  // namespace eyesim::tracking
