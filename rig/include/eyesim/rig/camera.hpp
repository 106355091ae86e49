#pragma once
/// \file
/// One PAL camera of the rig: OpenCV pinhole + distortion model, rig→camera pose, field geometry and timing;
/// `rig.yaml` reading and writing.
///
/// Conventions
/// - Rig frame (mm): origin at the centre of the mechanical eye at rest, +z up towards the surgeon/microscope,
///   +x to the surgeon's right, +y away from the surgeon (right-handed). Cameras sit below the eye (z < 0) and
///   look up.
/// - Camera frame: OpenCV (x right in the image, y down, z along the optical axis). x_cam = R * x_rig + t.
/// - K, distortion and image size in rig.yaml are the FRAME (720×576) intrinsics exactly as OpenCV uses them
///   (cv::projectPoints, cv::undistortPoints, calibrateCamera all apply unchanged). Pixel centres are at integer
///   coordinates: frame pixel (u, v) covers [u-0.5, u+0.5] × [v-0.5, v+0.5].
/// - Fields: field row y of parity p IS frame row v = 2y + p. Continuous mapping (exact):
///   field (x, y) of parity p ↔ frame (u, v) = (x, 2y + p); field y = (v - p) / 2. Field pixel (x, y) integrates
///   the frame pixel square around (x, 2y + p) (frame-integration CCD read out interlaced).
/// - Parity of field index i of a camera: (first_field_parity + i) mod 2; 0 = top field (frame rows 0,2,4,...).
///   Recordings start with a top field (first_field_parity = 0) unless rig.yaml says otherwise.

#include "eyesim/rig/pal.hpp"

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace eyesim::rig {

/// One camera: intrinsics, distortion, pose, PAL field order and clock. Plain data; all methods are const.
struct CameraModel {
    std::string name = "cam0";            ///< "cam0".."cam2": also the stem of its stream file
    int image_width = kFrameWidth;        ///< frame width the intrinsics refer to (720)
    int image_height = kFrameHeight;      ///< frame height the intrinsics refer to (576)
    double fx = 615.0;                    ///< focal length, frame pixels (horizontal)
    double fy = 640.0;                    ///< focal length, frame pixels (vertical)
    double cx = 359.5;                    ///< principal point, frame pixels
    double cy = 287.5;                    ///< principal point, frame pixels
    std::array<double, 5> dist{};         ///< OpenCV order: k1, k2, p1, p2, k3
    Eigen::Matrix3d R_cam_rig = Eigen::Matrix3d::Identity();  ///< rotation rig→camera
    Eigen::Vector3d t_cam_rig_mm = Eigen::Vector3d::Zero();   ///< translation rig→camera, mm
    int first_field_parity = 0;           ///< parity of field index 0 (0 = top)
    double field_time_offset_us = 0.0;    ///< start of field 0 on the recording clock (unsynchronised cameras)
    double exposure_us = 4000.0;          ///< shutter time per field
    /// Largest squared undistorted normalised radius (x/z)²+(y/z)² for which the distortion polynomial is
    /// trusted (monotonic); points beyond it are reported as not projectable.
    double max_r2 = 1.0;

    /// x_cam = R * x_rig + t (mm).
    Eigen::Vector3d to_camera(const Eigen::Vector3d& x_rig_mm) const { return R_cam_rig * x_rig_mm + t_cam_rig_mm; }
    /// Camera centre in the rig frame (mm).
    Eigen::Vector3d center_rig_mm() const { return -R_cam_rig.transpose() * t_cam_rig_mm; }

    /// Applies distortion and K to an undistorted normalised point (x/z, y/z): frame pixels, OpenCV formula.
    Eigen::Vector2d distort_normalized(const Eigen::Vector2d& xy) const;
    /// Frame-pixel Jacobian d(u,v)/d(x,y) of `distort_normalized` at xy.
    Eigen::Matrix2d distort_jacobian(const Eigen::Vector2d& xy) const;
    /// Inverse of `distort_normalized` by Newton iteration to 1e-12 (normalised units); nullopt if it fails.
    std::optional<Eigen::Vector2d> undistort_to_normalized(const Eigen::Vector2d& frame_px) const;

    /// Projects a rig point to FRAME pixels (identical to cv::projectPoints with K, dist, rvec(R), t).
    /// nullopt when the point is not in front of the camera (z <= 1e-6 mm) or beyond max_r2.
    /// Does not check the image bounds.
    std::optional<Eigen::Vector2d> project_frame(const Eigen::Vector3d& x_rig_mm) const;
    /// Projects a rig point to FIELD pixels of the given parity: (u, (v - parity) / 2).
    std::optional<Eigen::Vector2d> project_field(const Eigen::Vector3d& x_rig_mm, int parity) const;

    /// Parity of the camera's field `index`.
    int field_parity(int64_t index) const noexcept {
        return static_cast<int>((first_field_parity + (index & 1)) & 1);
    }
    /// Timing of the camera's field `index` (see pal.hpp).
    FieldTiming field_timing(int64_t index) const;

    /// K as OpenCV wants it.
    cv::Matx33d camera_matrix() const { return {fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0}; }
    /// Distortion coefficients (k1, k2, p1, p2, k3) as OpenCV wants them.
    cv::Vec<double, 5> dist_coeffs() const { return {dist[0], dist[1], dist[2], dist[3], dist[4]}; }
    /// Rodrigues vector of R_cam_rig (for cv::projectPoints / solvePnP).
    cv::Vec3d rvec() const;
    /// t_cam_rig_mm as an OpenCV vector.
    cv::Vec3d tvec() const { return {t_cam_rig_mm.x(), t_cam_rig_mm.y(), t_cam_rig_mm.z()}; }
};

/// Field pixel of parity p → frame pixel: (x, 2y + p).
inline Eigen::Vector2d field_to_frame_px(const Eigen::Vector2d& field_px, int parity) {
    return {field_px.x(), 2.0 * field_px.y() + parity};
}
/// Frame pixel → field pixel of parity p: (u, (v - p) / 2).
inline Eigen::Vector2d frame_to_field_px(const Eigen::Vector2d& frame_px, int parity) {
    return {frame_px.x(), 0.5 * (frame_px.y() - parity)};
}

/// The rig's default three cameras: below the eye at azimuths 90°, 210°, 330°, 86 mm from the eye
/// centre, (68 mm out, 52 mm down), looking up at a point 14 mm above it; 1/3" CCD with a 4 mm lens (fx≈615, fy≈640 frame px), barrel
/// distortion; unsynchronised clocks (offsets 0, 6700, 13300 µs); 4 ms shutter.
std::vector<CameraModel> default_rig();

/// Reads rig.yaml (OpenCV FileStorage). Layout:
/// ```
/// camera_count: 3
/// cam0: { image_width: 720, image_height: 576, K: !!opencv-matrix 3x3 d, dist: 1x5 d, R: 3x3 d, t: 3x1 d (mm),
///         first_field_parity: 0, field_time_offset_us: 0., exposure_us: 4000., max_r2: 1. }
/// cam1: ...
/// ```
/// `first_field_parity`, `field_time_offset_us`, `exposure_us`, `max_r2` are optional (defaults above).
/// Throws RigError "<path>: <key>: <why>" on a missing file, missing key, wrong matrix size, NaN/Inf, a
/// non-rotation R, non-positive focal length, or an image size other than 720×576.
std::vector<CameraModel> load_rig_yaml(const std::string& path);

/// Writes rig.yaml in the layout above (full double precision). Throws RigError if it cannot be written.
void save_rig_yaml(const std::string& path, const std::vector<CameraModel>& cams);

}  // namespace eyesim::rig
