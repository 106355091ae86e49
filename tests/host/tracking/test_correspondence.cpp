#include "eyesim/tracking/correspondence.hpp"
#include "eyesim/tracking/distortion.hpp"

#include "test_support.hpp"

#include <catch2/catch.hpp>

#include <random>
#include <vector>

using namespace eyesim::tracking;

namespace {

struct Scene {
    std::vector<Eigen::Vector3d> X;
    std::vector<std::uint8_t> cls;
};

/// Images every marker in every camera (with noise), shuffled per camera so order carries no information.
std::array<CameraObservations, 3> image(const std::array<CameraGeometry, 3>& cams, const Scene& s,
                                        std::mt19937_64& rng, double sigma,
                                        std::vector<std::array<int, 3>>* where = nullptr) {
    std::array<CameraObservations, 3> v;
    std::normal_distribution<double> n(0.0, sigma);
    if (where) where->assign(s.X.size(), {-1, -1, -1});
    for (int c = 0; c < 3; ++c) {
        v[std::size_t(c)].present = true;
        std::vector<int> order(s.X.size());
        for (std::size_t i = 0; i < order.size(); ++i) order[i] = int(i);
        std::shuffle(order.begin(), order.end(), rng);
        for (int i : order) {
            ImagePoint p;
            REQUIRE(project_point(cams[std::size_t(c)], s.X[std::size_t(i)], p.px));
            p.px += Eigen::Vector2d(n(rng), n(rng));
            p.xn = undistort_pixel(cams[std::size_t(c)], p.px).xn;
            p.colour_class = s.cls[std::size_t(i)];
            p.sigma_px = std::max(sigma, 0.02);
            auto& cv = v[std::size_t(c)];
            if (where) (*where)[std::size_t(i)][std::size_t(c)] = cv.count;
            cv.points[std::size_t(cv.count++)] = p;
        }
    }
    return v;
}

/// Index of the scene marker nearest to a result (for scoring).
int nearest(const Scene& s, const Eigen::Vector3d& X) {
    int best = -1;
    double bd = 1e300;
    for (std::size_t i = 0; i < s.X.size(); ++i) {
        const double d = (s.X[i] - X).norm();
        if (d < bd) { bd = d; best = int(i); }
    }
    return best;
}

Scene random_scene(std::mt19937_64& rng, int n) {
    Scene s;
    for (int i = 0; i < n; ++i) {
        s.X.push_back(test::random_point(rng, {0, 0, 5}, 12.0));
        s.cls.push_back(std::uint8_t(1 + i % 4));
    }
    return s;
}

}  // namespace

TEST_CASE("correspondence recovers ten markers with repeated colours", "[tracking][correspondence]") {
    const auto cams = test::three_camera_rig();
    const Correspondence corr(cams);
    std::mt19937_64 rng(11);
    int total = 0, correct = 0;
    double ss = 0.0;
    for (int trial = 0; trial < 200; ++trial) {
        const Scene s = random_scene(rng, 10);
        const auto views = image(cams, s, rng, 0.05);
        CorrespondenceResult r;
        corr.solve(views, r);
        total += 10;
        for (int m = 0; m < r.count; ++m) {
            const auto& mm = r.markers[std::size_t(m)];
            const int i = nearest(s, mm.point.X_rig_mm);
            const double e = (s.X[std::size_t(i)] - mm.point.X_rig_mm).norm();
            if (e < 0.1 && s.cls[std::size_t(i)] == mm.colour_class) {
                ++correct;
                ss += e * e;
            }
        }
        CHECK(r.count <= 10);
    }
    // Random scenes sometimes put two same-coloured markers on one epipolar plane; nearly all must be found.
    CHECK(correct >= int(0.97 * total));
    CHECK(std::sqrt(ss / correct) < 0.02);
}

