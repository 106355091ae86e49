#include "eyesim/tracking/rigid_fit.hpp"
#include "eyesim/tracking/tracker.hpp"

#include "synthetic_stream.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <limits>
#include <span>
#include <vector>

using namespace eyesim::tracking;
using eyesim::tracking::test::SyntheticScene;

namespace {

struct Errors {
    double ss_marker = 0, ss_tip = 0, ss_eye_deg = 0, ss_tip_eye = 0;
    int n_marker = 0, n_tip = 0, n_eye = 0, frames = 0, two_view = 0;
    double rms_marker_um() const { return 1e3 * std::sqrt(ss_marker / std::max(n_marker, 1)); }
    double rms_tip_um() const { return 1e3 * std::sqrt(ss_tip / std::max(n_tip, 1)); }
    double rms_tip_eye_um() const { return 1e3 * std::sqrt(ss_tip_eye / std::max(n_tip, 1)); }
    double rms_eye_deg() const { return std::sqrt(ss_eye_deg / std::max(n_eye, 1)); }
};

/// Runs the stream through a tracker and scores each frame against the scene truth at the frame time.
template <typename Drop>
Errors run(const SyntheticScene& scene, int fields, double sigma_px, SyncMode mode, Drop drop,
           double insertion_tol_mm = 0.1, std::uint64_t seed = 1) {
    std::mt19937_64 rng(seed);
    TrackerConfig cfg = scene.tracker_config();
    cfg.sync.mode = mode;
    cfg.centroid_sigma_px = std::max(sigma_px, 0.02);
    Tracker tracker(cfg);
    tracker.set_clock_offset_us(1e6);  // device clock = recording clock + 1 s
    Errors e;
    TrackingFrame f;
    auto consume = [&]() {
        while (tracker.pop(f, 0.0)) {
            ++e.frames;
            if (f.flags & kFrameTwoView) ++e.two_view;
            const auto truth = scene.at(f.timing.sample_host_us);
            // Positions and poses are finite whatever happened.
            REQUIRE(f.eye.rotation_eye_to_rig.coeffs().allFinite());
            for (int m = 0; m < f.markers.count; ++m) {
                const auto& mk = f.markers.markers[std::size_t(m)];
                REQUIRE(mk.point.X_rig_mm.allFinite());
                double best = 1e9;
                for (std::size_t k = 0; k < truth.markers_rig_mm.size(); ++k)
                    if (truth.marker_class[k] == mk.colour_class)
                        best = std::min(best, (truth.markers_rig_mm[k] - mk.point.X_rig_mm).norm());
                e.ss_marker += best * best;
                ++e.n_marker;
            }
            if (f.eye.measured()) {
                e.ss_eye_deg += std::pow(rotation_angle_deg(f.eye.rotation_eye_to_rig.toRotationMatrix(),
                                                            truth.q_eye_to_rig.toRotationMatrix()), 2);
                ++e.n_eye;
            }
            for (int b = 0; b < f.instrument_count; ++b) {
                const auto& p = f.instruments[std::size_t(b)];
                REQUIRE(p.tip_rig_mm.allFinite());
                REQUIRE(p.tip_eye_mm.allFinite());
                if (!p.measured()) continue;
                e.ss_tip += (p.tip_rig_mm - truth.tip_rig_mm[std::size_t(b)]).squaredNorm();
                e.ss_tip_eye += (p.tip_eye_mm - truth.tip_eye_mm[std::size_t(b)]).squaredNorm();
                ++e.n_tip;
                CHECK(p.axis_rig.dot(truth.axis_rig[std::size_t(b)]) > 0.995);
                CHECK(std::abs(p.insertion_depth_mm - truth.insertion_mm[std::size_t(b)]) < insertion_tol_mm);
            }
        }
    };
    for (const auto& msg : scene.stream(fields, sigma_px, rng, drop)) {
        tracker.push(msg, double(msg.field_end_us) - 1e6 + 100.0);
        consume();
    }
    tracker.finish();
    consume();
    return e;
}

}  // namespace

TEST_CASE("noise-free synthetic stream: interpolated frames track to micrometres", "[tracking][tracker]") {
    const SyntheticScene scene(1.0);
    const Errors e = run(scene, 60, 0.0, SyncMode::Interpolate, [](int, int) { return false; });
    INFO("marker " << e.rms_marker_um() << " um, tip " << e.rms_tip_um() << " um, eye " << e.rms_eye_deg() << " deg");
    CHECK(e.frames == 60);
    CHECK(e.n_tip >= 2 * 58);
    CHECK(e.n_eye >= 58);
    // Only q16 quantisation and linear interpolation of slow motion remain.
    CHECK(e.rms_marker_um() < 3.0);
    CHECK(e.rms_tip_um() < 5.0);
    CHECK(e.rms_eye_deg() < 0.01);
}

