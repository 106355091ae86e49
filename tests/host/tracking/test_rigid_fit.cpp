#include "eyesim/tracking/rigid_fit.hpp"

#include <catch2/catch.hpp>

#include <random>
#include <vector>

using namespace eyesim::tracking;

namespace {

Eigen::Matrix3d random_rotation(std::mt19937_64& rng) {
    std::normal_distribution<double> n(0.0, 1.0);
    return Eigen::Quaterniond(n(rng), n(rng), n(rng), n(rng)).normalized().toRotationMatrix();
}

}  // namespace

TEST_CASE("Kabsch recovers known rotations and translations", "[tracking][rigid]") {
    std::mt19937_64 rng(6);
    std::normal_distribution<double> n(0.0, 5.0);
    for (int trial = 0; trial < 200; ++trial) {
        const Eigen::Matrix3d R = random_rotation(rng);
        const Eigen::Vector3d t(n(rng), n(rng), n(rng));
        std::vector<Eigen::Vector3d> b, m;
        for (int i = 0; i < 3 + trial % 5; ++i) {
            b.emplace_back(n(rng), n(rng), n(rng));
            m.push_back(R * b.back() + t);
        }
        const RigidFit f = fit_rigid(b, m);
        REQUIRE(f.ok);
        CHECK((f.R - R).norm() < 1e-10);
        CHECK((f.t_mm - t).norm() < 1e-10);
        CHECK(f.rms_mm < 1e-10);
        CHECK(rotation_angle_deg(f.R, R) < 1e-7);
    }
}

TEST_CASE("Kabsch handles near-180 degree rotations and rejects a reflection", "[tracking][rigid]") {
    const Eigen::Matrix3d R = Eigen::AngleAxisd(3.14159, Eigen::Vector3d(1, 2, 3).normalized()).matrix();
    std::vector<Eigen::Vector3d> b{{1, 0, 0}, {0, 2, 0}, {0, 0, 3}, {1, 1, 1}};
    std::vector<Eigen::Vector3d> m;
    for (const auto& p : b) m.push_back(R * p);
    const RigidFit f = fit_rigid(b, m);
    REQUIRE(f.ok);
    CHECK(f.R.determinant() == Approx(1.0));
    CHECK(rotation_angle_deg(f.R, R) < 1e-7);
}

TEST_CASE("rotation about a fixed centre from two vectors", "[tracking][rigid]") {
    std::mt19937_64 rng(7);
    const Eigen::Vector3d c(0.5, -1.0, 3.0);
    for (int trial = 0; trial < 100; ++trial) {
        const Eigen::Matrix3d R = random_rotation(rng);
        std::vector<Eigen::Vector3d> b{{12, 0, 0}, {0, 8.5, 8.5}};
        std::vector<Eigen::Vector3d> m{R * b[0] + c, R * b[1] + c};
        const RigidFit f = fit_rotation_about(c, b, m);
        REQUIRE(f.ok);
        CHECK(rotation_angle_deg(f.R, R) < 1e-7);
    }
}

TEST_CASE("degenerate point sets are flagged", "[tracking][rigid]") {
    std::vector<Eigen::Vector3d> collinear{{0, 0, 0}, {0, 0, 5}, {0, 0, 10}};
    std::vector<Eigen::Vector3d> moved{{1, 0, 0}, {1, 0, 5}, {1, 0, 10}};
    CHECK_FALSE(fit_rigid(collinear, moved).ok);
    std::vector<Eigen::Vector3d> two{{0, 0, 0}, {1, 0, 0}};
    CHECK_FALSE(fit_rigid(two, two).ok);
    std::vector<Eigen::Vector3d> nan{{0, 0, 0}, {1, 0, 0}, {0, std::nan(""), 1}};
    const RigidFit f = fit_rigid(nan, nan);
    CHECK_FALSE(f.ok);
    CHECK(f.R.allFinite());
}
