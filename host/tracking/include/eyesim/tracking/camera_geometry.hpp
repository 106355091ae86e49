#pragma once
/// \file
/// Camera geometry used in the tracking hot path: pinhole intrinsics, OpenCV distortion and rig→camera extrinsics
/// in fixed-size Eigen types (no allocation). Built from the rig's CameraModel (rig.yaml) by `rig_adapter.hpp`.

#include <Eigen/Core>

#include <array>

namespace eyesim::tracking {

/// One calibrated camera. Pixel coordinates are full-frame (720×576) pixels as in rig.yaml's K; field rows are
/// mapped to frame rows before they get here. Distortion follows OpenCV's model exactly:
/// radial (k1 k2 k3)/(k4 k5 k6), tangential (p1 p2); coefficient order k1 k2 p1 p2 k3 k4 k5 k6.
struct CameraGeometry {
    double fx = 1.0;  ///< focal length in pixels along x
    double fy = 1.0;  ///< focal length in pixels along y
    double cx = 0.0;  ///< principal point x (pixels)
    double cy = 0.0;  ///< principal point y (pixels)
    std::array<double, 8> dist{};  ///< k1 k2 p1 p2 k3 k4 k5 k6 (zeros: no distortion)
    Eigen::Matrix3d R_cam_rig = Eigen::Matrix3d::Identity();  ///< rotation rig→camera: X_cam = R X_rig + t
    Eigen::Vector3d t_cam_rig_mm = Eigen::Vector3d::Zero();   ///< translation rig→camera (mm)

    /// Camera centre in the rig frame (mm): −Rᵀt.
    Eigen::Vector3d centre_rig_mm() const { return -R_cam_rig.transpose() * t_cam_rig_mm; }

    /// True when all entries are finite, focal lengths positive and R orthonormal with det +1.
    bool valid() const;

    /// Mean focal length (pixels): converts normalised-plane distances to approximate pixels.
    double mean_focal_px() const { return 0.5 * (fx + fy); }
};

/// Maximum number of cameras a tracking frame combines (the rig has three; fixed capacity keeps the hot path
/// allocation-free).
inline constexpr int kMaxCameras = 4;

}  // namespace eyesim::tracking
