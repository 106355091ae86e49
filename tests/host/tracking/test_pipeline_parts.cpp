#include "eyesim/tracking/correspondence.hpp"
#include "eyesim/tracking/distortion.hpp"
#include "eyesim/tracking/field_sync.hpp"
#include "eyesim/tracking/pose.hpp"
#include "eyesim/tracking/pose_io.hpp"
#include "eyesim/tracking/validation.hpp"

#include "test_support.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <cmath>
#include <random>
#include <span>
#include <utility>
#include <vector>

using namespace eyesim::tracking;
namespace proto = eyesim::protocol;

namespace {

proto::FieldMarkers part(std::uint32_t field, std::uint16_t index, bool more, int markers, std::uint8_t cls = 1) {
    proto::FieldMarkers m;
    m.camera_id = 1;
    m.field_parity = 1;
    m.field_counter = field;
    m.part_index = index;
    m.flags = more ? proto::kFieldFlagMoreFollows : 0;
    m.field_end_us = 100000 + 20000ull * field;
    for (int i = 0; i < markers; ++i) {
        proto::Marker& k = m.markers[m.marker_count++];
        k.colour_class = cls;
        k.x_q16 = std::uint32_t((100 + 10 * i) * 65536);
        k.y_q16 = std::uint32_t(50 * 65536 + 32768);  // field row 50.5
        k.area_px = 20;
    }
    return m;
}

}  // namespace

TEST_CASE("field assembler joins parts, maps field rows to frame rows, flags lost parts", "[tracking][sync]") {
    FieldAssembler fa;
    CameraTiming t;
    CHECK(fa.push(part(7, 0, true, 14), 1.0, t) == 0);
    REQUIRE(fa.push(part(7, 1, false, 3), 2.0, t) == 1);
    const CameraField& f = fa.completed(0);
    CHECK(f.count == 17);
    CHECK_FALSE(f.incomplete);
    CHECK(f.received_host_us == 2.0);
    CHECK(f.images[0].frame_px.y() == Approx(2.0 * 50.5 + 1.0));  // bottom field: frame row 2y + 1
    CHECK(f.sample_device_us == Approx(100000.0 + 140000.0 - t.end_to_sample_us[1]));
    // Field 8 loses its last part: the first part of field 9 completes it, flagged.
    CHECK(fa.push(part(8, 0, true, 2), 3.0, t) == 0);
    REQUIRE(fa.push(part(9, 0, false, 1), 4.0, t) == 2);
    CHECK(fa.completed(0).field_counter == 8);
    CHECK(fa.completed(0).incomplete);
    CHECK(fa.completed(1).field_counter == 9);
    CHECK_FALSE(fa.completed(1).incomplete);
    // A marker with an undefined colour class is refused and counted.
    REQUIRE(fa.push(part(10, 0, false, 2, 0), 5.0, t) == 1);
    CHECK(fa.completed(0).count == 0);
    CHECK(fa.rejected_images() == 2);
}

TEST_CASE("error summary percentiles and RMS", "[tracking][validation]") {
    std::vector<double> v{4.0, 1.0, 3.0, 2.0};
    const ErrorSummary s = summarise(v);
    CHECK(s.count == 4);
    CHECK(s.rms == Approx(std::sqrt(7.5)));
    CHECK(s.p50 == 2.0);
    CHECK(s.p95 == 4.0);
    CHECK(s.max == 4.0);
    std::vector<double> empty;
    CHECK(summarise(empty).count == 0);
}

