#pragma once
/// \file
/// Cross-camera correspondence of marker images: by colour class, gated by epipolar (two-view) and epipolar
/// transfer (three-view, trifocal) consistency, decided by triangulated reprojection error with outlier
/// rejection. Fixed capacities; no allocation per frame.

#include "eyesim/tracking/camera_geometry.hpp"
#include "eyesim/tracking/triangulate.hpp"

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <span>

namespace eyesim::tracking {

/// Marker images one camera can contribute to one tracking frame.
inline constexpr int kMaxMarkersPerCamera = 32;
/// 3D markers one tracking frame can hold.
inline constexpr int kMaxMarkersPerFrame = 32;

/// One marker image, already mapped to full-frame pixels and undistorted.
struct ImagePoint {
    std::uint8_t colour_class = 0;                 ///< 1..4
    std::uint8_t flags = 0;                        ///< protocol Marker flags (border, merged, …)
    Eigen::Vector2d px = Eigen::Vector2d::Zero();  ///< distorted full-frame pixel
    Eigen::Vector2d xn = Eigen::Vector2d::Zero();  ///< undistorted normalised point (z = 1)
    double sigma_px = 0.05;                        ///< 1σ centroid noise (pixels)
    float area_px = 0.0f;                          ///< blob area in field pixels (0: unknown)
};

/// Everything one camera contributes to one tracking frame (after time alignment).
struct CameraObservations {
    bool present = false;  ///< false: camera missing in this frame (dropped field, out of sync)
    int count = 0;         ///< valid entries in `points`
    std::array<ImagePoint, kMaxMarkersPerCamera> points{};  ///< the first `count` are valid
};

/// One 3D marker found by correspondence.
struct MatchedMarker {
    std::uint8_t colour_class = 0;  ///< 1..4
    TriangulatedPoint point;        ///< position, covariance, residual, flags
    std::array<std::int8_t, kMaxCameras> image_index{};  ///< index in each camera's points, −1 when unused
    std::uint8_t occluded_views = 0;  ///< bit c: camera c's image was judged partly occluded (left out of the fit)
    bool occluded = false;            ///< fewer than two unoccluded views: position biased, fit it last
};

/// Result of one frame's correspondence.
struct CorrespondenceResult {
    int count = 0;  ///< valid entries in `markers`
    std::array<MatchedMarker, kMaxMarkersPerFrame> markers{};  ///< the first `count` are valid
    int unmatched_images = 0;      ///< marker images left without a consistent partner (one-view, outliers)
    int rejected_hypotheses = 0;   ///< candidate matches that failed the residual test
};

/// A region a colour class's markers must lie in: a spherical shell (all eye markers sit on the eye) — rejects
/// two-view "ghost" intersections of same-coloured markers, which are epipolar-consistent by construction.
struct ClassRegion {
    bool enabled = false;                                    ///< false: any position is plausible
    Eigen::Vector3d centre_rig_mm = Eigen::Vector3d::Zero(); ///< shell centre
    double radius_mm = 0.0;                                  ///< shell radius
    double tolerance_mm = 0.5;                               ///< accepted |distance − radius|
};

/// Options of the correspondence search.
struct CorrespondenceOptions {
    double epipolar_gate_px = 2.0;   ///< max distance of an image from the partner's epipolar line (pixels)
    double max_rms_px = 0.6;         ///< max reprojection RMS of an accepted match (pixels)
    TriangulationOptions triangulation;  ///< passed to `triangulate`
    std::array<ClassRegion, 5> region{};  ///< per colour class 1..4 (index 0 unused)
    /// Partial-occlusion test of each view from its blob area: a marker sphere of this radius (mm) at the
    /// triangulated depth covers π·(fx·r/z)·(fy·r/z)/2 field pixels; a view whose area is below
    /// `min_area_ratio` of that, or below `relative_area_ratio` of the best view's ratio, is partly hidden (by the
    /// eye, a shaft, another instrument) and its centroid biased by up to a marker radius. Such views are left out
    /// when two others remain. 0 disables.
    double marker_radius_mm = 0.0;
    double min_area_ratio = 0.6;       ///< absolute area ratio below which a view is occluded
    double relative_area_ratio = 0.85; ///< ratio to the best view below which a view is occluded
    /// A small blob's area varies from view to view by its edge pixels (a 4-px marker: ±10 % between fields, three
    /// views 25 % apart): the relative threshold is at most 1 − this/√(expected area, field px): 0.75 at 25 px,
    /// 0.85 from 69 px. 0: off.
    double relative_area_noise = 1.25;
};

/// Same-coloured images per camera the search considers (more are left unmatched and counted).
inline constexpr int kMaxImagesPerClass = 16;

/// Finds, per colour class, which images in different cameras show the same marker, and triangulates them.
class Correspondence {
public:
    /// Precomputes the essential matrices of every camera pair. `cams` must outlive this object.
    Correspondence(std::span<const CameraGeometry> cams, const CorrespondenceOptions& opt = {});

    /// Matches `views` (one entry per camera, same order as the cameras) into `out`. Per colour class, candidate
    /// triples (every pair on its epipolar line) and pairs are ranked by summed epipolar distance; they are
    /// triangulated lazily in that order, triples first, and accepted when the reprojection RMS and the class
    /// region agree; an image is used at most once. An outlier image makes its triple fail, and the marker is
    /// then kept from the remaining consistent pair. With `marker_radius_mm`, a triple that fails only by one
    /// view whose blob is small for its depth (mostly hidden) is kept from the other two, that view marked
    /// occluded; and pairs whose poorer view's blob is small rank after pairs that see more of the marker.
    void solve(std::span<const CameraObservations> views, CorrespondenceResult& out) const;

    /// Symmetric epipolar distance (pixels) between image `xa` in camera a and `xb` in camera b.
    double epipolar_distance_px(int a, int b, const Eigen::Vector2d& xa, const Eigen::Vector2d& xb) const;

    /// The options in use.
    const CorrespondenceOptions& options() const { return opt_; }

    /// Camera c's blob area p over the area a marker at X would have there (−1: unknown).
    double area_ratio(const ImagePoint& p, int c, const Eigen::Vector3d& X_rig_mm) const;
    /// The views of the images `idx` (−1: none) whose blob is small for a marker at X (partly hidden); `clean`: the
    /// others.
    std::uint8_t occluded_views(std::span<const CameraObservations> views, const std::array<std::int8_t, kMaxCameras>& idx,
                                const Eigen::Vector3d& X_rig_mm, int ncam, int& clean) const;

private:
    void check_occlusion(std::span<const CameraObservations> views, MatchedMarker& m, int ncam) const;
    /// The field pixels a marker sphere at X covers in camera c (−1: behind it).
    double expected_area_px(int c, const Eigen::Vector3d& X_rig_mm) const;
    /// The share of the best view's area ratio below which a view whose sphere covers `expected_area_px` field
    /// pixels is judged partly hidden: relative_area_ratio, lowered for small blobs by relative_area_noise.
    double relative_area_threshold(double expected_area_px) const;

    std::span<const CameraGeometry> cams_;
    CorrespondenceOptions opt_;
    std::array<std::array<Eigen::Matrix3d, kMaxCameras>, kMaxCameras> E_{};  ///< x_bᵀ E[a][b] x_a = 0
};

}  // namespace eyesim::tracking
