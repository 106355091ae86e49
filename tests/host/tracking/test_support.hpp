#pragma once
/// \file
/// Shared helpers of the tracking tests: a synthetic three-camera rig below an eye-sized working volume.

#include "eyesim/tracking/camera_geometry.hpp"

#include <Eigen/Core>

#include <array>
#include <random>

namespace eyesim::tracking::test {

/// A camera at `centre_rig_mm` looking at `target_rig_mm` with PAL-like intrinsics and the given distortion.
CameraGeometry look_at_camera(const Eigen::Vector3d& centre_rig_mm, const Eigen::Vector3d& target_rig_mm,
                              const std::array<double, 8>& dist = {-0.25, 0.08, 0.001, -0.0007, -0.01, 0, 0, 0});

/// Three cameras ~80 mm below the eye, 120° apart in azimuth, tilted to the eye centre (origin).
std::array<CameraGeometry, 3> three_camera_rig();

/// Uniform random point in a box of half-size `half_mm` about `centre`.
Eigen::Vector3d random_point(std::mt19937_64& rng, const Eigen::Vector3d& centre, double half_mm);

}  // namespace eyesim::tracking::test
