// Recording directories: synthesis, reading back (raw and video), truth.jsonl, and every malformed input class.
#include "recording_dirs.hpp"

#include "eyesim/rig/error.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/rig/truth.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>
#include <opencv2/videoio.hpp>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>

using namespace eyesim::rig;
namespace fs = std::filesystem;

using namespace rigtest;

namespace {

/// A short synthetic recording shared by the tests of this file.
const std::string& recording() {
    static const std::string dir = [] {
        const std::string d = temp_dir("base");
        SynthRequest req;
        req.out_dir = d;
        req.scenario = "surgery";
        req.seconds = 0.2;
        req.seed = 9;
        const SynthSummary s = write_recording(req);
        REQUIRE(s.fields == 10);
        return d;
    }();
    static const RemoveAtExit cleanup{dir};
    return dir;
}

}  // namespace

TEST_CASE("synthesised recording reads back: counts, bytes, parity, timing", "[rig][recording]") {
    const std::string dir = recording();
    Recording rec = Recording::open(dir);
    REQUIRE(rec.camera_count() == 3);
    CHECK(rec.warnings().empty());
    std::vector<uint8_t> f(kFieldBytes);
    for (int c = 0; c < 3; ++c) {
        CHECK(rec.field_count(c) == 10);
        CHECK(rec.format(c) == StreamFormat::kRawUyvy);
        for (int64_t i : {0, 3, 9, 1}) {
            rec.read_field(c, i, f.data());
            CHECK(f == file_bytes(rec.stream_path(c), static_cast<size_t>(i) * kFieldBytes, kFieldBytes));
            CHECK(rec.field_parity(c, i) == static_cast<int>(i % 2));
        }
        CHECK(rec.field_end_time_us(c, 2) - rec.field_end_time_us(c, 0) == Approx(40000.0));
        CHECK_THROWS_AS(rec.read_field(c, 10, f.data()), RigError);
    }
    CHECK_THROWS_AS(rec.field_count(3), RigError);
    // Cameras are unsynchronised: the same field index ends at different times.
    CHECK(rec.field_end_time_us(0, 0) != rec.field_end_time_us(1, 0));
}

TEST_CASE("truth.jsonl: one line per field, consistent with the cameras and bodies", "[rig][recording][truth]") {
    const std::string dir = recording();
    Recording rec = Recording::open(dir);
    const auto truth = read_truth(rec.truth_path());
    REQUIRE(truth.size() == 10);
    const Bodies bodies = load_bodies(default_bodies_path());
    size_t visible = 0;
    for (size_t i = 0; i < truth.size(); ++i) {
        const FieldTruth& t = truth[i];
        CHECK(t.field == static_cast<int64_t>(i));
        REQUIRE(t.cameras.size() == 3);
        for (int c = 0; c < 3; ++c) {
            CHECK(t.cameras[c].parity == rec.field_parity(c, t.field));
            CHECK(t.cameras[c].end_us == Approx(rec.field_end_time_us(c, t.field)));
        }
        REQUIRE(t.instruments.size() == 2);
        CHECK(t.instruments[0].kind == InstrumentKind::kForceps);
        CHECK(t.instruments[0].jaw_opening == Approx(1.0 - t.pedal.axes[0]));
        // Tip and axis in rig and eye frames agree through the eye rotation.
        for (const auto& in : t.instruments) {
            CHECK((t.q_eye_to_rig * in.tip_eye_mm + t.eye_center_rig_mm - in.tip_rig_mm).norm() < 1e-9);
            CHECK((t.q_eye_to_rig * in.axis_eye - in.axis_rig).norm() < 1e-9);
        }
        REQUIRE(t.markers.size() == bodies.eye.markers.size() + 6);
        for (const auto& m : t.markers) {
            REQUIRE(m.cams.size() == 3);
            if (m.body == "eye") {
                // Eye markers: rotated body positions.
                const Eigen::Vector3d expect = t.eye_center_rig_mm + t.q_eye_to_rig * bodies.eye.markers[m.id].position_eye_mm;
                CHECK((expect - m.center_rig_mm).norm() < 1e-9);
            }
            for (int c = 0; c < 3; ++c) {
                const auto& mc = m.cams[c];
                if (!mc.visible) continue;
                ++visible;
                // The projected centre of the per-camera 3D centre, through rig.yaml's camera.
                const auto p = rec.cameras()[c].project_field(mc.center_rig_mm, t.cameras[c].parity);
                REQUIRE(p);
                CHECK((*p - mc.projected_px).norm() < 1e-9);
                // Unoccluded: intensity centroid near the projected centre (perspective, shading, blur apart).
                if (mc.occluded_fraction == 0) CHECK((mc.centroid_px - mc.projected_px).norm() < 1.0);
                CHECK(mc.radius_px > 2.5);
            }
        }
    }
    CHECK(visible > 200);
    // Round trip of one line.
    const std::string line = truth_to_json_line(truth[3]);
    const FieldTruth back = truth_from_json_line(line, "mem");
    CHECK(truth_to_json_line(back) == line);
}