TEST_CASE("a missing camera gives two-view markers", "[tracking][correspondence]") {
    const auto cams = test::three_camera_rig();
    const Correspondence corr(cams);
    std::mt19937_64 rng(12);
    const Scene s = random_scene(rng, 4);  // one marker per class: unambiguous
    auto views = image(cams, s, rng, 0.05);
    views[1].present = false;
    CorrespondenceResult r;
    corr.solve(views, r);
    REQUIRE(r.count == 4);
    for (int m = 0; m < r.count; ++m) {
        CHECK(r.markers[std::size_t(m)].point.views == 2);
        CHECK(r.markers[std::size_t(m)].image_index[1] == -1);
        const int i = nearest(s, r.markers[std::size_t(m)].point.X_rig_mm);
        CHECK((s.X[std::size_t(i)] - r.markers[std::size_t(m)].point.X_rig_mm).norm() < 0.05);
    }
}

TEST_CASE("an outlier image is rejected and the marker kept from two views", "[tracking][correspondence]") {
    const auto cams = test::three_camera_rig();
    const Correspondence corr(cams);
    std::mt19937_64 rng(13);
    const Scene s = random_scene(rng, 4);
    std::vector<std::array<int, 3>> where;
    auto views = image(cams, s, rng, 0.05, &where);
    // Corrupt marker 0's image in camera 2 by a few pixels (a reflection merged into the blob, say).
    auto& p = views[2].points[std::size_t(where[0][2])];
    p.px += Eigen::Vector2d(3.0, 2.0);
    p.xn = undistort_pixel(cams[2], p.px).xn;
    CorrespondenceResult r;
    corr.solve(views, r);
    REQUIRE(r.count == 4);
    bool found = false;
    for (int m = 0; m < r.count; ++m) {
        const auto& mm = r.markers[std::size_t(m)];
        if (nearest(s, mm.point.X_rig_mm) != 0) continue;
        found = true;
        CHECK(mm.point.views == 2);
        CHECK(mm.image_index[2] == -1);
        CHECK((mm.point.X_rig_mm - s.X[0]).norm() < 0.05);
    }
    CHECK(found);
    CHECK(r.unmatched_images == 1);
}

TEST_CASE("a marker seen by one camera is not invented", "[tracking][correspondence]") {
    const auto cams = test::three_camera_rig();
    const Correspondence corr(cams);
    std::mt19937_64 rng(14);
    const Scene s = random_scene(rng, 1);
    auto views = image(cams, s, rng, 0.05);
    views[0].present = false;
    views[1].count = 0;
    CorrespondenceResult r;
    corr.solve(views, r);
    CHECK(r.count == 0);
    CHECK(r.unmatched_images == 1);
}

TEST_CASE("a marker mostly hidden in one camera is placed from the two that see it whole", "[tracking][correspondence]") {
    // The hidden view's blob is small and its centroid off the centre. Moved along camera 2's ray, it stays on
    // camera 2's epipolar line: the pair (0, 2) has as small an epipolar distance as the clean pair (1, 2) and a
    // placement 1.5 mm off. Surgery seed 23: a forceps marker 80 % hidden in camera 0 was paired with camera 2.
    const auto cams = test::three_camera_rig();
    CorrespondenceOptions opt;
    opt.marker_radius_mm = 0.5;
    const Correspondence corr(cams, opt);
    std::mt19937_64 rng(15);
    auto area_of = [&](int c, const Eigen::Vector3d& X) {
        const CameraGeometry& g = cams[std::size_t(c)];
        const double r = opt.marker_radius_mm / (g.R_cam_rig * X + g.t_cam_rig_mm).z();
        return float(3.141592653589793 * (g.fx * r) * (g.fy * r) * 0.5);
    };
    int cases = 0, placed = 0, hidden_left_out = 0;
    for (int trial = 0; trial < 40; ++trial) {
        const Scene s = random_scene(rng, 4);  // one marker per class: unambiguous
        std::vector<std::array<int, 3>> where;
        auto views = image(cams, s, rng, 0.02, &where);
        for (std::size_t i = 0; i < s.X.size(); ++i)
            for (int c = 0; c < 3; ++c) views[std::size_t(c)].points[std::size_t(where[i][std::size_t(c)])].area_px = area_of(c, s.X[i]);
        // Marker 0 in camera 0: a fifth of its blob left, its centroid where the point 1.5 mm along camera 2's ray projects.
        const CameraGeometry& g2 = cams[2];
        const Eigen::Vector3d centre2 = -(g2.R_cam_rig.transpose() * g2.t_cam_rig_mm);
        const Eigen::Vector3d moved = s.X[0] + 1.5 * (s.X[0] - centre2).normalized();
        ImagePoint& p = views[0].points[std::size_t(where[0][0])];
        REQUIRE(project_point(cams[0], moved, p.px));
        p.xn = undistort_pixel(cams[0], p.px).xn;
        p.area_px = 0.2f * area_of(0, s.X[0]);
        CorrespondenceResult r;
        corr.solve(views, r);
        for (int m = 0; m < r.count; ++m) {
            const auto& mm = r.markers[std::size_t(m)];
            if (mm.colour_class != s.cls[0]) continue;
            ++cases;
            placed += (mm.point.X_rig_mm - s.X[0]).norm() < 0.05;
            // Camera 0's image is either not used or used as an occluded view; the point is from cameras 1 and 2.
            hidden_left_out += (mm.image_index[0] == -1 || (mm.occluded_views & 1u)) && !mm.occluded && mm.point.views == 2;
        }
    }
    INFO("trials with marker 0 found " << cases << ": placed within 0.05 mm " << placed << ", hidden view left out "
                                       << hidden_left_out);
    CHECK(cases == 40);
    CHECK(placed == cases);
    CHECK(hidden_left_out == cases);
}

