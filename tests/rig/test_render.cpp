// Renderer truth against an independent brute-force supersampled computation; timing, parity, determinism.
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/renderer.hpp"
#include "eyesim/rig/scenario.hpp"
#include "eyesim/rig/synth.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <stdexcept>

using namespace eyesim::rig;

namespace {

/// Brute force: N×N point samples per frame-pixel aperture, each ray found by full Newton undistortion,
/// Tref time samples; returns the centroid of coverage × shading in FIELD pixels, and the coverage sum.
struct Ref {
    Eigen::Vector2d centroid;
    double area;
};
Ref brute_force(const CameraModel& cam, int parity, const std::function<Eigen::Vector3d(double)>& center_at,
                double t0, double t1, int tref, double rho, int n) {
    double si = 0, sx = 0, sy = 0, sa = 0;
    for (int k = 0; k < tref; ++k) {
        const double t = t0 + (k + 0.5) / tref * (t1 - t0);
        const Eigen::Vector3d C = cam.to_camera(center_at(t));
        const Eigen::Vector2d pc = *cam.project_frame(center_at(t));
        const double rpx = 2.0 * rho / C.z() * std::max(cam.fx, cam.fy) + 3.0;
        for (int y = static_cast<int>(std::floor((pc.y() - rpx - parity) / 2));
             y <= static_cast<int>(std::ceil((pc.y() + rpx - parity) / 2)); ++y) {
            const double v = 2.0 * y + parity;
            for (int x = static_cast<int>(std::floor(pc.x() - rpx)); x <= static_cast<int>(std::ceil(pc.x() + rpx)); ++x) {
                double acc = 0, cov = 0;
                for (int sy_ = 0; sy_ < n; ++sy_)
                    for (int sx_ = 0; sx_ < n; ++sx_) {
                        const Eigen::Vector2d p(x - 0.5 + (sx_ + 0.5) / n, v - 0.5 + (sy_ + 0.5) / n);
                        const auto q = cam.undistort_to_normalized(p);
                        if (!q) throw std::runtime_error("undistortion failed in the reference");
                        const Eigen::Vector3d d = Eigen::Vector3d(q->x(), q->y(), 1.0).normalized();
                        const double tca = d.dot(C);
                        const double disc = rho * rho - (C.squaredNorm() - tca * tca);
                        if (disc <= 0) continue;
                        const double th = tca - std::sqrt(disc);
                        const Eigen::Vector3d nrm = (th * d - C) / rho;
                        acc += kShadeAmbient + kShadeDiffuse * (-nrm.dot(d));
                        cov += 1;
                    }
                acc /= n * n;
                cov /= n * n;
                si += acc;
                sx += acc * x;
                sy += acc * y;
                sa += cov;
            }
        }
    }
    return {{sx / si, sy / si}, sa / tref};
}

CameraModel test_camera() { return default_rig()[0]; }

}  // namespace

