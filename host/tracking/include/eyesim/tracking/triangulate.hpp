#pragma once
/// \file
/// N-view triangulation of one marker: linear DLT on undistorted normalised rays, then Levenberg–Marquardt
/// refinement of the distorted-pixel reprojection error, with a per-point covariance (Eigen, fixed size).

#include "eyesim/tracking/camera_geometry.hpp"

#include <Eigen/Core>

#include <cstdint>
#include <span>

namespace eyesim::tracking {

/// One 2D observation of a marker in one camera.
struct Observation {
    int camera = 0;                                 ///< index into the camera array
    Eigen::Vector2d px = Eigen::Vector2d::Zero();   ///< observed distorted pixel (full-frame pixels)
    Eigen::Vector2d xn = Eigen::Vector2d::Zero();   ///< undistorted normalised point (z = 1) of `px`
    double sigma_px = 0.05;                         ///< 1σ centroid noise of this observation (pixels)
};

/// Bit flags describing why a triangulated point is unreliable (0 = good).
enum TriangulationFlag : std::uint32_t {
    kTriOk = 0,
    kTriTooFewViews = 1u << 0,       ///< fewer than two views: depth unobservable
    kTriNonFinite = 1u << 1,         ///< NaN/Inf in an observation or camera
    kTriDegenerate = 1u << 2,        ///< rays (nearly) parallel: √trace(covariance) beyond `max_sigma_mm`
    kTriBehindCamera = 1u << 3,      ///< solution not in front of every camera that saw it
    kTriNotConverged = 1u << 4,      ///< LM hit its iteration limit without settling
    kTriHighResidual = 1u << 5,      ///< reprojection RMS above `max_rms_px` (likely a wrong match)
};

/// Options of `triangulate`.
struct TriangulationOptions {
    int max_iterations = 20;        ///< LM iteration bound (2–4 are typical from the DLT start)
    double step_tolerance_mm = 1e-6;   ///< stop when the next update would be smaller than this (1 nm)
    double max_sigma_mm = 1.0;      ///< largest acceptable √trace of the covariance (else kTriDegenerate)
    double max_rms_px = 1.0;        ///< largest acceptable reprojection RMS (else kTriHighResidual)
    bool refine = true;             ///< false: linear DLT only (for comparisons)
};

/// A triangulated marker.
struct TriangulatedPoint {
    Eigen::Vector3d X_rig_mm = Eigen::Vector3d::Zero();   ///< position in the rig frame (mm); 0 when invalid
    Eigen::Matrix3d cov_mm2 = Eigen::Matrix3d::Zero();    ///< covariance from σ_px through the LM Jacobian (mm²)
    double rms_px = 0.0;        ///< reprojection RMS over the views (pixels)
    int views = 0;              ///< observations used
    int iterations = 0;         ///< LM iterations run
    std::uint32_t flags = kTriOk;  ///< TriangulationFlag bits

    /// True when the point can be used (no flag other than kTriNotConverged).
    bool usable() const { return (flags & ~std::uint32_t(kTriNotConverged)) == 0; }
};

/// Linear N-view DLT (inhomogeneous least squares on the normalised rays). Returns false when fewer than two
/// finite observations or the normal matrix is singular; `X` is left unchanged then.
bool triangulate_dlt(std::span<const CameraGeometry> cams, std::span<const Observation> obs,
                     Eigen::Vector3d& X_rig_mm);

/// DLT then LM on the pixel reprojection error; fills covariance, residual and flags. Never returns NaN: an
/// unusable point carries flags and a zero (or the DLT) position. Allocation-free.
TriangulatedPoint triangulate(std::span<const CameraGeometry> cams, std::span<const Observation> obs,
                              const TriangulationOptions& opt = {});

}  // namespace eyesim::tracking
