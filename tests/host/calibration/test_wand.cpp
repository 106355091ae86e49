// Wand calibration against analytic truth: wand views made by projecting the `wand` scenario's markers with a
// known rig (no rendering), the bundle adjustment recovering that rig from a perturbed start, outliers
// down-weighted, and the rig frame from the eye's markers at rest.
#include "eyesim/calibration/wand.hpp"

#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/camera.hpp"
#include "eyesim/rig/geometry.hpp"
#include "eyesim/rig/scenario.hpp"

#include <catch2/catch.hpp>

#include <Eigen/Geometry>

#include <cmath>
#include <random>

namespace {

namespace cal = eyesim::calibration;
namespace rig = eyesim::rig;

constexpr double kPi = 3.14159265358979323846;

/// The default rig with every camera moved by a few mm and turned by about a degree, clocks as the default's.
std::vector<rig::CameraModel> perturbed_rig(uint64_t seed) {
    std::mt19937_64 g(seed);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    auto cams = rig::default_rig();
    for (auto& c : cams) {
        const Eigen::Vector3d centre = c.center_rig_mm() + 3.0 * Eigen::Vector3d(u(g), u(g), u(g));
        const Eigen::Vector3d axis = Eigen::Vector3d(u(g), u(g), u(g)).normalized();
        c.R_cam_rig = c.R_cam_rig * Eigen::AngleAxisd(1.0 * kPi / 180.0, axis).toRotationMatrix();
        c.t_cam_rig_mm = -c.R_cam_rig * centre;
        c.fx *= 1.0 + 0.01 * u(g);
        c.fy = c.fx * 1.04;
    }
    return cams;
}

/// Wand views of `fields` fields per camera: the scenario's markers at each camera's exposure mid-time, projected
/// (frame px), kept when all project inside the image with a 10 px margin.
cal::WandViews project_wand(const std::vector<rig::CameraModel>& cams, uint64_t seed, int64_t fields) {
    const rig::Bodies bodies = rig::load_bodies(rig::default_bodies_path());
    const rig::Scenario sc = rig::Scenario::make("wand", seed, static_cast<double>(fields) * 20000.0, bodies);
    const auto markers = rig::scene_markers(bodies, sc.kinds(), true);
    cal::WandViews v;
    v.views.resize(cams.size());
    v.rejects.assign(cams.size(), {});
    for (size_t c = 0; c < cams.size(); ++c) {
        v.views[c].resize(static_cast<size_t>(fields));
        for (int64_t i = 0; i < fields; ++i) {
            const rig::SceneState st = sc.state_at(cams[c].field_timing(i).exposure_mid_us);
            cal::WandView view;
            for (const auto& m : markers) {
                if (m.body != "wand") continue;
                const auto p = cams[c].project_frame(rig::marker_center_rig(m, st));
                if (!p || p->x() < 10 || p->y() < 10 || p->x() > 710 || p->y() > 566) break;
                view.push_back(*p);
            }
            if (view.size() == 3) v.views[c][static_cast<size_t>(i)] = view;
            ++v.rejects[c][view.size() == 3 ? 0 : 2];
        }
    }
    return v;
}

/// The eye's markers at rest projected into every camera (frame px).
cal::EyeImages project_eye(const std::vector<rig::CameraModel>& cams) {
    const rig::Bodies bodies = rig::load_bodies(rig::default_bodies_path());
    cal::EyeImages e;
    e.px.resize(cams.size());
    e.fields.resize(cams.size());
    for (size_t c = 0; c < cams.size(); ++c)
        for (const auto& m : bodies.eye.markers) {
            const Eigen::Vector3d X = bodies.eye.center_rig_mm + m.position_eye_mm;
            // Seen when the marker faces the camera (its outward normal towards it).
            if ((cams[c].center_rig_mm() - X).dot(m.position_eye_mm) <= 0) continue;
            if (const auto p = cams[c].project_frame(X)) {
                e.px[c].push_back(*p);
                e.fields[c].push_back(100);
            }
        }
    return e;
}

/// Cameras expressed in camera 0's frame (x_cam = R x_cam0 + t).
std::vector<rig::CameraModel> in_cam0(const std::vector<rig::CameraModel>& cams) {
    std::vector<rig::CameraModel> out = cams;
    const Eigen::Matrix3d R0 = cams[0].R_cam_rig;
    const Eigen::Vector3d t0 = cams[0].t_cam_rig_mm;
    for (auto& c : out) {
        const Eigen::Matrix3d R = c.R_cam_rig * R0.transpose();
        c.t_cam_rig_mm = c.t_cam_rig_mm - R * t0;
        c.R_cam_rig = R;
    }
    return out;
}

double rotation_error_deg(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
    return Eigen::AngleAxisd(a * b.transpose()).angle() * 180.0 / kPi;
}

/// The intrinsics of `truth` on cameras whose poses are unknown (identity, origin): all the solver may use.
std::vector<rig::CameraModel> intrinsics_only(const std::vector<rig::CameraModel>& truth) {
    auto cams = truth;
    for (auto& c : cams) {
        c.R_cam_rig.setIdentity();
        c.t_cam_rig_mm.setZero();
        c.field_time_offset_us = 0;
    }
    return cams;
}

}  // namespace

