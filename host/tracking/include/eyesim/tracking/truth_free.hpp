#pragma once
/// \file
/// What can be checked on real data, where there is no ground truth: the figures engineers read off a
/// tracking system (OptiTrack's and Vicon's residuals), from the tracker's own frames.
///
/// - Reprojection residual (frame px) of every assigned marker in every camera that gave it an image: the
///   distance between the image the tracker used and the projection of (a) the triangulated 3D point and (b) the
///   body's model point under the fitted pose. A wrong camera pose or focal length shows here first.
/// - Ray-convergence residual (µm): the distance of each camera's ray through the used image from the
///   triangulated point (OptiTrack's "residual").
/// - Marker-pair distances against the bodies file: for every body, every pair of its assigned markers, the
///   measured distance minus the model's (µm). A scale error of the rig, or a body built differently from its
///   file, shows as a bias. Each instrument's (and the wand's) outermost pair is its length (`length_pair`).
/// - The calibration wand, when given: the tracker does not fit it, so it is found here among the markers no
///   body claimed (all its markers, by colour class and rigid distances), fitted as a line, and joins every
///   table above as one more body; its length error is the wand-length error of a wand calibration.
/// - Eye-centre stability: the eye's markers fitted per frame with a free rigid transform (Kabsch); the eye
///   rotates about a fixed centre, so the spread of the per-frame centres (µm) measures how well the rig agrees
///   with itself, and their mean against the configured centre how well the rig frame matches the eye.
/// - Dropouts: per marker, the fraction of its body's tracked span (first to last measured frame) in which it was
///   not assigned.
///
/// Images the tracker judged partly occluded (left out of the triangulation) and markers it flagged occluded
/// are not scored here (they are counted): they are known to be biased.