TEST_CASE("noisy synthetic stream meets the accuracy targets", "[tracking][tracker]") {
    const SyntheticScene scene(1.0);
    const Errors e = run(scene, 150, 0.03, SyncMode::Interpolate, [](int, int) { return false; });
    INFO("marker " << e.rms_marker_um() << " um, tip " << e.rms_tip_um() << " um (eye frame "
                   << e.rms_tip_eye_um() << "), eye " << e.rms_eye_deg() << " deg");
    CHECK(e.rms_marker_um() < 25.0);
    CHECK(e.rms_tip_um() < 50.0);
    CHECK(e.rms_eye_deg() < 0.05);
}

TEST_CASE("unsynchronised cameras: interpolation beats using fields as they are", "[tracking][tracker]") {
    const SyntheticScene scene(6.0);  // fast motion makes the 6.7/13.3 ms camera skew visible
    const auto all = [](int, int) { return false; };
    const Errors interp = run(scene, 80, 0.0, SyncMode::Interpolate, all, 0.3);
    const Errors near = run(scene, 80, 0.0, SyncMode::Nearest, all, 0.3);
    INFO("interpolate " << interp.rms_marker_um() << " um over " << interp.n_marker << ", nearest "
                        << near.rms_marker_um() << " um over " << near.n_marker);
    // Nearest with the default 1 ms skew finds no partner field at all: nothing is triangulated.
    CHECK(near.n_marker == 0);
    CHECK(interp.n_marker > 0);
    CHECK(interp.rms_marker_um() < 25.0);
    const Errors extra = run(scene, 80, 0.0, SyncMode::Extrapolate, all, 1.0);
    INFO("extrapolate " << extra.rms_marker_um() << " um");
    CHECK(extra.rms_marker_um() > interp.rms_marker_um());
    CHECK(extra.rms_marker_um() < 200.0);
}

TEST_CASE("a missing camera and missing fields give two-view frames, not gaps", "[tracking][tracker]") {
    const SyntheticScene scene(1.0);
    // Camera 2 is off from field 20 on; camera 1 loses every 7th field; the reference loses field 30.
    const Errors e = run(scene, 60, 0.03, SyncMode::Interpolate, [](int c, int i) {
        return (c == 2 && i >= 20) || (c == 1 && i % 7 == 3) || (c == 0 && i == 30);
    });
    INFO("marker " << e.rms_marker_um() << " um, tip " << e.rms_tip_um() << " um, frames " << e.frames);
    CHECK(e.frames == 60);  // the lost reference field still gives its frame
    CHECK(e.two_view >= 40);
    CHECK(e.n_tip > 60);
    CHECK(e.rms_marker_um() < 60.0);
}

TEST_CASE("non-finite images are refused and poses stay finite", "[tracking][tracker]") {
    const SyntheticScene scene(1.0);
    Tracker tracker(scene.tracker_config());
    std::array<CameraField, 3> fields{};
    std::array<bool, 3> present{true, true, true};
    for (int c = 0; c < 3; ++c) {
        fields[std::size_t(c)].count = 2;
        fields[std::size_t(c)].images[0].colour_class = 1;
        fields[std::size_t(c)].images[0].frame_px = Eigen::Vector2d(std::numeric_limits<double>::quiet_NaN(), 3.0);
        fields[std::size_t(c)].images[1].colour_class = 2;
        fields[std::size_t(c)].images[1].frame_px = Eigen::Vector2d(300.0, std::numeric_limits<double>::infinity());
    }
    TrackingFrame f;
    tracker.track_images(fields, present, f);
    CHECK((f.flags & kFrameNonFinite) != 0);
    CHECK(f.markers.count == 0);
    CHECK_FALSE(f.eye.measured());
    CHECK(f.eye.rotation_eye_to_rig.coeffs().allFinite());
    for (int b = 0; b < f.instrument_count; ++b) {
        CHECK_FALSE(f.instruments[std::size_t(b)].measured());
        CHECK(f.instruments[std::size_t(b)].tip_eye_mm.allFinite());
    }
    // One camera only: flagged, nothing triangulated.
    std::array<bool, 3> one{true, false, false};
    tracker.track_images(fields, one, f);
    CHECK((f.flags & kFrameTooFewCameras) != 0);
}