TEST_CASE("a partly hidden view is left out by the blob-area test", "[tracking][correspondence]") {
    const auto cams = test::three_camera_rig();
    CorrespondenceOptions opt;
    opt.marker_radius_mm = 0.6;
    const Correspondence corr(cams, opt);
    const Eigen::Vector3d X(1.0, -2.0, 4.0);
    std::array<CameraObservations, 3> views;
    for (int c = 0; c < 3; ++c) {
        auto& v = views[std::size_t(c)];
        v.present = true;
        v.count = 1;
        ImagePoint& p = v.points[0];
        REQUIRE(project_point(cams[std::size_t(c)], X, p.px));
        const double z = (cams[std::size_t(c)].R_cam_rig * X + cams[std::size_t(c)].t_cam_rig_mm).z();
        const double r = 0.6 / z;
        p.area_px = float(3.141592653589793 * cams[std::size_t(c)].fx * r * cams[std::size_t(c)].fy * r * 0.5);
        p.colour_class = 4;
        if (c == 2) {  // half hidden: area halved, centroid pushed away by 0.4 px
            p.area_px *= 0.5f;
            p.px += Eigen::Vector2d(0.4, 0.0);
        }
        p.xn = undistort_pixel(cams[std::size_t(c)], p.px).xn;
    }
    CorrespondenceResult r;
    corr.solve(views, r);
    REQUIRE(r.count == 1);
    CHECK(r.markers[0].occluded_views == 0x4);
    CHECK_FALSE(r.markers[0].occluded);
    CHECK(r.markers[0].point.views == 2);
    CHECK((r.markers[0].point.X_rig_mm - X).norm() < 1e-6);
}

TEST_CASE("a tracked instrument that jumps is held, not reported", "[tracking][pose]") {
    BodySet bodies;
    bodies.eye.marker_count = 0;
    bodies.instrument_count = 1;
    InstrumentModel& im = bodies.instruments[0];
    im.name = "pick";
    im.marker_count = 3;
    const double s[3] = {26.0, 31.0, 38.0};
    for (int k = 0; k < 3; ++k) {
        im.markers[std::size_t(k)].colour_class = std::uint8_t(1 + k);
        im.markers[std::size_t(k)].pos_body_mm = Eigen::Vector3d(0, 0, s[k]);
    }
    auto frame_at = [&](const Eigen::Vector3d& tip) {
        CorrespondenceResult found;
        for (int k = 0; k < 3; ++k) {
            MatchedMarker& m = found.markers[std::size_t(found.count++)];
            m.colour_class = std::uint8_t(1 + k);
            m.point.X_rig_mm = tip + Eigen::Vector3d(0, 0, s[k]);
            m.point.cov_mm2 = Eigen::Matrix3d::Identity() * 1e-4;
            m.point.views = 3;
        }
        return found;
    };
    PoseOptions opt;
    EyePose eye0, eye;
    std::array<InstrumentPose, 1> prev{}, cur{};
    MarkerAssignment asg;
    fit_poses(bodies, frame_at({1, 2, 3}), opt, eye0, prev, eye, cur, asg);
    REQUIRE(cur[0].measured());
    CHECK((cur[0].tip_rig_mm - Eigen::Vector3d(1, 2, 3)).norm() < 1e-9);
    CHECK(cur[0].axis_rig.z() == Approx(1.0));
    prev = cur;
    fit_poses(bodies, frame_at({1, 2, 13}), opt, eye0, prev, eye, cur, asg);  // 10 mm in one frame
    CHECK_FALSE(cur[0].measured());
    CHECK((cur[0].flags & kPoseJumpRejected) != 0);
    CHECK((cur[0].tip_rig_mm - Eigen::Vector3d(1, 2, 3)).norm() < 1e-9);  // held
    // Not measured last frame → re-acquired with all three markers.
    prev = cur;
    fit_poses(bodies, frame_at({1, 2, 13}), opt, eye0, prev, eye, cur, asg);
    CHECK(cur[0].measured());
    // The poses.jsonl line is valid JSON with finite values.
    TrackingFrame f;
    f.instrument_count = 1;
    f.instruments[0] = cur[0];
    const auto j = nlohmann::json::parse(frame_json_line(f, bodies));
    CHECK(j["instruments"][0]["name"] == "pick");
    CHECK(j["instruments"][0]["tip_rig_mm"][2].get<double>() == Approx(13.0));
}