TEST_CASE("rendered intensity centroid equals brute-force supersampling (static markers)", "[rig][render]") {
    const CameraModel cam = test_camera();
    RenderOptions opt;
    opt.noise_sigma = 0;
    CameraRenderer r(cam, 0, Eigen::Vector3d::Zero(), 0.0, opt);
    // Marker centres chosen in frame pixels (centre, off-axis, near a corner: strong distortion), at 70..95 mm.
    const Eigen::Vector3d cc = cam.center_rig_mm();
    const Eigen::Matrix3d Rt = cam.R_cam_rig.transpose();
    struct Case { double u, v, z, rho; int64_t field; };
    const Case cases[] = {{360.3, 290.7, 80, 0.6, 0}, {131.37, 97.2, 90, 0.6, 1}, {640.8, 510.45, 70, 0.6, 2},
                          {500.1, 150.9, 95, 0.45, 3}, {80.6, 470.2, 75, 0.75, 4}};
    for (const Case& c : cases) {
        const auto q = cam.undistort_to_normalized({c.u, c.v});
        REQUIRE(q.has_value());
        const Eigen::Vector3d center = cc + Rt * (Eigen::Vector3d(q->x(), q->y(), 1.0) * c.z);
        const GeometryAt geo = [&](double, SceneGeometry& g) {
            g.eye_radius_mm = 0;
            g.shafts.clear();
            g.markers.assign(1, {center, c.rho, 1});
        };
        std::vector<MarkerCameraTruth> truth;
        r.render_field(geo, c.field, nullptr, truth);
        REQUIRE(truth.size() == 1);
        REQUIRE(truth[0].visible);
        const int parity = cam.field_parity(c.field);
        const Ref ref = brute_force(cam, parity, [&](double) { return center; }, 0, 1, 1, c.rho, 96);
        const Eigen::Vector2d ref_field(ref.centroid.x(), ref.centroid.y());
        INFO("case u=" << c.u << " v=" << c.v << " render " << truth[0].centroid_px.transpose() << " ref "
                       << ref_field.transpose() << " projected " << truth[0].projected_px.transpose());
        CHECK(std::abs(truth[0].centroid_px.x() - ref_field.x()) < 1e-3);
        CHECK(std::abs(truth[0].centroid_px.y() - ref_field.y()) < 0.5e-3);  // field y: half the frame scale
        CHECK(truth[0].area_px == Approx(ref.area).epsilon(2e-3));
        // Projected centre and intensity centroid differ (perspective, distortion, field sampling) but are close.
        CHECK((truth[0].centroid_px - truth[0].projected_px).norm() < 0.5);
    }
}

TEST_CASE("motion-blurred centroid equals brute-force time and space supersampling", "[rig][render]") {
    const CameraModel cam = test_camera();
    RenderOptions opt;
    opt.noise_sigma = 0;
    CameraRenderer r(cam, 0, Eigen::Vector3d::Zero(), 0.0, opt);
    const auto q = cam.undistort_to_normalized({250.2, 200.6});
    const Eigen::Vector3d c0 = cam.center_rig_mm() + cam.R_cam_rig.transpose() * (Eigen::Vector3d(q->x(), q->y(), 1) * 85);
    const Eigen::Vector3d vel_mm_per_us(0.00021, -0.00009, 0.00005);  // ≈ 235 mm/s: several px of blur
    const int64_t field = 7;
    const FieldTiming ft = cam.field_timing(field);
    auto center_at = [&](double t) -> Eigen::Vector3d { return c0 + vel_mm_per_us * (t - ft.exposure_mid_us); };
    const GeometryAt geo = [&](double t, SceneGeometry& g) {
        g.eye_radius_mm = 0;
        g.shafts.clear();
        g.markers.assign(1, {center_at(t), 0.6, 2});
    };
    std::vector<MarkerCameraTruth> truth;
    r.render_field(geo, field, nullptr, truth);
    const double blur_px = (*cam.project_frame(center_at(ft.exposure_end_us)) - *cam.project_frame(center_at(ft.exposure_start_us))).norm();
    REQUIRE(blur_px > 3.0);
    const Ref ref = brute_force(cam, ft.parity, center_at, ft.exposure_start_us, ft.exposure_end_us, 48, 0.6, 40);
    INFO("blur " << blur_px << " px; render " << truth[0].centroid_px.transpose() << " ref " << ref.centroid.transpose());
    CHECK(std::abs(truth[0].centroid_px.x() - ref.centroid.x()) < 1e-3);
    CHECK(std::abs(truth[0].centroid_px.y() - ref.centroid.y()) < 0.5e-3);
}