TEST_CASE("synth output is byte-identical for the same seed", "[rig][recording][determinism]") {
    const std::string a = temp_dir("det_a"), b = temp_dir("det_b");
    for (const auto& d : {a, b}) {
        SynthRequest req;
        req.out_dir = d;
        req.scenario = "occlusion";
        req.seconds = 0.06;
        req.seed = 77;
        write_recording(req);
    }
    for (const char* f : {"cam0.uyvy", "cam1.uyvy", "cam2.uyvy", "truth.jsonl", "rig.yaml"}) {
        const auto sa = fs::file_size(fs::path(a) / f);
        CHECK(file_bytes((fs::path(a) / f).string(), 0, sa) == file_bytes((fs::path(b) / f).string(), 0, sa));
    }
    fs::remove_all(a);
    fs::remove_all(b);
}

TEST_CASE("malformed recordings give one-line errors", "[rig][recording][errors]") {
    const std::string base = recording();
    const std::string d = temp_dir("bad");
    SECTION("truncated camera file") {
        copy_dir(base, d);
        fs::resize_file(fs::path(d) / "cam1.uyvy", 3 * static_cast<uintmax_t>(kFieldBytes) + 1000);
        expect_open_error(d, "cam1.uyvy: size: 1245160 bytes is not a whole number");
    }
    SECTION("missing camera file") {
        copy_dir(base, d);
        fs::remove(fs::path(d) / "cam2.uyvy");
        expect_open_error(d, "cam2.uyvy: file: missing");
    }
    SECTION("empty camera file") {
        copy_dir(base, d);
        fs::resize_file(fs::path(d) / "cam0.uyvy", 0);
        expect_open_error(d, "cam0.uyvy: size: empty");
    }
    SECTION("missing rig.yaml") {
        copy_dir(base, d);
        fs::remove(fs::path(d) / "rig.yaml");
        expect_open_error(d, "rig.yaml: file: missing");
    }
    SECTION("NaN in rig.yaml") {
        copy_dir(base, d);
        std::ifstream in(fs::path(d) / "rig.yaml");
        std::stringstream ss;
        ss << in.rdbuf();
        std::string t = ss.str();
        const size_t k = t.find(" t: !!opencv-matrix", t.find("cam0:"));
        const size_t data = t.find("data: [", k) + 7;
        t = t.substr(0, data) + " .Nan" + t.substr(t.find(',', data));
        std::ofstream(fs::path(d) / "rig.yaml") << t;
        expect_open_error(d, "rig.yaml: cam0.t[0,0]: not finite");
    }
    SECTION("manifest disagreeing with the files") {
        copy_dir(base, d);
        fs::resize_file(fs::path(d) / "cam2.uyvy", 4 * static_cast<uintmax_t>(kFieldBytes));
        expect_open_error(d, "manifest.json: cameras[2].fields: says 10, cam2.uyvy holds 4");
    }
    SECTION("manifest describing other files") {
        copy_dir(base, d);
        const fs::path m = fs::path(d) / "manifest.json";
        std::ifstream in(m);
        nlohmann::json j = nlohmann::json::parse(in);
        in.close();
        struct Edit {
            const char* what;
            std::function<void(nlohmann::json&)> edit;
        };
        const Edit edits[] = {
            {"manifest.json: field_bytes: is 1, expected 414720", [](nlohmann::json& x) { x["field_bytes"] = 1; }},
            {"manifest.json: format: is 7, expected", [](nlohmann::json& x) { x["format"] = 7; }},
            {"manifest.json: format: says \"video\", but cam0.uyvy is raw UYVY", [](nlohmann::json& x) { x["format"] = "video"; }},
            {"manifest.json: cameras[1].file: says \"../cam1.uyvy\", but camera 1's stream is cam1.uyvy",
             [](nlohmann::json& x) { x["cameras"][1]["file"] = "../cam1.uyvy"; }},
            {"manifest.json: cameras[0]: not a JSON object", [](nlohmann::json& x) { x["cameras"][0] = 3; }},
            {"manifest.json: file: not a JSON object", [](nlohmann::json& x) { x = nlohmann::json::array({1, 2}); }},
        };
        for (const Edit& e : edits) {
            nlohmann::json x = j;
            e.edit(x);
            std::ofstream(m) << x.dump();
            expect_open_error(d, e.what);
        }
    }
    SECTION("manifest is optional") {
        copy_dir(base, d);
        fs::remove(fs::path(d) / "manifest.json");
        fs::remove(fs::path(d) / "truth.jsonl");
        Recording r = Recording::open(d);
        CHECK(r.common_field_count() == 10);
        CHECK(r.truth_path().empty());
    }
    SECTION("missing directory") { expect_open_error(d + "/nope", "nope: directory: missing"); }
    SECTION("malformed truth line") {
        copy_dir(base, d);
        std::ofstream(fs::path(d) / "truth.jsonl", std::ios::app) << "{\"field\": 1, \"t_us\": \"x\"}\n";
        CHECK_THROWS_WITH(read_truth((fs::path(d) / "truth.jsonl").string()), Catch::Contains("truth.jsonl:11: t_us: not a number"));
    }
    fs::remove_all(d);
}