#include "eyesim/tracking/body_model.hpp"
#include "eyesim/tracking/pose.hpp"
#include "eyesim/tracking/tracker.hpp"

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace eyesim::tracking {

/// Per camera: one sample per scored view.
struct CameraResiduals {
    std::vector<float> reprojection_px;      ///< triangulated point vs used image (frame px)
    std::vector<float> fit_reprojection_px;  ///< fitted body point vs used image (frame px)
    std::vector<float> ray_um;               ///< triangulated point's distance from the camera ray (µm)
    long views_left_out = 0;                 ///< images of assigned markers judged partly occluded (not scored)
};

/// Per body marker: sums over the run.
struct MarkerResiduals {
    int body = 0;                 ///< 0 eye, 1 + i instrument i, then the wand
    int marker = 0;               ///< index in the body
    int colour_class = 0;         ///< 1..4
    long frames_assigned = 0;     ///< frames in which the marker was assigned to its body
    long frames_occluded = 0;     ///< of those, frames in which the tracker flagged it occluded (not scored)
    long views = 0;               ///< scored views
    double reprojection_ss_px2 = 0, fit_reprojection_ss_px2 = 0, ray_ss_um2 = 0;  ///< sums of squares
};

/// One pair of markers of one body: measured distance − model distance.
struct PairDistance {
    int body = 0;                 ///< 0 eye, 1 + i instrument i, then the wand
    int a = 0, b = 0;             ///< marker indices in the body (a < b)
    double model_mm = 0;          ///< distance in the bodies file
    long frames = 0;              ///< frames with both markers assigned (neither flagged occluded)
    double sum_um = 0, ss_um2 = 0, max_abs_um = 0;  ///< of the signed error
};

/// A body's tracked span and how often it was measured in it.
struct BodyTrack {
    int body = 0;                 ///< 0 eye, 1 + i instrument i, then the wand
    std::string name;             ///< "eye", instrument kind name, "wand"
    long first_frame = -1;        ///< first frame (ordinal in this run) it was measured; −1: never
    long last_frame = -1;         ///< last frame it was measured
    long measured_frames = 0;     ///< frames it was measured
    int length_pair = -1;         ///< index in `pairs` of its two outermost markers (instruments); −1: none
};

/// Accumulates the truth-free figures of a run, one frame at a time.
class TruthFreeStats {
public:
    /// For frames of a tracker configured with `bodies` and `camera_count` cameras; `wand` (optional): the
    /// calibration wand as an instrument-like body (markers along +z from marker 0 at the origin), looked for in
    /// every frame among the markers no body claimed.
    TruthFreeStats(const BodySet& bodies, int camera_count, const InstrumentModel* wand = nullptr);

    /// Scores `frame`, which must be the frame `tracker` built last (its images are read from the tracker).
    void add(const Tracker& tracker, const TrackingFrame& frame);

    /// Frames added.
    long frames() const { return frames_; }
    /// Per camera (same order as the tracker's).
    const std::vector<CameraResiduals>& cameras() const { return cameras_; }
    /// Per body marker: eye markers first, then each instrument's.
    const std::vector<MarkerResiduals>& markers() const { return markers_; }
    /// Every marker pair of every body.
    const std::vector<PairDistance>& pairs() const { return pairs_; }
    /// Every pair-distance sample (signed, µm), all bodies.
    const std::vector<float>& pair_errors_um() const { return pair_errors_um_; }
    /// Per body: eye, then the instruments, then the wand (when given).
    const std::vector<BodyTrack>& bodies() const { return bodies_; }
    /// The eye centre per frame from a free rigid fit of its markers (rig frame, mm), for frames with ≥ 3
    /// assigned eye markers.
    const std::vector<Eigen::Vector3d>& eye_centres_mm() const { return eye_centres_mm_; }
    /// The configured eye centre (rig frame, mm).
    const Eigen::Vector3d& eye_centre_configured_mm() const { return eye_centre_mm_; }
    /// Per frame: the frame's time (device clock, s) and the RMS reprojection residual of its scored views
    /// (frame px; −1 when none).
    const std::vector<double>& frame_t_s() const { return frame_t_s_; }
    const std::vector<double>& frame_reprojection_px() const { return frame_reprojection_px_; }  ///< see frame_t_s
    /// Triangulated markers no body claimed, over the run.
    long unassigned_markers() const { return unassigned_; }
    /// Marker-frames in tracked spans and how many of them had the marker unassigned (dropouts).
    long span_marker_frames() const;
    long dropped_marker_frames() const;  ///< see span_marker_frames
    /// Index into markers() of body `body`'s marker `marker` (−1 when out of range).
    int marker_index(int body, int marker) const;
    /// Body name ("eye" for 0).
    const std::string& body_name(int body) const { return bodies_[std::size_t(body)].name; }
    /// Body index of the wand (−1: no wand given).
    int wand_body() const { return wand_body_; }

private:
    const BodyMarker& body_marker(int body, int k) const;
    int marker_count(int body) const;
    bool find_wand(const TrackingFrame& frame, std::array<int, kMaxBodyMarkers>& which, InstrumentPose& pose) const;

    BodySet model_;
    InstrumentModel wand_;
    int wand_body_ = -1;
    int ncam_ = 0;
    long frames_ = 0;
    long unassigned_ = 0;
    Eigen::Vector3d eye_centre_mm_ = Eigen::Vector3d::Zero();
    std::vector<CameraResiduals> cameras_;
    std::vector<MarkerResiduals> markers_;
    std::vector<int> body_first_marker_;  // index in markers_ of each body's marker 0
    std::vector<PairDistance> pairs_;
    std::vector<int> body_first_pair_;    // index in pairs_ of each body's first pair
    std::vector<float> pair_errors_um_;
    std::vector<BodyTrack> bodies_;
    std::vector<Eigen::Vector3d> eye_centres_mm_;
    std::vector<double> frame_t_s_, frame_reprojection_px_;
};

}  // namespace eyesim::tracking