namespace {

/// An eye with three markers at rest and one instrument (markers 26, 31, 38 mm behind the tip, classes 1–3) with
/// a trocar at (0, 0, 11.5) in the eye frame; `frame(tip, n)` gives the eye's markers and the instrument's
/// proximal n markers for a shaft from `tip` through the trocar.
struct DeepShaft {
    BodySet bodies;
    const Eigen::Vector3d eye_m[3] = {{12, 0, 0}, {0, 12, 0}, {-8.5, -8.5, 0}};
    const double s[3] = {26.0, 31.0, 38.0};
    Eigen::Vector3d trocar{0, 0, 11.5};

    DeepShaft() {
        bodies.eye.marker_count = 3;
        for (int k = 0; k < 3; ++k) {
            bodies.eye.markers[std::size_t(k)].colour_class = 4;
            bodies.eye.markers[std::size_t(k)].pos_body_mm = eye_m[k];
        }
        bodies.instrument_count = 1;
        InstrumentModel& im = bodies.instruments[0];
        im.name = "forceps";
        im.marker_count = 3;
        im.has_trocar = true;
        im.trocar_eye_mm = trocar;
        for (int k = 0; k < 3; ++k) {
            im.markers[std::size_t(k)].colour_class = std::uint8_t(1 + k);
            im.markers[std::size_t(k)].pos_body_mm = Eigen::Vector3d(0, 0, s[k]);
        }
    }
    CorrespondenceResult frame(const Eigen::Vector3d& tip, int markers) const {
        const Eigen::Vector3d axis = (trocar - tip).normalized();
        CorrespondenceResult found;
        auto add = [&](std::uint8_t cls, const Eigen::Vector3d& x) {
            MatchedMarker& m = found.markers[std::size_t(found.count++)];
            m.colour_class = cls;
            m.point.X_rig_mm = x;
            m.point.cov_mm2 = Eigen::Matrix3d::Identity() * 1e-4;
            m.point.views = 2;
        };
        for (const auto& e : eye_m) add(4, e);
        for (int k = 3 - markers; k < 3; ++k) add(std::uint8_t(1 + k), tip + s[k] * axis);
        return found;
    }
};

}  // namespace

TEST_CASE("an instrument deep in the eye is acquired from two markers when its shaft passes through its trocar",
          "[tracking][pose]") {
    // The distal marker is hidden behind the eye: two markers alone could be any body's, but two markers and the
    // trocar are three points on one line.
    DeepShaft d;
    InstrumentModel& im = d.bodies.instruments[0];
    const Eigen::Vector3d tip(0, 0, -10);  // near the back wall, on the line through the trocar
    const CorrespondenceResult found = d.frame(tip, 2);
    PoseOptions opt;
    EyePose eye0, eye;
    MarkerAssignment asg;
    std::array<InstrumentPose, 1> prev{}, cur{};

    fit_poses(d.bodies, found, opt, eye0, prev, eye, cur, asg);
    REQUIRE(eye.measured());
    REQUIRE(cur[0].measured());
    CHECK((cur[0].tip_rig_mm - tip).norm() < 1e-3);

    im.trocar_eye_mm = Eigen::Vector3d(3, 0, 11.5);  // 3 mm off the line: the two markers are not confirmed
    fit_poses(d.bodies, found, opt, eye0, prev, eye, cur, asg);
    CHECK_FALSE(cur[0].measured());

    im.has_trocar = false;  // no trocar: three markers are needed to acquire
    fit_poses(d.bodies, found, opt, eye0, prev, eye, cur, asg);
    CHECK_FALSE(cur[0].measured());
}