TEST_CASE("field parity and timing follow the PAL model", "[rig][timing]") {
    CameraModel cam = test_camera();
    cam.field_time_offset_us = 1234.5;
    cam.exposure_us = 3000;
    for (int64_t i = 0; i < 6; ++i) {
        const FieldTiming t = cam.field_timing(i);
        CHECK(t.parity == static_cast<int>(i % 2));
        CHECK(t.start_us == Approx(1234.5 + 20000.0 * i));
        CHECK(t.exposure_mid_us == Approx(t.start_us - 1500.0));
        CHECK(t.exposure_end_us - t.exposure_start_us == Approx(3000.0));
        // Last active line ends 22 blanking lines + 288 lines (+ half a line for the bottom field) after sync.
        CHECK(t.end_us == Approx(t.start_us + (22 + 287) * 64.0 + 10.5 + 52.0 + (i % 2 ? 32.0 : 0.0)));
        CHECK(t.line_start_us(1) - t.line_start_us(0) == Approx(64.0));
    }
    cam.first_field_parity = 1;
    CHECK(cam.field_parity(0) == 1);
    CHECK(cam.field_parity(1) == 0);
    // Default rig: unsynchronised cameras.
    const auto rig = default_rig();
    CHECK(rig[0].field_time_offset_us != rig[1].field_time_offset_us);
    CHECK(rig[1].field_time_offset_us != rig[2].field_time_offset_us);
}

TEST_CASE("a marker in a bottom field is rendered on odd frame rows", "[rig][render][timing]") {
    // The same static marker rendered in a top and a bottom field: the centroid in frame rows agrees (both sample
    // the same continuous image), the field rows differ by the parity offset.
    const CameraModel cam = test_camera();
    RenderOptions opt;
    opt.noise_sigma = 0;
    CameraRenderer r(cam, 0, Eigen::Vector3d::Zero(), 0.0, opt);
    const auto q = cam.undistort_to_normalized({300.0, 301.0});
    const Eigen::Vector3d c = cam.center_rig_mm() + cam.R_cam_rig.transpose() * (Eigen::Vector3d(q->x(), q->y(), 1) * 80);
    const GeometryAt geo = [&](double, SceneGeometry& g) {
        g.eye_radius_mm = 0;
        g.shafts.clear();
        g.markers.assign(1, {c, 0.6, 3});
    };
    std::vector<MarkerCameraTruth> t0, t1;
    r.render_field(geo, 0, nullptr, t0);
    r.render_field(geo, 1, nullptr, t1);
    CHECK(t0[0].projected_px.y() == Approx(301.0 / 2).margin(1e-9));
    CHECK(t1[0].projected_px.y() == Approx(300.0 / 2).margin(1e-9));
    // Frame-row centroids from the two fields agree to the sampling difference (rows 2y vs 2y+1).
    CHECK(std::abs(2 * t0[0].centroid_px.y() - (2 * t1[0].centroid_px.y() + 1)) < 0.2);
}

TEST_CASE("UYVY output: BT.601 studio swing, ranges, chroma of a marker", "[rig][render]") {
    const CameraModel cam = test_camera();
    RenderOptions opt;
    opt.noise_sigma = 0;
    CameraRenderer r(cam, 0, Eigen::Vector3d::Zero(), 0.0, opt);
    const auto q = cam.undistort_to_normalized({360.0, 288.0});
    const Eigen::Vector3d c = cam.center_rig_mm() + cam.R_cam_rig.transpose() * (Eigen::Vector3d(q->x(), q->y(), 1) * 40);
    const GeometryAt geo = [&](double, SceneGeometry& g) {
        g.eye_radius_mm = 0;
        g.shafts.clear();
        g.markers.assign(1, {c, 1.0, 1});  // big red marker, centre pixel fully facing the camera
    };
    std::vector<uint8_t> buf(kFieldBytes);
    std::vector<MarkerCameraTruth> t;
    r.render_field(geo, 0, buf.data(), t);
    size_t out_of_range = 0;
    for (size_t i = 0; i < buf.size(); i += 2) {
        out_of_range += buf[i] < 16 || buf[i] > 240;          // Cb / Cr
        out_of_range += buf[i + 1] < 16 || buf[i + 1] > 235;  // Y
    }
    CHECK(out_of_range == 0);
    // Background pixel (14,14,18): Y = 16 + 219/255 * 14.456 = 28.4 -> 28.
    CHECK(buf[1] == 28);
    // Marker centre: red (220,40,40): Y = 16 + 219/255*(0.299*220+0.587*40+0.114*40) = 96.6 -> 97,
    // Cr = 128 + 224/255*(220-89.86)/1.402 = 209.5; the centre pair is flat, so within 1 of that.
    const int x = static_cast<int>(std::lround(t[0].projected_px.x())) & ~1;
    const int y = static_cast<int>(std::lround(t[0].projected_px.y()));
    const uint8_t* px = &buf[(static_cast<size_t>(y) * kFieldWidth + x) * 2];
    CHECK(std::abs(px[1] - 97) <= 1);
    CHECK(std::abs(px[2] - 209) <= 2);
    CHECK(px[0] < 128);  // Cb below neutral for red
}

