#pragma once
/// \file
/// OpenCV lens distortion forward (with Jacobian) and its inverse by Newton iteration to convergence, plus the
/// full projection rig point → distorted pixel with its Jacobian.

#include "eyesim/tracking/camera_geometry.hpp"

#include <Eigen/Core>

namespace eyesim::tracking {

/// Applies the distortion to a normalised (undistorted, z=1) image point. When `J` is given it receives
/// ∂x_distorted/∂x_normalised.
Eigen::Vector2d distort_normalized(const CameraGeometry& cam, const Eigen::Vector2d& xn,
                                   Eigen::Matrix2d* J = nullptr);

/// Result of undistorting one pixel.
struct Undistorted {
    Eigen::Vector2d xn = Eigen::Vector2d::Zero();  ///< normalised image point (z = 1)
    int iterations = 0;         ///< Newton iterations used
    double residual_px = 0.0;   ///< |distort(xn) − observed| in pixels after the last iteration
    bool converged = false;     ///< residual below tolerance (and finite input)
};

/// Options of the inverse distortion.
struct UndistortOptions {
    double tolerance_px = 1e-9;  ///< stop when the forward-projected point is this close to the pixel
    int max_iterations = 50;     ///< safety bound only: Newton converges in 2–5 steps inside the image
};

/// Inverts the distortion of a pixel: solves distort(xn) = K⁻¹·px by damped Newton iteration until the
/// forward model reproduces the pixel to `tolerance_px` (not a fixed count of fixed-point steps, which
/// leaves residuals near the image corners under strong distortion). Non-finite input → converged = false.
Undistorted undistort_pixel(const CameraGeometry& cam, const Eigen::Vector2d& px,
                            const UndistortOptions& opt = {});

/// Projects a rig-frame point to a distorted pixel. Returns false when the point is not in front of the camera
/// (z ≤ 0) or not finite. When `J` is given it receives ∂px/∂X_rig.
bool project_point(const CameraGeometry& cam, const Eigen::Vector3d& X_rig_mm, Eigen::Vector2d& px,
                   Eigen::Matrix<double, 2, 3>* J = nullptr);

}  // namespace eyesim::tracking