TEST_CASE("an instrument measured last frame is kept from one marker and its trocar, never acquired from one",
          "[tracking][pose]") {
    DeepShaft d;
    PoseOptions opt;
    EyePose eye0, eye;
    MarkerAssignment asg;
    std::array<InstrumentPose, 1> none{}, prev{}, cur{};
    const Eigen::Vector3d tip0(1.0, 0.5, -10.0), tip1(1.3, 0.4, -10.1);  // the shaft tilted, deep in the eye
    fit_poses(d.bodies, d.frame(tip0, 2), opt, eye0, none, eye, prev, asg);
    REQUIRE(prev[0].measured());
    // Next frame only the proximal marker: kept, with the tip on the line marker–trocar.
    fit_poses(d.bodies, d.frame(tip1, 1), opt, eye0, prev, eye, cur, asg);
    REQUIRE(cur[0].measured());
    CHECK((cur[0].flags & kPoseSingleMarker) != 0);
    CHECK((cur[0].tip_rig_mm - tip1).norm() < 1e-6);
    // Not measured before: one marker does not acquire it.
    fit_poses(d.bodies, d.frame(tip1, 1), opt, eye0, none, eye, cur, asg);
    CHECK_FALSE(cur[0].measured());
    // A marker far from where the last pose puts it is not taken.
    fit_poses(d.bodies, d.frame(Eigen::Vector3d(4.0, -3.0, -8.0), 1), opt, eye0, prev, eye, cur, asg);
    CHECK_FALSE(cur[0].measured());
}

TEST_CASE("a marker flagged partly hidden carries little weight in its instrument's fit", "[tracking][pose]") {
    // The distal marker's point is the centroid of its visible part (the eye hides most of it in one view): 0.4 mm
    // off its centre across the shaft. Flagged (MatchedMarker::occluded), it is weighted by occluded_sigma_mm, and
    // the two clean markers and the trocar carry the pose; at full weight it tilts the shaft.
    DeepShaft d;
    const Eigen::Vector3d tip(0.5, -0.3, -8.0);
    CorrespondenceResult found = d.frame(tip, 3);
    MatchedMarker& distal = found.markers[3];  // after the eye's three: class 1, 26 mm behind the tip
    REQUIRE(distal.colour_class == 1);
    const Eigen::Vector3d axis = (d.trocar - tip).normalized();
    distal.point.X_rig_mm += 0.4 * axis.cross(Eigen::Vector3d::UnitX()).normalized();
    distal.occluded = true;
    EyePose eye0, eye;
    MarkerAssignment asg;
    std::array<InstrumentPose, 1> prev{}, cur{};

    PoseOptions opt;
    fit_poses(d.bodies, found, opt, eye0, prev, eye, cur, asg);
    REQUIRE(cur[0].measured());
    CHECK(cur[0].markers_used == 3);
    CHECK(asg.body[3] == 1);  // still assigned to the instrument
    const double weighted_um = (cur[0].tip_rig_mm - tip).norm() * 1e3;
    CHECK(weighted_um < 20.0);

    opt.occluded_sigma_mm = 0.0;  // as a clean marker
    fit_poses(d.bodies, found, opt, eye0, prev, eye, cur, asg);
    REQUIRE(cur[0].measured());
    const double full_um = (cur[0].tip_rig_mm - tip).norm() * 1e3;
    INFO("tip error: " << weighted_um << " um weighted, " << full_um << " um at full weight");
    CHECK(full_um > 100.0);
}

