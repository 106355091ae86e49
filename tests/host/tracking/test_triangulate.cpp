#include "eyesim/tracking/distortion.hpp"
#include "eyesim/tracking/triangulate.hpp"

#include "test_support.hpp"

#include <Eigen/LU>
#include <catch2/catch.hpp>
#include <opencv2/calib3d.hpp>

#include <limits>
#include <random>
#include <vector>

using namespace eyesim::tracking;

namespace {

/// Observes X in every camera of the rig with optional Gaussian pixel noise.
std::vector<Observation> observe(std::span<const CameraGeometry> cams, const Eigen::Vector3d& X,
                                 std::mt19937_64* rng = nullptr, double sigma_px = 0.0) {
    std::vector<Observation> obs;
    std::normal_distribution<double> n(0.0, 1.0);
    for (int i = 0; i < int(cams.size()); ++i) {
        Observation o;
        o.camera = i;
        REQUIRE(project_point(cams[std::size_t(i)], X, o.px));
        if (rng) o.px += sigma_px * Eigen::Vector2d(n(*rng), n(*rng));
        o.sigma_px = sigma_px > 0 ? sigma_px : 0.05;
        const Undistorted u = undistort_pixel(cams[std::size_t(i)], o.px);
        REQUIRE(u.converged);
        o.xn = u.xn;
        obs.push_back(o);
    }
    return obs;
}

}  // namespace

TEST_CASE("noise-free projections triangulate back to 1e-9 mm", "[tracking][triangulate]") {
    const auto cams = test::three_camera_rig();
    std::mt19937_64 rng(3);
    double worst = 0.0;
    for (int i = 0; i < 500; ++i) {
        const Eigen::Vector3d X = test::random_point(rng, {0, 0, 5}, 14.0);
        const auto obs = observe(cams, X);
        const TriangulatedPoint p = triangulate(cams, obs);
        REQUIRE(p.usable());
        worst = std::max(worst, (p.X_rig_mm - X).norm());
        // Two-view subsets as well.
        const TriangulatedPoint p2 = triangulate(cams, std::span(obs).subspan(1, 2));
        REQUIRE(p2.usable());
        worst = std::max(worst, (p2.X_rig_mm - X).norm());
    }
    CHECK(worst < 1e-9);
}

TEST_CASE("covariance predicts the scatter under pixel noise", "[tracking][triangulate]") {
    const auto cams = test::three_camera_rig();
    std::mt19937_64 rng(4);
    const double sigma = 0.05;
    double sum_nees = 0.0;
    const int n = 2000;
    for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d X = test::random_point(rng, {0, 0, 5}, 10.0);
        const TriangulatedPoint p = triangulate(cams, observe(cams, X, &rng, sigma));
        REQUIRE(p.usable());
        const Eigen::Vector3d e = p.X_rig_mm - X;
        sum_nees += e.dot(p.cov_mm2.inverse() * e);
    }
    // Normalised estimation error squared is χ²(3): mean 3. Allow sampling and linearisation slack.
    const double mean_nees = sum_nees / n;
    CHECK(mean_nees > 2.7);
    CHECK(mean_nees < 3.3);
}

