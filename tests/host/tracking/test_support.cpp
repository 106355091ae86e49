#include "test_support.hpp"

#include <Eigen/Geometry>

#include <cmath>
#include <numbers>

namespace eyesim::tracking::test {

CameraGeometry look_at_camera(const Eigen::Vector3d& centre, const Eigen::Vector3d& target,
                              const std::array<double, 8>& dist) {
    CameraGeometry c;
    c.fx = 1100.0;
    c.fy = 1090.0;
    c.cx = 361.3;
    c.cy = 287.6;
    c.dist = dist;
    const Eigen::Vector3d z = (target - centre).normalized();
    Eigen::Vector3d up(0, 0, 1);
    if (std::abs(z.dot(up)) > 0.95) up = Eigen::Vector3d(0, 1, 0);
    const Eigen::Vector3d x = up.cross(z).normalized();
    const Eigen::Vector3d y = z.cross(x);
    Eigen::Matrix3d R;  // rows: camera axes in rig coordinates (rig→camera)
    R.row(0) = x.transpose();
    R.row(1) = y.transpose();
    R.row(2) = z.transpose();
    c.R_cam_rig = R;
    c.t_cam_rig_mm = -R * centre;
    return c;
}

std::array<CameraGeometry, 3> three_camera_rig() {
    std::array<CameraGeometry, 3> cams;
    for (int i = 0; i < 3; ++i) {
        const double a = 2.0 * std::numbers::pi * i / 3.0 + 0.3;
        const Eigen::Vector3d centre(55.0 * std::cos(a), 55.0 * std::sin(a), -80.0);
        cams[std::size_t(i)] = look_at_camera(centre, Eigen::Vector3d(0, 0, 5.0));
    }
    return cams;
}

Eigen::Vector3d random_point(std::mt19937_64& rng, const Eigen::Vector3d& centre, double half_mm) {
    std::uniform_real_distribution<double> u(-half_mm, half_mm);
    return centre + Eigen::Vector3d(u(rng), u(rng), u(rng));
}

}  // namespace eyesim::tracking::test