TEST_CASE("rendering is deterministic from the seed", "[rig][render][determinism]") {
    const Bodies bodies = load_bodies(default_bodies_path());
    auto render_all = [&](uint64_t seed, const std::string& scen) {
        RenderOptions opt;
        opt.seed = seed;
        RigSynth s(default_rig(), bodies, Scenario::make(scen, seed, 200000, bodies), opt);
        std::vector<std::vector<uint8_t>> bufs(3, std::vector<uint8_t>(kFieldBytes));
        std::vector<uint8_t> all;
        FieldTruth t;
        for (int64_t i = 0; i < 3; ++i) {
            s.render(i, {bufs[0].data(), bufs[1].data(), bufs[2].data()}, t);
            for (auto& b : bufs) all.insert(all.end(), b.begin(), b.end());
        }
        return all;
    };
    const auto a = render_all(5, "fast");
    const auto b = render_all(5, "fast");
    const auto c = render_all(6, "fast");
    CHECK(a == b);
    CHECK(a != c);
}

TEST_CASE("scenarios are smooth, deterministic and keep instruments through their trocars", "[rig][scenario]") {
    const Bodies bodies = load_bodies(default_bodies_path());
    for (const auto& name : scenario_names()) {
        const Scenario s1 = Scenario::make(name, 11, 2e6, bodies);
        const Scenario s2 = Scenario::make(name, 11, 2e6, bodies);
        for (double t = 0; t < 2e6; t += 97000) {
            const SceneState a = s1.state_at(t), b = s2.state_at(t);
            CHECK(a.q_eye_to_rig.coeffs() == b.q_eye_to_rig.coeffs());
            REQUIRE(a.instruments.size() == 2);
            for (size_t k = 0; k < 2; ++k) {
                const InstrumentPose& p = a.instruments[k];
                const Eigen::Vector3d troc = bodies.eye.trocars[p.trocar].position_eye_mm;
                // The trocar lies on the shaft line: tip + insertion * (-axis) ... = trocar.
                CHECK((p.tip_eye_mm + p.insertion_mm * p.axis_eye - troc).norm() < 1e-9);
                if (p.insertion_mm > 0) CHECK(p.tip_eye_mm.norm() < bodies.eye.radius_mm);
            }
            // Eye rotation stays within the mechanical range.
            CHECK(Eigen::AngleAxisd(a.q_eye_to_rig).angle() < 0.7);
        }
    }
    CHECK_THROWS_AS(Scenario::make("nope", 1, 1e6, bodies), RigError);
}

