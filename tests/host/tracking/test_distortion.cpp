#include "eyesim/tracking/distortion.hpp"

#include "test_support.hpp"

#include <catch2/catch.hpp>
#include <opencv2/calib3d.hpp>

#include <limits>
#include <random>

using namespace eyesim::tracking;

namespace {

cv::Mat camera_matrix(const CameraGeometry& c) {
    return (cv::Mat_<double>(3, 3) << c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1);
}

cv::Mat dist_coeffs(const CameraGeometry& c) {
    cv::Mat d(1, 8, CV_64F);
    for (int i = 0; i < 8; ++i) d.at<double>(i) = c.dist[std::size_t(i)];
    return d;
}

}  // namespace

TEST_CASE("distortion matches OpenCV projectPoints", "[tracking][distortion]") {
    std::array<double, 8> rational{-0.31, 0.12, 0.0013, -0.0009, -0.02, 0.05, -0.01, 0.004};
    const CameraGeometry cam = test::look_at_camera({10, -20, -80}, {0, 0, 5}, rational);
    std::mt19937_64 rng(1);
    std::vector<cv::Point3d> pts;
    std::vector<Eigen::Vector3d> epts;
    for (int i = 0; i < 200; ++i) {
        const Eigen::Vector3d X = test::random_point(rng, {0, 0, 5}, 12.0);
        epts.push_back(X);
        pts.emplace_back(X.x(), X.y(), X.z());
    }
    cv::Mat R(3, 3, CV_64F), rvec, tvec(3, 1, CV_64F);
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) R.at<double>(r, c) = cam.R_cam_rig(r, c);
        tvec.at<double>(r) = cam.t_cam_rig_mm(r);
    }
    cv::Rodrigues(R, rvec);
    std::vector<cv::Point2d> img;
    cv::projectPoints(pts, rvec, tvec, camera_matrix(cam), dist_coeffs(cam), img);
    for (std::size_t i = 0; i < pts.size(); ++i) {
        Eigen::Vector2d px;
        REQUIRE(project_point(cam, epts[i], px));
        CHECK(std::abs(px.x() - img[i].x) < 1e-9);
        CHECK(std::abs(px.y() - img[i].y) < 1e-9);
    }
}

TEST_CASE("distortion Jacobian matches finite differences", "[tracking][distortion]") {
    std::array<double, 8> rational{-0.31, 0.12, 0.0013, -0.0009, -0.02, 0.05, -0.01, 0.004};
    const CameraGeometry cam = test::look_at_camera({10, -20, -80}, {0, 0, 5}, rational);
    std::mt19937_64 rng(2);
    for (int i = 0; i < 50; ++i) {
        const Eigen::Vector3d X = test::random_point(rng, {0, 0, 5}, 12.0);
        Eigen::Vector2d px;
        Eigen::Matrix<double, 2, 3> J;
        REQUIRE(project_point(cam, X, px, &J));
        for (int k = 0; k < 3; ++k) {
            Eigen::Vector3d d = Eigen::Vector3d::Zero();
            d[k] = 1e-5;
            Eigen::Vector2d p1, p0;
            REQUIRE(project_point(cam, X + d, p1));
            REQUIRE(project_point(cam, X - d, p0));
            const Eigen::Vector2d fd = (p1 - p0) / 2e-5;
            CHECK((fd - J.col(k)).norm() < 1e-5 * (1.0 + fd.norm()));
        }
    }
}

TEST_CASE("undistortion round-trips to the forward model over the whole image", "[tracking][distortion]") {
    // Strong barrel distortion: a few fixed-point steps would leave visible residuals near the corners.
    std::array<double, 8> strong{-0.42, 0.25, 0.002, -0.001, -0.08, 0, 0, 0};
    CameraGeometry cam = test::look_at_camera({0, 0, -80}, {0, 0, 5}, strong);
    int worst_it = 0;
    double worst = 0.0;
    for (double v = 0.0; v <= 576.0; v += 16.0) {
        for (double u = 0.0; u <= 720.0; u += 16.0) {
            const Undistorted r = undistort_pixel(cam, {u, v});
            REQUIRE(r.converged);
            const Eigen::Vector2d back = distort_normalized(cam, r.xn);
            const Eigen::Vector2d back_px(cam.fx * back.x() + cam.cx, cam.fy * back.y() + cam.cy);
            worst = std::max(worst, (back_px - Eigen::Vector2d(u, v)).norm());
            worst_it = std::max(worst_it, r.iterations);
        }
    }
    CHECK(worst < 1e-9);
    CHECK(worst_it < 20);
}

TEST_CASE("undistortion agrees with OpenCV undistortPoints run to convergence", "[tracking][distortion]") {
    std::array<double, 8> rational{-0.31, 0.12, 0.0013, -0.0009, -0.02, 0.05, -0.01, 0.004};
    const CameraGeometry cam = test::look_at_camera({0, 0, -80}, {0, 0, 5}, rational);
    std::vector<cv::Point2d> px;
    for (double v = 20.0; v <= 556.0; v += 24.0)
        for (double u = 20.0; u <= 700.0; u += 24.0) px.emplace_back(u, v);
    std::vector<cv::Point2d> cv_out, cv_default;
    // OpenCV's default is 5 fixed-point iterations; with a strict criterion it converges to the same point.
    cv::undistortPoints(px, cv_out, camera_matrix(cam), dist_coeffs(cam), cv::noArray(), cv::noArray(),
                        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 500, 1e-15));
    cv::undistortPoints(px, cv_default, camera_matrix(cam), dist_coeffs(cam));
    double worst_strict = 0.0, worst_default = 0.0;
    for (std::size_t i = 0; i < px.size(); ++i) {
        const Undistorted r = undistort_pixel(cam, {px[i].x, px[i].y});
        REQUIRE(r.converged);
        worst_strict = std::max(worst_strict, cam.fx * std::hypot(r.xn.x() - cv_out[i].x, r.xn.y() - cv_out[i].y));
        worst_default =
            std::max(worst_default, cam.fx * std::hypot(r.xn.x() - cv_default[i].x, r.xn.y() - cv_default[i].y));
    }
    CHECK(worst_strict < 1e-6);  // pixels
    // The default count is measurably short of convergence at the corners: the reason we iterate to tolerance.
    CHECK(worst_default > worst_strict);
}

TEST_CASE("undistortion flags non-finite input", "[tracking][distortion]") {
    const CameraGeometry cam = test::look_at_camera({0, 0, -80}, {0, 0, 5});
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const Undistorted r = undistort_pixel(cam, {nan, 100.0});
    CHECK_FALSE(r.converged);
    CHECK(r.xn.allFinite());
}