TEST_CASE("wand bundle adjustment recovers a perturbed rig and its clocks from projected views", "[calibration][wand]") {
    const auto truth = perturbed_rig(5);
    const cal::WandViews views = project_wand(truth, 21, 600);
    for (size_t c = 0; c < 3; ++c) REQUIRE(views.accepted(static_cast<int>(c)) > 200);
    cal::WandOptions opt;
    const cal::WandSolve s = cal::solve_wand(views, intrinsics_only(truth), rig::load_bodies(rig::default_bodies_path()).wand, opt);
    REQUIRE(s.converged);
    const auto want = in_cam0(truth);
    for (size_t c = 1; c < 3; ++c) {
        INFO("camera " << c);
        // Noise-free projections: what is left is the cubic interpolation in time (sub-µm at hand speed).
        CHECK((s.cameras[c].center_rig_mm() - want[c].center_rig_mm()).norm() < 1e-3);
        CHECK(rotation_error_deg(s.cameras[c].R_cam_rig, want[c].R_cam_rig) < 1e-4);
        // Exposure mid-time offset against camera 0 (equal shutters: the field start offsets' difference).
        CHECK(std::fabs(s.stats[c].time_offset_us - (truth[c].field_time_offset_us - truth[0].field_time_offset_us)) < 1.0);
        CHECK(std::fabs(s.cameras[c].field_time_offset_us - truth[c].field_time_offset_us) < 1.0);
    }
    for (const auto& st : s.stats) {
        CHECK(st.image_error_px_rms < 1e-3);
        CHECK(st.world_error_mm < 1e-4);
        CHECK(st.outliers == 0);
    }
    REQUIRE(!s.wand_length_error_mm.empty());
    for (double e : s.wand_length_error_mm) CHECK(std::fabs(e) < 1e-3);
}

/// Adds Gaussian centroid noise (σ per axis, frame px) to every view.
void add_noise(cal::WandViews& views, double sigma, uint64_t seed) {
    std::mt19937_64 g(seed);
    std::normal_distribution<double> noise(0.0, sigma);
    for (auto& cam : views.views)
        for (auto& v : cam)
            for (auto& p : v) p += Eigen::Vector2d(noise(g), noise(g));
}

/// Largest camera centre (mm) and rotation (deg) error of a solve against the truth, in camera 0's frame.
std::pair<double, double> worst_error(const cal::WandSolve& s, const std::vector<rig::CameraModel>& truth) {
    const auto want = in_cam0(truth);
    double centre = 0, rot = 0;
    for (size_t c = 1; c < truth.size(); ++c) {
        centre = std::max(centre, (s.cameras[c].center_rig_mm() - want[c].center_rig_mm()).norm());
        rot = std::max(rot, rotation_error_deg(s.cameras[c].R_cam_rig, want[c].R_cam_rig));
    }
    return {centre, rot};
}

TEST_CASE("wand solve: views off the smooth track (ends swapped, a marker pulled) are dropped", "[calibration][wand]") {
    const auto truth = perturbed_rig(8);
    cal::WandViews views = project_wand(truth, 33, 600);
    add_noise(views, 0.03, 4);
    std::mt19937_64 g(5);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::vector<int64_t> corrupted(3, 0);
    for (size_t c = 0; c < 3; ++c)
        for (auto& v : views.views[c]) {
            if (v.empty()) continue;
            // 3 % of the views: one marker's image pulled by 2–5 px (a marker half hidden) or the ends swapped.
            const double r = u(g);
            if (r < 0.015) {
                v[1] += Eigen::Vector2d(2.0 + 3.0 * u(g), -2.0);
                ++corrupted[c];
            } else if (r < 0.03) {
                std::swap(v[0], v[2]);
                ++corrupted[c];
            }
        }
    const cal::WandSolve s = cal::solve_wand(views, intrinsics_only(truth), rig::load_bodies(rig::default_bodies_path()).wand, {});
    REQUIRE(s.converged);
    for (size_t c = 0; c < 3; ++c) {
        INFO("camera " << c);
        REQUIRE(corrupted[c] > 5);
        // Every corrupted view goes (its neighbours are judged again once it is out, so they stay).
        CHECK(s.stats[c].jumps >= corrupted[c]);
        CHECK(s.stats[c].jumps <= corrupted[c] + 2);
        // What is left is the centroid noise, 0.03 frame px per axis: in field px (the solve's unit) 0.03 in x and
        // 0.015 in y, 0.034 in length, less what the fit absorbs (5 of the 6 residuals' degrees of freedom left
        // per two-camera view on average).
        CHECK(s.stats[c].image_error_px_rms > 0.018);
        CHECK(s.stats[c].image_error_px_rms < 0.034);
        CHECK(s.stats[c].image_error_frame_px_rms > s.stats[c].image_error_px_rms);
    }
    const auto [centre_mm, rot_deg] = worst_error(s, truth);
    CHECK(centre_mm < 0.02);
    CHECK(rot_deg < 0.003);
    // 50 µs at the wand's image speed (≈ 0.2 px/ms) is 0.01 px.
    for (size_t c = 1; c < 3; ++c)
        CHECK(std::fabs(s.stats[c].time_offset_us - (truth[c].field_time_offset_us - truth[0].field_time_offset_us)) < 50.0);
}