namespace {

/// Interpolated x of camera 1's marker at each frame of camera 0 (fields 20 ms apart, camera 1 half a period later):
/// Camera `cam`'s field `k`, exposed at `t_us` and ending `end_after_us` later, with one image at (x, 300) px.
CameraField one_image_field(int cam, std::uint32_t k, double t_us, double x, double end_after_us) {
    CameraField f;
    f.camera = cam;
    f.field_counter = k;
    f.parity = int(k & 1u);
    f.sample_device_us = t_us;
    f.field_end_device_us = t_us + end_after_us;
    f.count = 1;
    f.images[0].colour_class = 2;
    f.images[0].frame_px = Eigen::Vector2d(x, 300.0);
    f.images[0].area_px = 30.0f;
    return f;
}

/// x(t) = 100 + 200·t + ½·accel·(t − 0.12 s)² px plus a bias of ±`parity_bias_px` that alternates with the field.
std::vector<std::pair<double, double>> interpolated_x(double accel_px_s2, double parity_bias_px, bool curvature) {
    SyncOptions opt;
    opt.curvature = curvature;
    FrameSync sync(2, opt);
    auto field = [](int cam, std::uint32_t k, double t_us, double x) {
        return one_image_field(cam, k, t_us, x, 5000.0);
    };
    auto truth_x = [&](double t_us) {
        const double t = t_us * 1e-6;  // within the pairing gate: ≤ 25 px a field
        return 100.0 + 200.0 * t + 0.5 * accel_px_s2 * (t - 0.12) * (t - 0.12);
    };
    std::vector<std::pair<double, double>> out;  // (truth, interpolated) per frame
    double T = 0, end = 0, recv = 0;
    std::uint32_t ref = 0;
    std::array<AlignedCamera, kMaxCameras> cams;
    std::array<CameraField, kMaxCameras> images;
    for (std::uint32_t k = 0; k < 12; ++k) {
        const double t0 = 20000.0 * k, t1 = t0 + 10000.0;
        sync.add(field(0, k, t0, 50.0));
        sync.add(field(1, k, t1, truth_x(t1) + ((k & 1u) ? parity_bias_px : -parity_bias_px)));
        while (sync.pop(T, ref, cams, images, end, recv))
            if (cams[1].state == CameraSyncState::Interpolated && images[1].count == 1)
                out.push_back({truth_x(T), images[1].images[0].frame_px.x()});
    }
    return out;
}

}  // namespace

TEST_CASE("interpolation bends with the image's acceleration and keeps a parity bias out of it", "[tracking][sync]") {
    // 5,000 px/s²: a straight line between fields 20 ms apart is 0.25 px off at their midpoint (c·h²/4).
    const auto bent = interpolated_x(5000.0, 0.1, true);
    const auto line = interpolated_x(5000.0, 0.1, false);
    REQUIRE(bent.size() == line.size());
    REQUIRE(bent.size() >= 8);
    int with_history = 0;
    for (std::size_t i = 0; i < bent.size(); ++i) {
        INFO("frame " << i << ": truth " << bent[i].first << ", bent " << bent[i].second << ", line " << line[i].second);
        CHECK(std::abs(line[i].second - line[i].first) == Approx(0.25).margin(1e-6));
        // The first frames lack the two fields before the pair: the line stands.
        if (std::abs(bent[i].second - line[i].second) < 1e-9) continue;
        ++with_history;
        CHECK(std::abs(bent[i].second - bent[i].first) < 1e-3);
    }
    CHECK(with_history >= int(bent.size()) - 3);
    // Uniform motion with the alternating bias: the acceleration estimate is zero, the line is kept exactly.
    const auto still_bent = interpolated_x(0.0, 0.1, true);
    const auto still_line = interpolated_x(0.0, 0.1, false);
    REQUIRE(still_bent.size() == still_line.size());
    for (std::size_t i = 0; i < still_bent.size(); ++i) {
        CHECK(still_bent[i].second == Approx(still_line[i].second).margin(1e-9));
        CHECK(still_bent[i].second == Approx(still_bent[i].first).margin(1e-9));  // the bias cancels at the midpoint
    }
}

