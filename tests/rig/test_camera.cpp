// Camera model against OpenCV, field/frame mapping, rig.yaml round trip and validation.
#include "eyesim/rig/camera.hpp"
#include "eyesim/rig/error.hpp"

#include <catch2/catch.hpp>
#include <opencv2/calib3d.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <regex>
#include <sstream>

using namespace eyesim::rig;
namespace fs = std::filesystem;

namespace {

std::string temp_dir(const std::string& name) {
    const fs::path p = fs::temp_directory_path() / ("eyesim_test_rig_" + name + "_" + std::to_string(::getpid()));
    fs::remove_all(p);
    fs::create_directories(p);
    return p.string();
}

std::string slurp(const std::string& path) {
    std::ifstream in(path);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

void spit(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

}  // namespace

TEST_CASE("projection equals cv::projectPoints to 1e-9 px with distortion", "[rig][camera]") {
    std::mt19937_64 rng(42);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (const CameraModel& cam : default_rig()) {
        std::vector<cv::Point3d> pts;
        for (int i = 0; i < 500; ++i) {
            // Points in the working volume around the eye, in the rig frame.
            pts.emplace_back(25 * u(rng), 25 * u(rng), 8 + 25 * u(rng));
        }
        std::vector<cv::Point2d> ocv;
        cv::projectPoints(pts, cam.rvec(), cam.tvec(), cam.camera_matrix(), cam.dist_coeffs(), ocv);
        int compared = 0;
        for (size_t i = 0; i < pts.size(); ++i) {
            const auto p = cam.project_frame({pts[i].x, pts[i].y, pts[i].z});
            if (!p) continue;
            ++compared;
            INFO(cam.name << " point " << i);
            CHECK(std::abs(p->x() - ocv[i].x) < 1e-9);
            CHECK(std::abs(p->y() - ocv[i].y) < 1e-9);
        }
        CHECK(compared > 450);
    }
}

TEST_CASE("distortion Jacobian matches finite differences; undistortion inverts distortion", "[rig][camera]") {
    const CameraModel cam = default_rig()[1];
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u(-0.7, 0.7);
    for (int i = 0; i < 200; ++i) {
        const Eigen::Vector2d q(u(rng), u(rng) * 0.8);
        if (q.squaredNorm() > cam.max_r2) continue;
        const Eigen::Matrix2d J = cam.distort_jacobian(q);
        const double h = 1e-6;
        for (int k = 0; k < 2; ++k) {
            Eigen::Vector2d dq = Eigen::Vector2d::Zero();
            dq[k] = h;
            const Eigen::Vector2d fd = (cam.distort_normalized(q + dq) - cam.distort_normalized(q - dq)) / (2 * h);
            CHECK((J.col(k) - fd).norm() < 1e-5);
        }
        const auto back = cam.undistort_to_normalized(cam.distort_normalized(q));
        REQUIRE(back.has_value());
        CHECK((*back - q).norm() < 1e-12);
    }
    // Against OpenCV's undistortPoints with many iterations at the image corners.
    std::vector<cv::Point2d> px = {{0, 0}, {719, 0}, {0, 575}, {719, 575}, {360, 288}}, und;
    cv::undistortPoints(px, und, cam.camera_matrix(), cam.dist_coeffs(), cv::noArray(), cv::noArray(),
                        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 200, 1e-15));
    for (size_t i = 0; i < px.size(); ++i) {
        const auto q = cam.undistort_to_normalized({px[i].x, px[i].y});
        REQUIRE(q.has_value());
        CHECK(std::abs(q->x() - und[i].x) < 1e-7);
        CHECK(std::abs(q->y() - und[i].y) < 1e-7);
    }
}

TEST_CASE("field and frame pixel coordinates map exactly", "[rig][camera]") {
    const CameraModel cam = default_rig()[2];
    CHECK(field_to_frame_px({10.25, 3.5}, 0) == Eigen::Vector2d(10.25, 7.0));
    CHECK(field_to_frame_px({10.25, 3.5}, 1) == Eigen::Vector2d(10.25, 8.0));
    CHECK(frame_to_field_px({5.0, 9.0}, 1) == Eigen::Vector2d(5.0, 4.0));
    CHECK(frame_to_field_px({5.0, 9.0}, 0) == Eigen::Vector2d(5.0, 4.5));
    const Eigen::Vector3d x(3, -4, 12);
    const auto f = cam.project_frame(x);
    REQUIRE(f);
    for (int p = 0; p < 2; ++p) {
        const auto fld = cam.project_field(x, p);
        REQUIRE(fld);
        CHECK(fld->x() == f->x());
        CHECK(2 * fld->y() + p == Approx(f->y()).margin(1e-12));
    }
    // Behind the camera: not projectable.
    CHECK_FALSE(cam.project_frame(cam.center_rig_mm() - 10 * cam.R_cam_rig.row(2).transpose()).has_value());
}

TEST_CASE("default rig sees the eye and the instrument volume", "[rig][camera]") {
    for (const CameraModel& cam : default_rig()) {
        const auto c = cam.project_frame(Eigen::Vector3d::Zero());
        REQUIRE(c);
        CHECK(c->x() > 100);
        CHECK(c->x() < 620);
        CHECK(c->y() > 100);
        CHECK(c->y() < 476);
        // Cameras below the eye, looking up.
        CHECK(cam.center_rig_mm().z() < -20);
        CHECK(cam.R_cam_rig.row(2).z() > 0.3);
        // Eye marker of 0.6 mm radius at the eye surface: 6..10 px diameter.
        const double dist = (cam.center_rig_mm()).norm() - 12.6;
        const double diam = 2 * 0.6 / dist * cam.fx;
        CHECK(diam > 6);
        CHECK(diam < 12);
    }
}

TEST_CASE("rig.yaml round trip is exact and OpenCV-readable", "[rig][camera][yaml]") {
    const std::string dir = temp_dir("yaml");
    const std::string path = dir + "/rig.yaml";
    auto cams = default_rig();
    cams[1].first_field_parity = 1;
    cams[2].exposure_us = 1234.5;
    save_rig_yaml(path, cams);
    const auto back = load_rig_yaml(path);
    REQUIRE(back.size() == 3);
    for (size_t i = 0; i < 3; ++i) {
        CHECK(back[i].fx == cams[i].fx);
        CHECK(back[i].cy == cams[i].cy);
        CHECK(back[i].dist == cams[i].dist);
        CHECK(back[i].R_cam_rig == cams[i].R_cam_rig);
        CHECK(back[i].t_cam_rig_mm == cams[i].t_cam_rig_mm);
        CHECK(back[i].first_field_parity == cams[i].first_field_parity);
        CHECK(back[i].field_time_offset_us == cams[i].field_time_offset_us);
        CHECK(back[i].exposure_us == cams[i].exposure_us);
    }
    // Plain OpenCV reads it.
    cv::FileStorage fs(path, cv::FileStorage::READ);
    cv::Mat K, D;
    fs["cam0"]["K"] >> K;
    fs["cam0"]["dist"] >> D;
    CHECK(K.at<double>(0, 0) == cams[0].fx);
    CHECK(D.total() == 5);
    fs::remove_all(dir);
}

TEST_CASE("malformed rig.yaml gives one-line errors naming file and key", "[rig][camera][yaml]") {
    const std::string dir = temp_dir("yaml_bad");
    const std::string good = dir + "/good.yaml";
    save_rig_yaml(good, default_rig());
    const std::string text = slurp(good);
    auto expect_error = [&](const std::string& yaml, const std::string& needle) {
        const std::string p = dir + "/bad.yaml";
        spit(p, yaml);
        try {
            load_rig_yaml(p);
            FAIL("no error for " << needle);
        } catch (const RigError& e) {
            const std::string what = e.what();
            INFO(what);
            CHECK(what.find(p) != std::string::npos);
            CHECK(what.find(needle) != std::string::npos);
            CHECK(what.find('\n') == std::string::npos);
        }
    };
    SECTION("NaN in K") {
        // Replace fx of cam1 with .nan.
        const size_t k = text.find("cam1:");
        const size_t data = text.find("data: [", text.find("K:", k)) + 7;
        const size_t comma = text.find(',', data);
        expect_error(text.substr(0, data) + " .Nan" + text.substr(comma), "cam1.K");
    }
    SECTION("Inf in t") {
        const size_t k = text.find("cam2:");
        const size_t data = text.find("data: [", text.find(" t: !!opencv-matrix", k)) + 7;
        const size_t comma = text.find(',', data);
        expect_error(text.substr(0, data) + " .Inf" + text.substr(comma), "cam2.t");
    }
    SECTION("missing key") {
        const size_t k = text.find("dist:", text.find("cam0:"));
        const size_t end = text.find("R:", k);
        expect_error(text.substr(0, k) + text.substr(end), "cam0.dist: missing");
    }
    SECTION("wrong matrix size") {
        std::string t = text;
        const size_t k = t.find("dist:", t.find("cam0:"));
        const size_t rows = t.find("cols: 5", k);
        t.replace(rows, 7, "cols: 4");
        const size_t data = t.find("data: [", k) + 7;
        const size_t comma = t.find(',', data);
        t.erase(data, comma - data + 1);
        expect_error(t, "cam0.dist: expected 1x5");
    }
    SECTION("missing camera") { expect_error(std::regex_replace(text, std::regex("camera_count: 3"), "camera_count: 4"), "cam3"); }
    SECTION("wrong image size") {
        expect_error(std::regex_replace(text, std::regex("image_width: 720"), "image_width: 640"), "720x576");
    }
    SECTION("not a rotation") {
        const size_t k = text.find("R:", text.find("cam0:"));
        const size_t data = text.find("data: [", k) + 7;
        const size_t comma = text.find(',', data);
        expect_error(text.substr(0, data) + " 2." + text.substr(comma), "cam0.R: not a rotation");
    }
    SECTION("missing file") { CHECK_THROWS_WITH(load_rig_yaml(dir + "/none.yaml"), Catch::Contains("none.yaml: file: missing")); }
    SECTION("garbage") { expect_error("this is : : not [ yaml", "rig"); }
    fs::remove_all(dir);
}