TEST_CASE("scenario character: static is still, fast blurs, sweep covers the volume, occlusion hides markers",
          "[rig][scenario]") {
    const Bodies bodies = load_bodies(default_bodies_path());
    const auto cams = default_rig();
    auto max_blur_px = [&](const Scenario& s, double t_end_us) {
        const auto markers = scene_markers(bodies, s.kinds());
        double blur = 0;
        for (double t = 0; t < t_end_us; t += 20000) {
            const SceneState a = s.state_at(t - 2000), b = s.state_at(t + 2000);  // a 4 ms exposure
            for (const auto& m : markers)
                for (const auto& c : cams) {
                    const auto pa = c.project_frame(marker_center_rig(m, a)), pb = c.project_frame(marker_center_rig(m, b));
                    if (pa && pb) blur = std::max(blur, (*pa - *pb).norm());
                }
        }
        return blur;
    };
    CHECK(max_blur_px(Scenario::make("static", 3, 1e6, bodies), 1e6) == 0.0);
    CHECK(max_blur_px(Scenario::make("fast", 3, 1e6, bodies), 1e6) > 3.0);
    CHECK(max_blur_px(Scenario::make("surgery", 3, 1e6, bodies), 1e6) < 3.0);

    // Sweep: the tissue instrument tip visits a large part of the eye over 30 s.
    const Scenario sweep = Scenario::make("sweep", 3, 30e6, bodies);
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e9), hi = -lo;
    for (double t = 0; t < 30e6; t += 100000) {
        const SceneState s = sweep.state_at(t);
        const Eigen::Vector3d tip = s.eye_to_rig(s.instruments[0].tip_eye_mm);
        lo = lo.cwiseMin(tip);
        hi = hi.cwiseMax(tip);
    }
    CHECK((hi - lo).minCoeff() > 6.0);

    // Occlusion: over one second, marker views go from visible to hidden (pulled out, behind the eye).
    RenderOptions opt;
    RigSynth synth(cams, bodies, Scenario::make("occlusion", 3, 1e6, bodies), opt);
    FieldTruth t;
    int hidden = 0, visible = 0, partial = 0;
    for (int64_t i = 0; i < 50; i += 5) {
        synth.render(i, {nullptr, nullptr, nullptr}, t);
        for (const auto& m : t.markers)
            for (const auto& mc : m.cams) {
                visible += mc.visible;
                hidden += !mc.visible;
                partial += mc.visible && mc.occluded_fraction > 0.05;
            }
    }
    CHECK(hidden > 20);
    CHECK(visible > 100);
    CHECK(partial > 10);
}

TEST_CASE("long runs of every scenario keep the truth well formed", "[rig][stress]") {
    const Bodies bodies = load_bodies(default_bodies_path());
    for (const auto& name : scenario_names()) {
        RigSynth synth(default_rig(), bodies, Scenario::make(name, 17, 20e6, bodies), RenderOptions{});
        FieldTruth t;
        int64_t visible = 0;
        for (int64_t i = 0; i < 1000; i += 3) {
            synth.render(i, {nullptr, nullptr, nullptr}, t);
            REQUIRE(t.q_eye_to_rig.coeffs().allFinite());
            for (const auto& in : t.instruments) {
                REQUIRE(in.tip_rig_mm.allFinite());
                REQUIRE(std::abs(in.axis_rig.norm() - 1.0) < 1e-9);
                REQUIRE(in.jaw_opening >= 0.0);
                REQUIRE(in.jaw_opening <= 1.0);
            }
            for (const auto& m : t.markers)
                for (const auto& mc : m.cams) {
                    REQUIRE(mc.area_px >= 0.0);
                    REQUIRE(mc.occluded_fraction >= -1e-12);
                    REQUIRE(mc.occluded_fraction <= 1.0 + 1e-12);
                    if (!mc.visible) continue;
                    ++visible;
                    REQUIRE(mc.centroid_px.allFinite());
                    REQUIRE(mc.centroid_px.x() >= -0.5);
                    REQUIRE(mc.centroid_px.x() <= kFieldWidth - 0.5);
                    REQUIRE(mc.centroid_px.y() >= -0.5);
                    REQUIRE(mc.centroid_px.y() <= kFieldHeight - 0.5);
                    // A marker of 6-11 px diameter covers at most ~50 field pixels, blur aside.
                    REQUIRE(mc.area_px < 80.0);
                }
        }
        INFO(name);
        CHECK(visible > 1000);
    }
}

