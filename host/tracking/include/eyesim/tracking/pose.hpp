#pragma once
/// \file
/// Pose results of one tracking frame and the fitting of bodies to triangulated markers: marker-to-body
/// assignment by colour class and rigid distances, eye rotation about its fixed centre (Kabsch), instrument
/// tip/axis/roll (Kabsch, or a constrained line fit when all markers are on the shaft), insertion depth through
/// the trocar, and instrument poses expressed in the eye frame.

#include "eyesim/tracking/body_model.hpp"
#include "eyesim/tracking/correspondence.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>

namespace eyesim::tracking {

/// Bit flags of a pose (0 = measured this frame from enough markers).
enum PoseFlag : std::uint32_t {
    kPoseOk = 0,
    kPoseTooFewMarkers = 1u << 0,  ///< not enough markers assigned: the pose is the last good one (held)
    kPoseHeld = 1u << 1,           ///< values copied from the last good frame (or the rest pose if none)
    kPoseNoRoll = 1u << 2,         ///< markers on the shaft only: roll unobservable, orientation is minimal
    kPoseHighResidual = 1u << 3,   ///< fit RMS above the gate: a marker is probably misassigned
    kPoseNoEye = 1u << 4,          ///< eye pose not available: eye-frame values use the last eye pose
    kPoseJumpRejected = 1u << 5,   ///< a fit jumped implausibly from the last frame (misassigned markers): held
    kPoseSingleMarker = 1u << 6,   ///< kept from one marker and the trocar (the shaft's line; measured)
    kPoseSingleView = 1u << 7,     ///< from one camera's images and the trocar (fit_instrument_one_view; hints only)
};

/// Eye pose: rotation about its fixed centre.
struct EyePose {
    Eigen::Quaterniond rotation_eye_to_rig = Eigen::Quaterniond::Identity();  ///< rotation eye→rig
    Eigen::Vector3d centre_rig_mm = Eigen::Vector3d::Zero();                  ///< fixed centre (rig frame)
    double fit_rms_mm = 0.0;  ///< RMS marker residual of the fit
    int markers_used = 0;     ///< markers assigned
    std::uint32_t flags = kPoseTooFewMarkers | kPoseHeld;  ///< PoseFlag bits
    /// True when measured this frame.
    bool measured() const { return (flags & (kPoseTooFewMarkers | kPoseHeld)) == 0; }
};

/// Instrument pose in the rig frame and in the eye frame.
struct InstrumentPose {
    Eigen::Vector3d tip_rig_mm = Eigen::Vector3d::Zero();   ///< tip, rig frame
    Eigen::Vector3d axis_rig = Eigen::Vector3d::UnitZ();    ///< unit shaft direction tip→handle, rig frame
    Eigen::Quaterniond rotation_body_to_rig = Eigen::Quaterniond::Identity();  ///< full orientation (minimal
                                                            ///< rotation of the axis when kPoseNoRoll)
    Eigen::Vector3d tip_eye_mm = Eigen::Vector3d::Zero();   ///< tip in the eye frame
    Eigen::Vector3d axis_eye = Eigen::Vector3d::UnitZ();    ///< shaft direction in the eye frame
    Eigen::Quaterniond rotation_body_to_eye = Eigen::Quaterniond::Identity();  ///< orientation in the eye frame
    double insertion_depth_mm = 0.0;  ///< tip depth behind the trocar along the axis (< 0: tip outside the eye)
    double opening = 0.0;             ///< jaw opening / function 0..1 (from the pedal; markers cannot show it)
    double fit_rms_mm = 0.0;          ///< RMS marker residual of the fit
    int markers_used = 0;             ///< markers assigned
    std::uint32_t flags = kPoseTooFewMarkers | kPoseHeld;  ///< PoseFlag bits
    /// True when measured this frame.
    bool measured() const { return (flags & (kPoseTooFewMarkers | kPoseHeld)) == 0; }
};

/// Options of the body fit.
struct PoseOptions {
    double distance_tol_mm = 0.4;   ///< inter-marker distance tolerance when assigning markers to a body
    double max_fit_rms_mm = 0.25;   ///< fit residual gate (kPoseHighResidual above it)
    double eye_radius_tol_mm = 0.6; ///< |marker − centre| must match the model within this
    double eye_prior_gate_mm = 3.0; ///< eye markers are matched to their predicted positions within this
    int min_markers_acquire = 3;    ///< markers needed to report an instrument not measured in the last frame
                                    ///< (2 suffice when the shaft's line passes through its trocar)
    int min_markers_keep = 2;       ///< markers needed to keep reporting an instrument measured last frame
    double max_tip_jump_mm = 6.0;   ///< a tracked instrument's tip moving further in one frame is rejected
    /// Use the trocar as a point the shaft passes through (when the tip is past it): the markers sit 26–38 mm
    /// from the tip, so without it the tip is an extrapolation that multiplies the marker error ~4×.
    bool trocar_constraint = true;
    double trocar_sigma_mm = 0.02;  ///< 1σ of the shaft's passage through the trocar (clearance, eye pose)
    double trocar_gate_mm = 1.0;    ///< the constraint is used only when the marker-only line passes this close
    /// An instrument measured last frame is kept from a single marker (and its trocar) when that marker lies
    /// this close to where the last pose puts it.
    double single_marker_gate_mm = 1.5;
    /// An instrument not measured now (measured within the last second, or placed so in the last frame) whose
    /// markers a camera sees whole is placed from its images and its trocar for the refinement's hints
    /// (TrackingFrame::one_view; the other cameras' view blocked, or the instrument withdrawn along its trocar's
    /// line, `occlusion`): in each camera, of the images no body's marker took, one per marker on a line through the
    /// trocar's image in the markers' order, where exactly one such combination reprojects within
    /// single_view_max_rms_px (fit_instrument_one_view); with two cameras or more, one fit over all their images
    /// (fit_instrument_images) within the same.
    bool single_view = true;
    double single_view_max_rms_px = 1.0;
    /// 1σ of a marker the correspondence flagged partly hidden with fewer than two clean views (MatchedMarker::
    /// occluded): its point is the visible parts' centroid, up to a few tenths of a mm from the centre. Instrument
    /// fits weight it by that, so the clean markers and the trocar carry the pose and it only fills in.
    double occluded_sigma_mm = 0.3;
};

/// Fits an instrument's shaft through its trocar to one camera's images of its markers: the line's direction
/// through `trocar_rig_mm` (two parameters) and the tip's depth behind it (one) that reproject body markers
/// `which[k]` nearest the undistorted normalised points `xn[k]` of camera `cam` (Gauss–Newton from `start`'s axis
/// and tip). For an instrument only one camera sees (the others' view blocked): its markers alone are no 3D points,
/// but three images on the line and the trocar fix the shaft. Sets pose's tip, axis, rotation (no roll) and
/// flags kPoseNoRoll | kPoseSingleView; `rms_px` is the reprojection RMS (pixels by the mean focal). False with
/// fewer than three markers, a degenerate geometry (the shaft along the line of sight) or no convergence.
/// Allocation-free.
bool fit_instrument_one_view(const CameraGeometry& cam, const InstrumentModel& model, const Eigen::Vector3d& trocar_rig_mm,
                             std::span<const Eigen::Vector2d> xn, std::span<const int> which,
                             const InstrumentPose& start, InstrumentPose& pose, double& rms_px);

/// One image of an instrument's marker for fit_instrument_images: the camera, the undistorted normalised point, the
/// body marker.
struct ShaftImage {
    const CameraGeometry* camera = nullptr;
    Eigen::Vector2d xn = Eigen::Vector2d::Zero();
    int marker = -1;
};
/// Most images fit_instrument_images takes.
inline constexpr int kMaxShaftImages = kMaxCameras * kMaxBodyMarkers;

/// fit_instrument_one_view over the images of one or more cameras (each residual in its camera's pixels): where two
/// cameras see the markers but their images do not triangulate (a codec's bias on 2–10 px blobs beyond the
/// correspondence's residual gate), the second view fixes the depth the first leaves loose.
bool fit_instrument_images(std::span<const ShaftImage> images, const InstrumentModel& model,
                           const Eigen::Vector3d& trocar_rig_mm, const InstrumentPose& start, InstrumentPose& pose,
                           double& rms_px);

/// Which body (and which of its markers) each triangulated marker was assigned to.
struct MarkerAssignment {
    std::array<std::int8_t, kMaxMarkersPerFrame> body{};    ///< −1 unassigned, 0 eye, 1 + i instrument i
    std::array<std::int8_t, kMaxMarkersPerFrame> marker{};  ///< index of the body marker, −1 unassigned
};

/// Fits every body of `bodies` to the markers in `found`. `previous_*` are the last poses (held when a body is not
/// measurable; pass the default-constructed values on the first frame). Allocation-free.
void fit_poses(const BodySet& bodies, const CorrespondenceResult& found, const PoseOptions& opt,
               const EyePose& previous_eye, std::span<const InstrumentPose> previous_instruments, EyePose& eye,
               std::span<InstrumentPose> instruments, MarkerAssignment& assignment);

/// Fits an instrument to measured marker positions given the assignment `which[k]` = body marker index of
/// measured point k; weights are 1/σ² (mm⁻²). When `trocar_rig_mm` is given (with its weight), the shaft line is
/// also pulled through that point. Returns false when the markers do not determine tip and axis.
bool fit_instrument(const InstrumentModel& model, std::span<const Eigen::Vector3d> measured_rig_mm,
                    std::span<const int> which, std::span<const double> weights, InstrumentPose& pose,
                    const Eigen::Vector3d* trocar_rig_mm = nullptr, double trocar_weight = 0.0);

/// Expresses an instrument pose in the eye frame and computes the insertion depth through its trocar.
void instrument_in_eye(const InstrumentModel& model, const EyePose& eye, InstrumentPose& pose);

}  // namespace eyesim::tracking