TEST_CASE("synchronisation modes by the command lines' names; any other name is an error", "[tracking][tracker]") {
    CHECK(sync_mode_from_name("interpolate") == SyncMode::Interpolate);
    CHECK(sync_mode_from_name("extrapolate") == SyncMode::Extrapolate);
    CHECK(sync_mode_from_name("nearest") == SyncMode::Nearest);
    CHECK(sync_mode_from_name("async") == SyncMode::Async);
    CHECK_THROWS_AS(sync_mode_from_name("later"), std::invalid_argument);
    CHECK_THROWS_AS(sync_mode_from_name(""), std::invalid_argument);
}

TEST_CASE("an instrument one camera alone sees is placed for the hints from that view and its trocar, and stays held",
          "[tracking][tracker]") {
    const SyntheticScene scene(1.0);
    TrackerConfig cfg = scene.tracker_config();
    Tracker tracker(cfg);
    const int ncam = int(cfg.cameras.size());
    const int n_eye = int(scene.bodies().eye.markers.size());
    // The frame's images: every marker's exact projection, the forceps' (instrument 0, markers n_eye .. n_eye + 2)
    // in camera 0 only where `forceps_in_one`.
    auto frame = [&](const eyesim::tracking::test::SceneTruth& truth, bool forceps_in_one, TrackingFrame& out) {
        std::vector<CameraField> fields(static_cast<std::size_t>(ncam));
        for (int c = 0; c < ncam; ++c) {
            CameraField& f = fields[std::size_t(c)];
            f.camera = c;
            for (std::size_t k = 0; k < truth.markers_rig_mm.size(); ++k) {
                const bool forceps = int(k) >= n_eye && int(k) < n_eye + 3;
                Eigen::Vector2d px;
                if ((forceps && forceps_in_one && c != 0) ||
                    !project_point(cfg.cameras[std::size_t(c)], truth.markers_rig_mm[k], px))
                    continue;
                FieldImage& im = f.images[std::size_t(f.count++)];
                im.colour_class = std::uint8_t(truth.marker_class[k]);
                im.frame_px = px;
            }
        }
        const bool present[kMaxCameras] = {true, true, true, true};
        tracker.track_images(fields, std::span<const bool>(present, std::size_t(ncam)), out);
    };
    TrackingFrame out;
    frame(scene.at(0.0), false, out);
    REQUIRE(out.instruments[0].measured());
    CHECK(out.one_view_mask == 0);
    // 20 ms later only camera 0 sees the forceps: no 3D markers, so held, but placed from camera 0 for the hints.
    eyesim::tracking::test::SceneTruth truth = scene.at(20000.0);
    frame(truth, true, out);
    CHECK_FALSE(out.instruments[0].measured());
    CHECK(out.instruments[1].measured());
    REQUIRE((out.one_view_mask & 1u) != 0);
    CHECK((out.one_view_mask & 2u) == 0);  // the light pipe is measured: not placed from one view
    const InstrumentPose& one = out.one_view[0];
    CHECK((one.flags & kPoseSingleView) != 0);
    CHECK((one.tip_rig_mm - truth.tip_rig_mm[0]).norm() < 1e-3);  // exact images: q16-free, a Newton tolerance
    CHECK(one.axis_rig.dot(truth.axis_rig[0]) > 1.0 - 1e-9);
    // Withdrawn 25 mm along its line, still seen by camera 0 alone: followed from the last one-view pose.
    for (std::size_t k = std::size_t(n_eye); k < std::size_t(n_eye + 3); ++k)
        truth.markers_rig_mm[k] += 25.0 * truth.axis_rig[0];
    const Eigen::Vector3d tip = truth.tip_rig_mm[0] + 25.0 * truth.axis_rig[0];
    frame(truth, true, out);
    CHECK_FALSE(out.instruments[0].measured());
    REQUIRE((out.one_view_mask & 1u) != 0);
    CHECK((out.one_view[0].tip_rig_mm - tip).norm() < 1e-3);
    CHECK(out.one_view[0].insertion_depth_mm == Approx(truth.insertion_mm[0] - 25.0).margin(1e-3));
    // Off the trocar's line across camera 0's view (an instrument moved freely once out of the eye): nothing placed.
    const Eigen::Vector3d ray = tip - cfg.cameras[0].centre_rig_mm();
    const Eigen::Vector3d aside = 2.5 * truth.axis_rig[0].cross(ray).normalized();
    for (std::size_t k = std::size_t(n_eye); k < std::size_t(n_eye + 3); ++k) truth.markers_rig_mm[k] += aside;
    frame(truth, true, out);
    CHECK((out.one_view_mask & 1u) == 0);
}