TEST_CASE("video recordings: interlaced frames split into fields", "[rig][recording][video]") {
    const std::string d = temp_dir("video");
    SynthRequest req;
    req.out_dir = d;
    req.scenario = "static";
    req.seconds = 0.08;
    req.seed = 3;
    req.format = "video";  // lossless FFV1 4:2:2 .mkv
    req.render.noise_sigma = 0;
    const SynthSummary s = write_recording(req);
    CHECK(s.fields == 4);
    Recording rec = Recording::open(d);
    REQUIRE(rec.format(0) == StreamFormat::kVideo);
    CHECK(fs::path(rec.stream_path(0)).extension() == ".mkv");
    CHECK(rec.field_count(0) == 4);
    // The same fields rendered as raw UYVY: lossless 4:2:2 gives them back bit for bit.
    const std::string r = temp_dir("video_raw");
    req.out_dir = r;
    req.format = "uyvy";
    write_recording(req);
    Recording raw = Recording::open(r);
    std::vector<uint8_t> a(kFieldBytes), b(kFieldBytes);
    for (int64_t i : {0, 1, 2, 3, 0}) {  // the last: reading backwards seeks
        INFO("field " << i);
        CHECK(rec.read_field(1, i, a.data()));
        raw.read_field(1, i, b.data());
        CHECK(a == b);
    }
    fs::remove_all(d);
    fs::remove_all(r);
}

TEST_CASE("video: wrong frame size is an error, and 30 frames/s, no field order, 50 frames/s are warnings", "[rig][recording][video]") {
    const std::string base = recording();
    const std::string d = temp_dir("video_kinds");
    copy_dir(base, d);
    fs::remove(fs::path(d) / "manifest.json");
    auto write_video = [&](const std::string& name, cv::Size size, double fps, int frames) {
        cv::VideoWriter w;
        const std::string path = (fs::path(d) / name).string();
        if (!w.open(path, cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), fps, size, true)) return false;
        for (int i = 0; i < frames; ++i) {
            cv::Mat f(size, CV_8UC3, cv::Scalar(20 + i, 40, 60));
            w.write(f);
        }
        w.release();
        return true;
    };
    fs::remove(fs::path(d) / "cam1.uyvy");
    if (!write_video("cam1.avi", {640, 480}, 25.0, 3)) {
        WARN("no MJPG encoder here");
        return;
    }
    expect_open_error(d, "cam1.avi: frame size: 640x480, expected 720x576");
    fs::remove(fs::path(d) / "cam1.avi");
    // 30 frames/s and no field order in the stream (MJPG): two warnings.
    REQUIRE(write_video("cam1.avi", {720, 576}, 30.0, 4));
    {
        Recording rec = Recording::open(d);
        CHECK(rec.field_count(1) == 8);
        REQUIRE(rec.warnings().size() == 2);
        CHECK(rec.warnings()[0].find("30 frames/s (PAL is 25)") != std::string::npos);
        CHECK(rec.warnings()[1].find("does not say its field order") != std::string::npos);
    }
    fs::remove(fs::path(d) / "cam1.avi");
    REQUIRE(write_video("cam1.avi", {720, 576}, 50.0, 6));
    Recording rec = Recording::open(d);
    CHECK(rec.field_count(1) == 6);
    REQUIRE(rec.warnings().size() == 1);
    CHECK(rec.warnings()[0].find("progressive") != std::string::npos);
    // A flat BGR (60, 40, 20 + i) frame decodes to the BT.601 values of that colour in both parities.
    std::vector<uint8_t> f(kFieldBytes);
    rec.read_field(1, 3, f.data());
    CHECK(rec.field_parity(1, 3) == 1);
    const double y = 16 + 219.0 / 255.0 * (0.299 * 60 + 0.587 * 40 + 0.114 * 23);
    CHECK(std::abs(f[kFieldBytes / 2 + 1] - y) <= 2.0);
    fs::remove_all(d);
}