TEST_CASE("genlocked cameras: extrapolate and nearest wait for the fields exposed with the reference field only",
          "[tracking][sync]") {
    // A genlocked rig's three fields share their exposure and end; the reference camera's arrives first. Frames
    // built from it alone had the other cameras extrapolated a whole field (extrapolate) or missing (nearest):
    // `eyesim validate --sync nearest` on a `synth --synchronised` recording matched no marker at all.
    auto field = [](int cam, std::uint32_t k, double t_us) {
        return one_image_field(cam, k, t_us, 100.0 + 10.0 * cam + 1e-5 * t_us, 21000.0);
    };
    double T = 0, end = 0, recv = 0;
    std::uint32_t ref = 0;
    std::array<AlignedCamera, kMaxCameras> cams;
    std::array<CameraField, kMaxCameras> images;
    for (SyncMode mode : {SyncMode::Extrapolate, SyncMode::Nearest}) {
        SyncOptions opt;
        opt.mode = mode;
        INFO("mode " << int(mode));
        SECTION("genlocked: the frame waits for the two fields exposed with it, and uses them as they are") {
            FrameSync sync(3, opt);
            int frames = 0;
            for (std::uint32_t k = 0; k < 8; ++k) {
                const double t = 20000.0 * k;
                sync.add(field(0, k, t));
                if (k > 0) CHECK_FALSE(sync.pop(T, ref, cams, images, end, recv));  // the first: no period known
                sync.add(field(1, k, t));
                if (k > 0) CHECK_FALSE(sync.pop(T, ref, cams, images, end, recv));
                sync.add(field(2, k, t));
                while (sync.pop(T, ref, cams, images, end, recv)) {
                    if (T < 1.0) continue;
                    ++frames;
                    CHECK(T == t);
                    for (int c = 0; c < 3; ++c) {
                        CHECK(cams[std::size_t(c)].state == CameraSyncState::Direct);
                        CHECK(cams[std::size_t(c)].dt_us == 0.0);
                        REQUIRE(images[std::size_t(c)].count == 1);
                        CHECK(images[std::size_t(c)].images[0].frame_px.x() == field(c, k, t).images[0].frame_px.x());
                    }
                }
            }
            CHECK(frames == 7);
        }
        SECTION("a genlocked field lost: the frame goes out once a later field ends half a period past it") {
            FrameSync sync(3, opt);
            for (std::uint32_t k = 0; k < 3; ++k)
                for (int c = 0; c < 3; ++c) sync.add(field(c, k, 20000.0 * k));
            while (sync.pop(T, ref, cams, images, end, recv)) {}
            sync.add(field(0, 3, 60000.0));
            sync.add(field(1, 3, 60000.0));  // camera 2's field 3 never comes
            CHECK_FALSE(sync.pop(T, ref, cams, images, end, recv));
            sync.add(field(0, 4, 80000.0));
            REQUIRE(sync.pop(T, ref, cams, images, end, recv));
            CHECK(T == 60000.0);
            CHECK(cams[0].state == CameraSyncState::Direct);
            CHECK(cams[1].state == CameraSyncState::Direct);
            CHECK(cams[2].state != CameraSyncState::Direct);
            // Camera 2 back: its last two fields 40 ms apart, its period still taken as one field.
            sync.add(field(1, 4, 80000.0));
            sync.add(field(2, 4, 80000.0));
            while (sync.pop(T, ref, cams, images, end, recv)) {}
            sync.add(field(0, 5, 100000.0));
            sync.add(field(1, 5, 100000.0));
            CHECK_FALSE(sync.pop(T, ref, cams, images, end, recv));
            sync.add(field(2, 5, 100000.0));
            REQUIRE(sync.pop(T, ref, cams, images, end, recv));
            CHECK(T == 100000.0);
            CHECK(cams[2].state == CameraSyncState::Direct);
        }
        SECTION("unsynchronised: nothing waits for a later field, nor for one lost") {
            FrameSync sync(3, opt);
            for (std::uint32_t k = 0; k < 8; ++k) {
                const double t = 20000.0 * k;
                if (k != 4) sync.add(field(1, k, t - 13000.0));  // camera 1's field 4 lost
                sync.add(field(2, k, t - 6500.0));
                sync.add(field(0, k, t));
                bool got = false;
                while (sync.pop(T, ref, cams, images, end, recv)) got = T == t;
                CHECK(got);
            }
        }
    }
}

