#pragma once
/// \file
/// Extrinsic calibration from a wand (scenes/bodies.json "wand": collinear markers at known, unequal spacings)
/// waved through the working volume, with the mechanical eye at rest in view.
///
/// Pipeline (docs/calibration.md, "Wand"):
/// 1. `detect_recording`: the FPGA model (as `eyesim fpga` runs it, reset register map) on every field of every
///    camera; blob centroids in FRAME pixels (field (x, y) of parity p → frame (x, 2y + p)).
/// 2. `find_wand_views`: per camera and field, the wand's blobs (its colour class) when there are exactly as many
///    as the wand has markers, none flagged (image edge, merged, incomplete), collinear after undistortion, and
///    ordered along the line by the spacing ratio (the field is refused when the ratio is ambiguous);
///    `eye_images`: the eye's class-4 blobs averaged over the fields in which they keep still.
/// 3. `solve_wand`: the cameras are unsynchronised, so each camera's wand track is interpolated in time (cubic,
///    four fields) to camera 0's field instants, with each camera's time offset a parameter: first a grid search
///    (essential-matrix fit of camera 0 with that camera), then refined in the bundle adjustment. Initial relative
///    poses from cv::findEssentialMat + cv::recoverPose on undistorted normalised points (camera 0 with each
///    other camera), metric scale from the wand length; then ONE Ceres bundle adjustment over every camera's pose
///    (camera 0 fixed: the gauge), time offset, optionally intrinsics and distortion, and every wand sample's
///    pose (marker centroid + unit direction, the known spacings built in, so the scale is fixed), residuals in
///    field pixels, Huber loss, views beyond 8 robust sigmas dropped and the solve repeated.
/// 4. `fit_rig_frame`: the eye's markers triangulated from the averaged images, matched to bodies.json by their
///    distances, rigid fit (then refined on the reprojection error) of the eye frame at rest = the rig frame;
///    every camera moved into the rig frame.

#include "eyesim/fpga/blob.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/camera.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <functional>
#include <stdexcept>
#include <string>
#include <vector>

namespace eyesim::rig {
class Recording;
}