namespace {

/// Linear least-squares triangulation from undistorted rays of several cameras (rig frame, mm).
Eigen::Vector3d triangulate(const std::vector<CameraModel>& cams, const std::vector<int>& which,
                            const std::vector<Eigen::Vector2d>& frame_px) {
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    for (size_t k = 0; k < which.size(); ++k) {
        const CameraModel& c = cams[which[k]];
        const auto q = c.undistort_to_normalized(frame_px[k]);
        const Eigen::Vector3d d = (c.R_cam_rig.transpose() * Eigen::Vector3d(q->x(), q->y(), 1)).normalized();
        const Eigen::Matrix3d P = Eigen::Matrix3d::Identity() - d * d.transpose();
        A += P;
        b += P * c.center_rig_mm();
    }
    return A.ldlt().solve(b);
}

}  // namespace

TEST_CASE("truth is geometrically consistent: projected centres triangulate exactly, centroids nearly",
          "[rig][recording][truth]") {
    const std::string dir = temp_dir("static");
    SynthRequest req;
    req.out_dir = dir;
    req.scenario = "static";
    req.seconds = 0.1;
    req.seed = 21;
    write_recording(req);
    Recording rec = Recording::open(dir);
    const auto truth = read_truth(rec.truth_path());
    const auto& cams = rec.cameras();
    double worst_proj = 0, sum2 = 0;
    int n = 0;
    for (const FieldTruth& t : truth)
        for (const MarkerTruth& m : t.markers) {
            std::vector<int> which;
            std::vector<Eigen::Vector2d> proj, cen;
            for (int c = 0; c < 3; ++c) {
                const auto& mc = m.cams[c];
                if (!mc.visible || mc.occluded_fraction > 0) continue;
                which.push_back(c);
                proj.push_back(field_to_frame_px(mc.projected_px, t.cameras[c].parity));
                cen.push_back(field_to_frame_px(mc.centroid_px, t.cameras[c].parity));
            }
            if (which.size() < 2) continue;
            // Static-enough check: cameras see the marker at different times; compare each with its own centre.
            Eigen::Vector3d mean_center = Eigen::Vector3d::Zero();
            for (int c : which) mean_center += m.cams[c].center_rig_mm;
            mean_center /= which.size();
            double spread = 0;
            for (int c : which) spread = std::max(spread, (m.cams[c].center_rig_mm - mean_center).norm());
            if (spread > 1e-3) continue;  // moved more than 1 µm between the cameras' exposures
            worst_proj = std::max(worst_proj, (triangulate(cams, which, proj) - mean_center).norm());
            sum2 += (triangulate(cams, which, cen) - mean_center).squaredNorm();
            ++n;
        }
    INFO("markers triangulated: " << n);
    REQUIRE(n > 5);
    CHECK(worst_proj < 1e-6);  // mm: the projected centres are exact
    const double rms_um = 1000.0 * std::sqrt(sum2 / n);
    INFO("centroid triangulation RMS " << rms_um << " um");
    CHECK(rms_um < 25.0);
    fs::remove_all(dir);
}