TEST_CASE("wand solve: biased views are down-weighted by the robust loss", "[calibration][wand]") {
    const auto truth = perturbed_rig(9);
    cal::WandViews views = project_wand(truth, 34, 600);
    add_noise(views, 0.02, 6);
    // 30 % of camera 1's views with its middle marker 0.4 px to the right (partly hidden): too small to leave the
    // smooth track, a systematic pull on the solve.
    std::mt19937_64 g(7);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    int64_t biased = 0;
    for (auto& v : views.views[1])
        if (!v.empty() && u(g) < 0.3) {
            v[1].x() += 0.4;
            ++biased;
        }
    REQUIRE(biased > 20);
    const rig::WandBody wand = rig::load_bodies(rig::default_bodies_path()).wand;
    const cal::WandSolve robust = cal::solve_wand(views, intrinsics_only(truth), wand, {});
    cal::WandOptions plain;  // least squares: no loss, no outlier bound
    plain.huber_sigmas = 1e6;
    plain.outlier_sigmas = 1e6;
    const cal::WandSolve ls = cal::solve_wand(views, intrinsics_only(truth), wand, plain);
    REQUIRE(robust.converged);
    REQUIRE(ls.converged);
    CHECK(robust.stats[1].outliers > 0);
    CHECK(ls.stats[1].outliers == 0);
    const auto [rc, rr] = worst_error(robust, truth);
    const auto [lc, lr] = worst_error(ls, truth);
    INFO("robust " << rc * 1e3 << " um " << rr << " deg; least squares " << lc * 1e3 << " um " << lr << " deg");
    // The pull turns camera 1 (a shifted image point is mostly a rotation): least squares follows it, the robust
    // solve stays at the noise's level.
    CHECK(rr < 0.5 * lr);
    CHECK(rr < 0.003);
    CHECK(rc < lc);
    CHECK(rc < 0.01);
}

TEST_CASE("rig frame from the eye's markers at rest", "[calibration][wand]") {
    const auto truth = perturbed_rig(11);
    const rig::Bodies bodies = rig::load_bodies(rig::default_bodies_path());
    const cal::EyeImages eye = project_eye(truth);
    const auto c0 = in_cam0(truth);
    const cal::RigFrameFit fit = cal::fit_rig_frame(eye, c0, bodies.eye);
    CHECK(fit.markers >= 5);
    CHECK(fit.residual_mm_rms < 1e-6);
    CHECK(fit.residual_px_rms < 1e-6);
    // x_rig = R x_cam0 + t: camera 0's own pose inverted.
    CHECK(rotation_error_deg(fit.R_rig_cam0, truth[0].R_cam_rig.transpose()) < 1e-6);
    CHECK((fit.t_rig_cam0_mm - truth[0].center_rig_mm()).norm() < 1e-6);
    const auto back = cal::to_rig_frame(c0, fit);
    for (size_t c = 0; c < 3; ++c) {
        CHECK((back[c].center_rig_mm() - truth[c].center_rig_mm()).norm() < 1e-6);
        CHECK(rotation_error_deg(back[c].R_cam_rig, truth[c].R_cam_rig) < 1e-6);
    }

    // A second body of yellow blobs (two stray reflections) does not confuse the match.
    cal::EyeImages noisy = eye;
    noisy.px[0].push_back({100.0, 100.0});
    noisy.px[1].push_back({600.0, 500.0});
    const cal::RigFrameFit fit2 = cal::fit_rig_frame(noisy, c0, bodies.eye);
    CHECK(fit2.markers == fit.markers);
    CHECK(rotation_error_deg(fit2.R_rig_cam0, truth[0].R_cam_rig.transpose()) < 1e-6);

    // Too few markers seen by two cameras: an error naming why.
    cal::EyeImages few = eye;
    for (auto& p : few.px) p.resize(std::min<size_t>(p.size(), 1));
    CHECK_THROWS_AS(cal::fit_rig_frame(few, c0, bodies.eye), cal::CalibrationError);
}

TEST_CASE("wand solve: a camera that never sees the wand is an error naming it", "[calibration][wand]") {
    const auto truth = perturbed_rig(5);
    cal::WandViews views = project_wand(truth, 21, 200);
    for (auto& v : views.views[2]) v.clear();
    try {
        (void)cal::solve_wand(views, intrinsics_only(truth), rig::load_bodies(rig::default_bodies_path()).wand, {});
        FAIL("no error");
    } catch (const cal::CalibrationError& e) {
        CHECK(std::string(e.what()).find("camera 2") != std::string::npos);
    }
}