namespace eyesim::calibration {

/// A calibration that cannot be made from its input (too few samples, no convergence, no eye markers); the
/// message names the camera and what was missing. Bad input: exit code 1.
class CalibrationError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// Where a long step stands, for a progress line.
struct ProgressInfo {
    enum class Phase { kDetect, kSolve, kRigFrame };
    Phase phase = Phase::kDetect;
    int64_t done = 0, total = 0;              ///< detect: fields; solve: iteration, max iterations
    std::vector<int64_t> samples_per_camera;  ///< detect: wand views so far, per camera
    double cost = 0;                          ///< solve: current cost (½ Σ robust ρ(r²), px²)
    std::string stage;                        ///< solve: which solve ("initial", "refined", …)
};
/// Called with progress; may be empty.
using Progress = std::function<void(const ProgressInfo&)>;

/// One blob as the FPGA model emitted it, reduced to what calibration needs.
struct Blob2D {
    int class_id = 0;                              ///< colour class 1..4
    Eigen::Vector2d frame_px = Eigen::Vector2d::Zero();  ///< centroid, FRAME pixels
    uint32_t area_px = 0;                          ///< field pixels
    uint8_t flags = 0;                             ///< fpga::BlobFlag bits
};

/// The blobs of every field of every camera of a recording.
struct RecordingBlobs {
    std::vector<std::vector<std::vector<Blob2D>>> blobs;  ///< [camera][field] → blobs
    std::vector<int> first_field_parity;                  ///< per camera (from the recording)
    std::vector<double> exposure_us;                      ///< per camera (from the recording's rig.yaml)
    int64_t fields = 0;                                   ///< fields per camera (the common count)
};

/// Replaces blob centroids in place (e.g. the refinement stage's sphere fit), given the field's UYVY pixels.
using BlobRefine = std::function<void(const uint8_t* uyvy_field, std::vector<fpga::Blob>& blobs)>;

/// Runs the FPGA model (reset register map, one pipeline per camera) over the first `max_fields` fields
/// (all when < 0) of every camera, `refine` (may be empty) on each field's blobs. Progress counts blobs of
/// `wand_class` (exactly `wand_markers` of them in a field) per camera.
RecordingBlobs detect_recording(rig::Recording& rec, int64_t max_fields, int wand_class, int wand_markers,
                                const BlobRefine& refine = {}, const Progress& progress = {});

/// Why a camera's field gives no wand view.
enum class WandReject : int {
    kNone = 0,       ///< accepted
    kNoBlob,         ///< no blob of the wand's class
    kMissing,        ///< fewer blobs than markers (hidden, out of view or merged)
    kExtra,          ///< more blobs than markers
    kFlagged,        ///< a blob touches the image edge, was merged or is incomplete
    kNotCollinear,   ///< the blobs are not on one line (after undistortion)
    kAmbiguous,      ///< the spacing ratio does not tell the ends apart
    kCount
};
/// Short name: "no_blob", "missing", "extra", "flagged", "not_collinear", "ambiguous".
const char* to_string(WandReject r) noexcept;

/// A camera's view of the wand in one field: marker image centres, FRAME pixels, in marker order (marker 0 first).
/// Empty when the field gives no view.
using WandView = std::vector<Eigen::Vector2d>;

/// Wand views of a recording, per camera and field.
struct WandViews {
    std::vector<std::vector<WandView>> views;                     ///< [camera][field]
    std::vector<std::array<int64_t, static_cast<int>(WandReject::kCount)>> rejects;  ///< [camera][reason]
    /// Accepted views of camera `cam`.
    int64_t accepted(int cam) const { return rejects.at(static_cast<size_t>(cam))[0]; }
};

/// Picks the wand's views out of the blobs (see the file comment). `cams`: intrinsics of each camera (only K,
/// distortion and max_r2 are used).
WandViews find_wand_views(const RecordingBlobs& blobs, const rig::WandBody& wand,
                          const std::vector<rig::CameraModel>& cams);

/// The eye's marker images at rest, averaged per camera (FRAME pixels): blobs of the eye's class that stay within
/// 0.3 px of their median position in at least half of the fields.
struct EyeImages {
    std::vector<std::vector<Eigen::Vector2d>> px;      ///< [camera][image]
    std::vector<std::vector<int64_t>> fields;          ///< [camera][image]: fields averaged
    std::vector<std::vector<double>> area_px;          ///< [camera][image]: mean blob area, field px (0: unknown)
};

/// Averages the still blobs of class `colour_class` (the eye's markers) over all fields.
EyeImages eye_images(const RecordingBlobs& blobs, int colour_class);

/// The same from `fields` fields (pairs of consecutive fields: both parities) spread evenly over the first
/// `max_fields` (all when < 0) of the recording, each
/// blob of `colour_class` refined by `refine` before averaging (the refinement stage's sphere fit: the eye's
/// markers at rest are few, so this costs little, and their images fix the rig frame).
EyeImages eye_images(rig::Recording& rec, int colour_class, int64_t fields, int64_t max_fields, const BlobRefine& refine);

/// Solver settings.
struct WandOptions {
    bool refine_intrinsics = false;      ///< also solve fx, fy, cx, cy and k1 k2 p1 p2 k3 per camera
    bool estimate_time_offsets = true;   ///< solve each camera's field time offset; else use `time_offsets_us`
    /// Exposure mid-time of each camera's field i minus camera 0's field i (µs) when not estimated.
    std::vector<double> time_offsets_us;
    double huber_sigmas = 2.0;           ///< Huber loss scale after the first solve, in robust sigmas of the residual
    double outlier_sigmas = 8.0;         ///< views whose worst marker is beyond this many robust sigmas are dropped
    int max_iterations = 100;            ///< per Ceres solve
    int64_t min_samples_per_camera = 30; ///< fewer wand samples in a camera is an error
    int threads = 2;                     ///< Ceres threads
    bool synchronised = false;           ///< the cameras share one field clock (no interpolation, offsets 0)
};

/// Per-camera figures of the solve.
struct WandCameraStats {
    int64_t views = 0;                ///< wand views of this camera (find_wand_views)
    int64_t jumps = 0;                ///< views dropped off the smooth wand track (ends swapped, a marker hidden)
    int64_t samples = 0;              ///< wand samples with this camera's view in the final solve
    int64_t observations = 0;         ///< marker observations used (after outliers)
    int64_t outliers = 0;             ///< marker observations dropped by the solve (beyond the outlier bound)
    /// RMS length of the 2D reprojection residual (observed − projected marker centre) in FIELD pixels (x frame
    /// columns, y field rows: the pixels the camera delivers, as `eyesim fpga`'s centroid figures). The solve
    /// weighs residuals in these units.
    double image_error_px_rms = 0;
    double image_error_frame_px_rms = 0;  ///< the same in frame pixels (rig.yaml's K: a field row is 2 frame rows)
    double world_error_mm = 0;        ///< RMS distance of each fitted marker from this camera's ray through its
                                      ///< image: the image residual back-projected at the marker's depth, mm
    double time_offset_us = 0;        ///< exposure mid-time of field i minus camera 0's field i
    double coverage = 0;              ///< fraction of a 16 × 12 grid over the image with a wand marker seen
    std::vector<Eigen::Vector2d> observed_px;  ///< every marker observation used (frame px), for pictures
    std::vector<Eigen::Vector2d> residual_px;  ///< its residual (observed − projected), field px
};

/// Result of the wand bundle adjustment, in camera 0's frame (the gauge).
struct WandSolve {
    std::vector<rig::CameraModel> cameras;   ///< R, t relative to camera 0 (mm); intrinsics (refined or as given)
    std::vector<WandCameraStats> stats;      ///< per camera
    int64_t samples = 0;                     ///< wand samples in the solve (seen by ≥ 2 cameras)
    int iterations = 0;                      ///< Ceres iterations, all solves
    double initial_cost = 0, final_cost = 0; ///< of the last solve
    bool converged = false;                  ///< the last solve converged
    double solve_s = 0;                      ///< wall time from initialisation to the final solve
    /// Wand length from free triangulation of its end markers (each marker on its own, the solved cameras) minus
    /// the known length, per sample seen by ≥ 2 cameras, mm.
    std::vector<double> wand_length_error_mm;
    std::vector<std::string> notes;          ///< how the solve went (time-offset search, outliers …)
};

/// Solves the cameras' relative poses (and time offsets, optionally intrinsics) from wand views.
/// `cams`: intrinsics per camera (R, t ignored); `exposure_us`/`parity` are carried to the result.
/// Throws CalibrationError when a camera has too few samples or the solve does not converge.
WandSolve solve_wand(const WandViews& views, const std::vector<rig::CameraModel>& cams, const rig::WandBody& wand,
                     const WandOptions& opt, const Progress& progress = {});

/// The rig frame from the eye at rest.
struct RigFrameFit {
    Eigen::Matrix3d R_rig_cam0 = Eigen::Matrix3d::Identity();  ///< x_rig = R x_cam0 + t
    Eigen::Vector3d t_rig_cam0_mm = Eigen::Vector3d::Zero();
    int markers = 0;                  ///< eye markers used (seen by ≥ 2 cameras and matched to bodies.json)
    int views = 0;                    ///< their images used in the refinement
    int views_dropped = 0;            ///< images left out: partly hidden (area) or off by more than the bound
    double residual_mm_rms = 0;       ///< markers triangulated from the images kept (≥ 2) vs bodies.json, rig frame
    double residual_px_rms = 0;       ///< reprojection of the bodies.json markers after the refinement, field px
    std::vector<int> marker_ids;      ///< bodies.json ids of the markers used
};

/// Finds the rig frame from the eye's averaged marker images (cameras in camera 0's frame). An image whose blob
/// fills less than 75 % of what the camera's median image fills (blob area over a whole marker's at its distance:
/// a marker partly behind the eye's limb, its centroid pulled off the centre) is left out; then, refining the pose
/// on the images, the worst one at a time while it is off by more than max(0.2 px, 4 × the median of the others).
/// Throws CalibrationError when fewer than 3 eye markers can be triangulated and matched.
RigFrameFit fit_rig_frame(const EyeImages& eye, const std::vector<rig::CameraModel>& cams_in_cam0,
                          const rig::EyeBody& body);

/// Cameras moved from camera 0's frame into the rig frame.
std::vector<rig::CameraModel> to_rig_frame(const std::vector<rig::CameraModel>& cams_in_cam0, const RigFrameFit& fit);

}  // namespace eyesim::calibration