TEST_CASE("one camera's images and the trocar place an instrument's shaft, inside the eye or withdrawn",
          "[tracking][pose]") {
    // Truth: a shaft through the trocar (DeepShaft's), the markers projected exactly by one camera of the test rig.
    DeepShaft d;
    const InstrumentModel& im = d.bodies.instruments[0];
    const CameraGeometry cam = eyesim::tracking::test::three_camera_rig()[0];
    auto images = [&](const Eigen::Vector3d& tip, const Eigen::Vector3d& axis, std::array<Eigen::Vector2d, 3>& xn) {
        for (int k = 0; k < 3; ++k) {
            const Eigen::Vector3d c = cam.R_cam_rig * (tip + d.s[k] * axis) + cam.t_cam_rig_mm;
            xn[std::size_t(k)] = c.head<2>() / c.z();
        }
    };
    const std::array<int, 3> which{0, 1, 2};
    InstrumentPose start;
    start.tip_rig_mm = Eigen::Vector3d(0.5, -0.3, -6.0);  // the last pose: 3–40 mm and a few degrees away
    start.axis_rig = (d.trocar - start.tip_rig_mm).normalized();
    for (const double depth_mm : {9.0, 2.0, -30.0}) {  // inside the eye, just past the trocar, withdrawn
        CAPTURE(depth_mm);
        const Eigen::Vector3d axis = Eigen::Vector3d(0.12, -0.08, 1.0).normalized();
        const Eigen::Vector3d tip = d.trocar - depth_mm * axis;
        std::array<Eigen::Vector2d, 3> xn;
        images(tip, axis, xn);
        InstrumentPose pose;
        double rms_px = -1.0;
        REQUIRE(fit_instrument_one_view(cam, im, d.trocar, xn, which, start, pose, rms_px));
        CHECK(rms_px < 1e-6);
        CHECK((pose.tip_rig_mm - tip).norm() < 1e-6);
        CHECK(pose.axis_rig.dot(axis) > 1.0 - 1e-12);
        CHECK(pose.flags == (kPoseNoRoll | kPoseSingleView));
        // Noise of 0.05 px moves the shaft's line little across the line of sight; the reprojection stays at the
        // noise's level.
        std::mt19937_64 rng(7);
        std::normal_distribution<double> n(0.0, 0.05 / cam.mean_focal_px());
        for (auto& x : xn) x += Eigen::Vector2d(n(rng), n(rng));
        REQUIRE(fit_instrument_one_view(cam, im, d.trocar, xn, which, start, pose, rms_px));
        CHECK(rms_px < 0.1);
        CHECK(pose.axis_rig.dot(axis) > std::cos(0.5 * 3.14159265358979 / 180.0));
    }
    // Two markers, or a shaft along the line of sight (every marker on the trocar's image), place nothing.
    std::array<Eigen::Vector2d, 3> xn;
    const Eigen::Vector3d ray = (d.trocar - cam.centre_rig_mm()).normalized();
    images(d.trocar + 5.0 * ray, -ray, xn);
    InstrumentPose pose;
    double rms_px = 0.0;
    InstrumentPose along = start;
    along.axis_rig = -ray;
    along.tip_rig_mm = d.trocar + 5.0 * ray;
    CHECK_FALSE(fit_instrument_one_view(cam, im, d.trocar, xn, which, along, pose, rms_px));
    images(d.trocar - 9.0 * Eigen::Vector3d::UnitZ(), Eigen::Vector3d::UnitZ(), xn);
    CHECK_FALSE(fit_instrument_one_view(cam, im, d.trocar, std::span<const Eigen::Vector2d>(xn.data(), 2),
                                        std::span<const int>(which.data(), 2), start, pose, rms_px));
}