TEST_CASE("degenerate geometry is flagged and never NaN", "[tracking][triangulate]") {
    const auto cams = test::three_camera_rig();
    const Eigen::Vector3d X(1.0, 2.0, 6.0);
    auto obs = observe(cams, X);
    SECTION("one view") {
        const TriangulatedPoint p = triangulate(cams, std::span(obs).first(1));
        CHECK((p.flags & kTriTooFewViews) != 0);
        CHECK_FALSE(p.usable());
        CHECK(p.X_rig_mm.allFinite());
    }
    SECTION("NaN observation") {
        obs[1].px.x() = std::numeric_limits<double>::quiet_NaN();
        obs[1].xn.x() = std::numeric_limits<double>::quiet_NaN();
        const TriangulatedPoint p = triangulate(cams, obs);
        CHECK((p.flags & kTriNonFinite) != 0);
        CHECK(p.X_rig_mm.allFinite());
        // The two good views still give the point.
        CHECK(p.views == 2);
    }
    SECTION("NaN in two of three views") {
        for (int k : {0, 2}) obs[std::size_t(k)].xn.setConstant(std::numeric_limits<double>::quiet_NaN());
        const TriangulatedPoint p = triangulate(cams, obs);
        CHECK_FALSE(p.usable());
        CHECK(p.X_rig_mm.allFinite());
        CHECK(p.cov_mm2.allFinite());
    }
    SECTION("collinear cameras and a point on their line") {
        // Three cameras on the x axis looking along +z would see a point on the axis only if it were at the
        // epipole; instead put cameras on a line through the point: every ray is the same line.
        std::array<CameraGeometry, 3> line;
        const Eigen::Vector3d P(0, 0, 5);
        for (int i = 0; i < 3; ++i) {
            const Eigen::Vector3d c = P + Eigen::Vector3d(0.2, 0.3, -1.0).normalized() * (-60.0 - 15.0 * i);
            line[std::size_t(i)] = test::look_at_camera(c, P + Eigen::Vector3d(1.0, 0.0, 0.0));
        }
        const auto o = observe(line, P);
        const TriangulatedPoint p = triangulate(line, o);
        CHECK((p.flags & kTriDegenerate) != 0);
        CHECK_FALSE(p.usable());
        CHECK(p.X_rig_mm.allFinite());
        CHECK(p.cov_mm2.allFinite());
    }
    SECTION("a wrong match gives a high residual") {
        obs[2].px += Eigen::Vector2d(6.0, -4.0);
        obs[2].xn = undistort_pixel(cams[2], obs[2].px).xn;
        const TriangulatedPoint p = triangulate(cams, obs);
        CHECK((p.flags & kTriHighResidual) != 0);
    }
}

TEST_CASE("two-view LM is at least as accurate as OpenCV triangulatePoints", "[tracking][triangulate]") {
    const auto cams = test::three_camera_rig();
    std::mt19937_64 rng(5);
    const double sigma = 0.1;
    cv::Mat P0(3, 4, CV_64F), P1(3, 4, CV_64F);
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) {
            P0.at<double>(r, c) = cams[0].R_cam_rig(r, c);
            P1.at<double>(r, c) = cams[1].R_cam_rig(r, c);
        }
        P0.at<double>(r, 3) = cams[0].t_cam_rig_mm(r);
        P1.at<double>(r, 3) = cams[1].t_cam_rig_mm(r);
    }
    double ss_ours = 0.0, ss_cv = 0.0;
    const int n = 2000;
    for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d X = test::random_point(rng, {0, 0, 5}, 12.0);
        const auto obs = observe(cams, X, &rng, sigma);
        const TriangulatedPoint p = triangulate(cams, std::span(obs).first(2));
        REQUIRE(p.usable());
        ss_ours += (p.X_rig_mm - X).squaredNorm();
        // OpenCV on the same undistorted normalised points (identity K).
        cv::Mat x0 = (cv::Mat_<double>(2, 1) << obs[0].xn.x(), obs[0].xn.y());
        cv::Mat x1 = (cv::Mat_<double>(2, 1) << obs[1].xn.x(), obs[1].xn.y());
        cv::Mat Xh;
        cv::triangulatePoints(P0, P1, x0, x1, Xh);
        const Eigen::Vector3d Xcv(Xh.at<double>(0) / Xh.at<double>(3), Xh.at<double>(1) / Xh.at<double>(3),
                                  Xh.at<double>(2) / Xh.at<double>(3));
        ss_cv += (Xcv - X).squaredNorm();
    }
    const double rms_ours = std::sqrt(ss_ours / n), rms_cv = std::sqrt(ss_cv / n);
    INFO("two-view RMS ours " << rms_ours * 1e3 << " um, OpenCV " << rms_cv * 1e3 << " um");
    CHECK(rms_ours <= rms_cv * 1.001);
}