TEST_CASE("the rendered image carries the truth: background-subtracted luma centroid matches", "[rig][render]") {
    const CameraModel cam = test_camera();
    RenderOptions opt;
    opt.noise_sigma = 0;
    CameraRenderer r(cam, 0, Eigen::Vector3d::Zero(), 0.0, opt);
    const auto luma = [](const float* p) { return 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2]; };
    const double bg = 0.299 * kBackgroundRgb[0] + 0.587 * kBackgroundRgb[1] + 0.114 * kBackgroundRgb[2];
    for (const Eigen::Vector2d& px : {Eigen::Vector2d(102.3, 77.8), Eigen::Vector2d(420.6, 300.1)}) {
        const auto q = cam.undistort_to_normalized(px);
        const Eigen::Vector3d c = cam.center_rig_mm() + cam.R_cam_rig.transpose() * (Eigen::Vector3d(q->x(), q->y(), 1) * 85);
        const GeometryAt geo = [&](double, SceneGeometry& g) {
            g.eye_radius_mm = 0;
            g.shafts.clear();
            g.markers.assign(1, {c, 0.7, 2});
        };
        std::vector<MarkerCameraTruth> t;
        r.render_field(geo, 2, nullptr, t);
        const std::vector<float>& rgb = r.last_rgb();
        double s = 0, sx = 0, sy = 0;
        for (int y = 0; y < kFieldHeight; ++y)
            for (int x = 0; x < kFieldWidth; ++x) {
                const double w = luma(&rgb[(static_cast<size_t>(y) * kFieldWidth + x) * 3]) - bg;
                if (std::abs(w) < 1e-9) continue;
                s += w;
                sx += w * x;
                sy += w * y;
            }
        INFO("image " << sx / s << ", " << sy / s << " truth " << t[0].centroid_px.transpose());
        // The image weights coverage x (shade x marker luma - background luma), the truth coverage x shade only.
        CHECK(std::abs(sx / s - t[0].centroid_px.x()) < 0.005);
        CHECK(std::abs(sy / s - t[0].centroid_px.y()) < 0.005);
    }
}

TEST_CASE("a marker cut by the image border reports the hidden part", "[rig][render]") {
    const CameraModel cam = test_camera();
    RenderOptions opt;
    opt.noise_sigma = 0;
    CameraRenderer r(cam, 0, Eigen::Vector3d::Zero(), 0.0, opt);
    // Centre on the left border's outer edge (x = -0.5): half the marker lies outside the image.
    const auto q = cam.undistort_to_normalized({-0.5, 300.0});
    const Eigen::Vector3d c = cam.center_rig_mm() + cam.R_cam_rig.transpose() * (Eigen::Vector3d(q->x(), q->y(), 1) * 80);
    const GeometryAt geo = [&](double, SceneGeometry& g) {
        g.eye_radius_mm = 0;
        g.shafts.clear();
        g.markers.assign(1, {c, 0.7, 1});
    };
    std::vector<MarkerCameraTruth> t;
    r.render_field(geo, 0, nullptr, t);
    REQUIRE(t[0].visible);
    CHECK(t[0].occluded_fraction == Approx(0.5).margin(0.03));
    CHECK(t[0].centroid_px.x() > 0.5);  // the centroid of the visible half lies inside the image
    // Wholly outside: not visible.
    const auto q2 = cam.undistort_to_normalized({-40.0, 300.0});
    const Eigen::Vector3d c2 = cam.center_rig_mm() + cam.R_cam_rig.transpose() * (Eigen::Vector3d(q2->x(), q2->y(), 1) * 80);
    const GeometryAt geo2 = [&](double, SceneGeometry& g) {
        g.eye_radius_mm = 0;
        g.shafts.clear();
        g.markers.assign(1, {c2, 0.7, 1});
    };
    r.render_field(geo2, 0, nullptr, t);
    CHECK_FALSE(t[0].visible);
}