TEST_CASE("a small blob's area, varying from view to view by its edge pixels, does not make a view occluded",
          "[tracking][correspondence]") {
    // A 4-px instrument marker's blob area varies by ±10 % between fields (its edge pixels), so its three views'
    // area ratios lie up to 25 % apart with nothing hiding it (sweep seeds 44 and 56: markers flagged in two views
    // beside a third 25-35 % larger, their own shafts' bias then left uncorrected, 0.1 mm off). A large blob 22 %
    // smaller than the best view is still judged partly hidden.
    const auto cams = test::three_camera_rig();
    std::mt19937_64 rng(21);
    int small_clean = 0, large_flagged = 0;
    const int trials = 30;
    for (int trial = 0; trial < trials; ++trial) {
        const Scene s = random_scene(rng, 4);  // one marker per class: unambiguous
        std::vector<std::array<int, 3>> where;
        auto views = image(cams, s, rng, 0.02, &where);
        for (const double area0_px : {20.0, 200.0}) {
            // The sphere radius that covers area0_px field pixels in camera 0 at marker 0's depth.
            const CameraGeometry& g0 = cams[0];
            const double z0 = (g0.R_cam_rig * s.X[0] + g0.t_cam_rig_mm).z();
            CorrespondenceOptions opt;
            opt.marker_radius_mm = z0 * std::sqrt(2.0 * area0_px / (3.141592653589793 * g0.fx * g0.fy));
            const Correspondence corr(cams, opt);
            const std::array<double, 3> factor = area0_px < 100.0 ? std::array<double, 3>{1.15, 0.92, 1.0}
                                                                  : std::array<double, 3>{1.0, 0.78, 1.0};
            for (std::size_t i = 0; i < s.X.size(); ++i)
                for (int c = 0; c < 3; ++c) {
                    const CameraGeometry& g = cams[std::size_t(c)];
                    const double r = opt.marker_radius_mm / (g.R_cam_rig * s.X[i] + g.t_cam_rig_mm).z();
                    views[std::size_t(c)].points[std::size_t(where[i][std::size_t(c)])].area_px =
                        float(3.141592653589793 * (g.fx * r) * (g.fy * r) * 0.5 * (i == 0 ? factor[std::size_t(c)] : 1.0));
                }
            CorrespondenceResult r;
            corr.solve(views, r);
            for (int m = 0; m < r.count; ++m) {
                const auto& mm = r.markers[std::size_t(m)];
                if (mm.colour_class != s.cls[0]) continue;
                if (area0_px < 100.0)
                    small_clean += mm.occluded_views == 0 && mm.point.views == 3;
                else
                    large_flagged += (mm.occluded_views & 2u) != 0 && mm.point.views == 2;
            }
        }
    }
    INFO("small blobs with every view used " << small_clean << ", large blobs with camera 1 left out " << large_flagged);
    CHECK(small_clean == trials);
    CHECK(large_flagged == trials);
}