TEST_CASE("a second camera's images fix the depth one view leaves loose", "[tracking][pose]") {
    // A needle withdrawn 40 mm along its trocar's line, its markers seen by two cameras of the test rig with 0.05 px
    // of noise: from either camera alone the depth along its line of sight is loose; one fit over both is not.
    DeepShaft d;
    const InstrumentModel& im = d.bodies.instruments[0];
    const auto rig = eyesim::tracking::test::three_camera_rig();
    const Eigen::Vector3d axis = Eigen::Vector3d(0.1, 0.15, 1.0).normalized();
    const Eigen::Vector3d tip = d.trocar + 40.0 * axis;
    InstrumentPose start;
    start.tip_rig_mm = d.trocar - 5.0 * Eigen::Vector3d(0.0, 0.1, 1.0).normalized();  // last seen inside the eye
    start.axis_rig = Eigen::Vector3d(0.0, 0.1, 1.0).normalized();
    std::mt19937_64 rng(11);
    double ss_one = 0.0, ss_two = 0.0;
    const int trials = 20;
    for (int t = 0; t < trials; ++t) {
        std::array<ShaftImage, 6> images{};
        for (int c = 0; c < 2; ++c) {
            const CameraGeometry& cam = rig[std::size_t(c)];
            std::normal_distribution<double> n(0.0, 0.05 / cam.mean_focal_px());
            for (int k = 0; k < 3; ++k) {
                const Eigen::Vector3d p = cam.R_cam_rig * (tip + d.s[k] * axis) + cam.t_cam_rig_mm;
                images[std::size_t(3 * c + k)] = ShaftImage{&cam, p.head<2>() / p.z() + Eigen::Vector2d(n(rng), n(rng)), k};
            }
        }
        InstrumentPose one, two;
        double rms_one = 0.0, rms_two = 0.0;
        REQUIRE(fit_instrument_images(std::span<const ShaftImage>(images.data(), 3), im, d.trocar, start, one, rms_one));
        REQUIRE(fit_instrument_images(images, im, d.trocar, start, two, rms_two));
        CHECK(rms_two < 0.15);
        ss_one += (one.tip_rig_mm - tip).squaredNorm();
        ss_two += (two.tip_rig_mm - tip).squaredNorm();
    }
    const double rms_one_mm = std::sqrt(ss_one / trials), rms_two_mm = std::sqrt(ss_two / trials);
    INFO("tip RMS: camera 0 alone " << rms_one_mm << " mm, cameras 0 and 1 " << rms_two_mm << " mm");
    CHECK(rms_two_mm < 0.05);
    CHECK(rms_two_mm < 0.5 * rms_one_mm);
}

TEST_CASE("a field brought to the frame's time by two fields weighs each parity as the blend does", "[tracking][sync]") {
    // Camera 1 exposes 6 ms after camera 0: interpolated to camera 0's time T from its fields at T − 14 ms and
    // T + 6 ms (α = 0.7 of the later one), extrapolated from the two before T, at T − 34 and T − 14 ms (α = 1.7).
    // The tracker mixes an offset that depends on the field's parity (the marker's image model: the field lines'
    // sampling) by the same weights (CameraField::parity_weight); a field used as it is weighs 1.
    for (SyncMode mode : {SyncMode::Interpolate, SyncMode::Extrapolate}) {
        SyncOptions opt;
        opt.mode = mode;
        FrameSync sync(2, opt);
        double T = 0, end = 0, recv = 0;
        std::uint32_t ref = 0;
        std::array<AlignedCamera, kMaxCameras> cams;
        std::array<CameraField, kMaxCameras> images;
        int blended = 0;
        for (std::uint32_t k = 0; k < 8; ++k) {
            sync.add(one_image_field(0, k, 20000.0 * k, 50.0, 5000.0));
            sync.add(one_image_field(1, k, 20000.0 * k + 6000.0, 100.0 + 0.001 * k, 5000.0));
            while (sync.pop(T, ref, cams, images, end, recv)) {
                INFO("mode " << int(mode) << " T " << T);
                CHECK(images[0].parity_weight == 1.0);
                if (cams[1].state == CameraSyncState::Direct) CHECK(images[1].parity_weight == 1.0);
                if (cams[1].state != CameraSyncState::Interpolated && cams[1].state != CameraSyncState::Extrapolated)
                    continue;
                ++blended;
                const double alpha = mode == SyncMode::Interpolate ? 0.7 : 1.7;
                CHECK(images[1].parity_weight == Approx(alpha).margin(1e-12));
                // The weight is of the later field's parity, which the blend carries.
                const std::uint32_t later = mode == SyncMode::Interpolate ? ref : ref - 1;
                CHECK(images[1].parity == int(later & 1u));
            }
        }
        CHECK(blended >= 5);
    }
}
