// `eyesim validate` without ground truth, through the program a user runs: the truth-free figures on a clean
// recording are small and on the scale of the centroid error; a perturbed `--rig` raises them (and the truth
// error) while a copy of the true rig changes nothing; a recording without truth.jsonl and a capture with `--rig`
// give the same truth-free figures with the truth figures null; a marker built 0.2 mm off its bodies file shows as
// a 200 µm pair-distance error; `--report` writes index.html with the tables; a body one chain never measured is a
// warning in either chain; progress with the time left on a terminal; the wand's length error on a wand recording.
#include "cli_run.hpp"

#include "eyesim/rig/camera.hpp"

#include <catch2/catch.hpp>

#include <Eigen/Geometry>
#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using Result = eyesim::test::CliResult;
using eyesim::test::slurp;

const fs::path& scratch() {
    static const eyesim::test::ScratchDir dir("eyesim_test_validate_truthfree");
    return dir.path();
}

Result run_eyesim(const std::string& args) { return eyesim::test::run_cli(scratch(), EYESIM_EXE, args, 180); }

/// A recording named `name` (synth options in `args`), made once per process.
fs::path synth(const std::string& name, const std::string& args) {
    const fs::path d = scratch() / name;
    if (fs::exists(d / "rig.yaml")) return d;
    const Result r = run_eyesim("synth " + args + " --out " + d.string());
    INFO(r.err);
    REQUIRE(r.rc == 0);
    return d;
}

/// The 0.6 s sweep most cases use (30 fields, both instruments moving, the eye turning).
fs::path sweep() { return synth("sweep", "--scenario sweep --seconds 0.6 --seed 3"); }

nlohmann::json validate_json(const std::string& args) {
    const Result r = run_eyesim("validate " + args + " --json");
    INFO("validate " << args << "\nstderr: " << r.err);
    REQUIRE(r.rc == 0);
    return nlohmann::json::parse(r.out);
}

/// `rig` with camera `cam` turned by `deg` about its own x axis (centre kept), written to `out`.
fs::path rotated_rig(const fs::path& rig, int cam, double deg, const std::string& out) {
    std::vector<eyesim::rig::CameraModel> cams = eyesim::rig::load_rig_yaml(rig.string());
    const Eigen::Matrix3d Rx =
        Eigen::AngleAxisd(deg * std::numbers::pi / 180.0, Eigen::Vector3d::UnitX()).toRotationMatrix();
    cams[std::size_t(cam)].R_cam_rig = Rx * cams[std::size_t(cam)].R_cam_rig;
    cams[std::size_t(cam)].t_cam_rig_mm = Rx * cams[std::size_t(cam)].t_cam_rig_mm;
    const fs::path p = scratch() / out;
    eyesim::rig::save_rig_yaml(p.string(), cams);
    return p;
}

const char* kHeadline[] = {"reprojection_rms_px", "fit_reprojection_rms_px", "ray_residual_rms_um",
                           "pair_distance_rms_um", "dropout_fraction"};

}  // namespace

TEST_CASE("validate: truth-free figures of a clean recording are small and on the centroid error's scale",
          "[host][validate]") {
    const nlohmann::json j = validate_json("--recording " + sweep().string());
    const nlohmann::json& t = j["truth_free"];
    for (const char* k : kHeadline) {
        INFO(k);
        REQUIRE(t[k].is_number());
    }
    const double rp = t["reprojection_rms_px"].get<double>(), centroid = j["centroid_rms_px"].get<double>();
    INFO("reprojection " << rp << " frame px, centroid " << centroid << " field px, ray "
                         << t["ray_residual_rms_um"] << " um, pairs " << t["pair_distance_rms_um"] << " um");
    CHECK(rp > 0.0);
    // Frame px: a field row is two frame rows, and three views leave a residual below the centroid noise; both
    // centroid errors (FPGA, shaft correction) enter. So: the same scale, within a factor of a few.
    CHECK(rp > 0.5 * centroid);
    CHECK(rp < 5.0 * centroid);
    // A ray passing 10 µm from the point at ~85 mm is ~0.07 px: the same residual in other units.
    CHECK(t["ray_residual_rms_um"].get<double>() < 30.0);
    CHECK(t["pair_distance_rms_um"].get<double>() < 30.0);
    CHECK(std::abs(t["pair_distance_mean_error_um"].get<double>()) < 10.0);
    CHECK(t["eye_centre"]["spread_rms_um"].get<double>() < 20.0);
    CHECK(t["eye_centre"]["mean_offset_um"].get<double>() < 20.0);
    CHECK(t["dropout_fraction"].get<double>() < 0.2);
    REQUIRE(t["per_camera"].size() == 3);
    for (const auto& c : t["per_camera"]) {
        CHECK(c["views"].get<long>() > 150);  // ~ 8 markers in ~29 frames
        CHECK(c["reprojection_rms_px"].get<double>() < 3.0 * rp);
    }
    // Every body of the scene has its pairs measured; a wand (none in a sweep) is null.
    CHECK(t["wand_length_error_um"].is_null());
    int pairs = 0;
    for (const auto& p : t["pair_distances"]) pairs += p["frames"].get<long>() > 0;
    CHECK(pairs >= 3 + 3 + 6);
}

TEST_CASE("validate --rig: a copy of the true rig changes nothing, a rotated camera raises both the residual and "
          "the truth error",
          "[host][validate]") {
    const fs::path rec = sweep();
    const nlohmann::json base = validate_json("--recording " + rec.string());
    fs::copy_file(rec / "rig.yaml", scratch() / "copy.yaml", fs::copy_options::overwrite_existing);
    const nlohmann::json same = validate_json("--recording " + rec.string() + " --rig " + (scratch() / "copy.yaml").string());
    CHECK(same["rig"] == (scratch() / "copy.yaml").string());
    CHECK(same["truth_free"] == base["truth_free"]);
    for (const char* k : {"marker3d_rms_um", "tip_rms_um", "eye_rot_rms_deg", "centroid_rms_px"}) CHECK(same[k] == base[k]);

    // Camera 0 turned by 0.05°: its images move by ~0.56 frame px against the rig the tracker believes.
    const fs::path bad = rotated_rig(rec / "rig.yaml", 0, 0.05, "rotated.yaml");
    const nlohmann::json p = validate_json("--recording " + rec.string() + " --rig " + bad.string());
    const nlohmann::json &tb = base["truth_free"], &tp = p["truth_free"];
    INFO("reprojection " << tb["reprojection_rms_px"] << " -> " << tp["reprojection_rms_px"] << " px; 3D "
                         << base["marker3d_rms_um"] << " -> " << p["marker3d_rms_um"] << " um");
    CHECK(tp["reprojection_rms_px"].get<double>() > 2.0 * tb["reprojection_rms_px"].get<double>());
    CHECK(tp["per_camera"][0]["reprojection_rms_px"].get<double>() >
          3.0 * tb["per_camera"][0]["reprojection_rms_px"].get<double>());
    CHECK(tp["ray_residual_rms_um"].get<double>() > 2.0 * tb["ray_residual_rms_um"].get<double>());
    CHECK(p["marker3d_rms_um"].get<double>() > 1.5 * base["marker3d_rms_um"].get<double>());
    // The FPGA model still reads the recording's fields: the centroids are the same.
    CHECK(p["centroid_rms_px"] == base["centroid_rms_px"]);

    // A rig of another camera count is refused, naming both.
    std::vector<eyesim::rig::CameraModel> two = eyesim::rig::load_rig_yaml((rec / "rig.yaml").string());
    two.pop_back();
    eyesim::rig::save_rig_yaml((scratch() / "two.yaml").string(), two);
    const Result r = run_eyesim("validate --recording " + rec.string() + " --rig " + (scratch() / "two.yaml").string());
    CHECK(r.rc == 1);
    CHECK(r.err.find("2 cameras, the recording") != std::string::npos);
}

TEST_CASE("validate: a recording without truth.jsonl, and a capture with --rig, give the truth-free figures",
          "[host][validate]") {
    const fs::path rec = sweep();
    const nlohmann::json with_truth = validate_json("--recording " + rec.string());
    // The same recording without its truth.
    const fs::path bare = scratch() / "bare";
    fs::remove_all(bare);
    fs::copy(rec, bare);
    fs::remove(bare / "truth.jsonl");
    const Result text = run_eyesim("validate --recording " + bare.string());
    INFO(text.err);
    REQUIRE(text.rc == 0);
    CHECK(text.err.empty());
    CHECK(text.out.find("no truth.jsonl: truth-free figures only") != std::string::npos);
    CHECK(text.out.find("truth-free, FPGA chain") != std::string::npos);
    CHECK(text.out.find("3D marker RMS") == std::string::npos);
    const nlohmann::json j = validate_json("--recording " + bare.string());
    CHECK(j["truth"] == false);
    for (const char* k : {"centroid_rms_px", "marker3d_rms_um", "tip_rms_um", "eye_rot_rms_deg", "truth_centroids"}) {
        INFO(k);
        CHECK(j[k].is_null());
    }
    CHECK(j["per_camera"][0]["centroid_rms_px"].is_null());
    CHECK(j["fpga_chain"]["marker3d_um"]["count"] == 0);
    // Without truth every instrument kind is fitted; the two in view are found the same way.
    for (const char* k : kHeadline) {
        INFO(k);
        CHECK(j["truth_free"][k] == with_truth["truth_free"][k]);
    }

    // The FPGA chain's packets as a capture, tracked with the recording's rig: the same chain, the same figures.
    const fs::path cap = scratch() / "sweep.cap";
    REQUIRE(run_eyesim("fpga --recording " + rec.string() + " --out " + cap.string()).rc == 0);
    const nlohmann::json c = validate_json("--capture " + cap.string() + " --rig " + (rec / "rig.yaml").string());
    CHECK(c["truth"] == false);
    CHECK(c["capture"] == cap.string());
    CHECK(c["frames"].get<long>() >= 29);
    CHECK(c["marker3d_rms_um"].is_null());
    for (const char* k : kHeadline) {
        INFO(k);
        REQUIRE(c["truth_free"][k].is_number());
        CHECK(c["truth_free"][k].get<double>() == Approx(with_truth["truth_free"][k].get<double>()).epsilon(0.02));
    }
    // A capture needs the rig, and one source only.
    const Result no_rig = run_eyesim("validate --capture " + cap.string());
    CHECK(no_rig.rc == 2);
    CHECK(no_rig.err.find("--capture needs --rig") != std::string::npos);
    CHECK(run_eyesim("validate --capture " + cap.string() + " --recording " + rec.string()).rc == 2);
    CHECK(run_eyesim("validate").rc == 2);
    CHECK(run_eyesim("validate --capture " + cap.string() + " --rig " + (rec / "rig.yaml").string() + " --refine").rc == 2);
}

TEST_CASE("validate: a marker built 0.2 mm off its bodies file shows as a 200 um pair-distance error",
          "[host][validate]") {
    // Rendered with every instrument's third marker 0.2 mm further from the tip, tracked with the true file: the
    // pairs (0, 2) and (1, 2) are 0.2 mm longer than the file says, the pair (0, 1) is as it says.
    nlohmann::json b = nlohmann::json::parse(slurp(fs::path(EYESIM_SOURCE_DIR) / "scenes/bodies.json"));
    for (auto& inst : b["instruments"]) inst["markers"][2]["distance_from_tip_mm"] = inst["markers"][2]["distance_from_tip_mm"].get<double>() + 0.2;
    const fs::path bodies = scratch() / "longer.json";
    std::ofstream(bodies, std::ios::trunc) << b.dump(1);
    const fs::path rec = synth("longer", "--scenario sweep --seconds 0.4 --seed 5 --bodies " + bodies.string());
    const nlohmann::json j = validate_json("--recording " + rec.string());
    int checked = 0;
    for (const auto& p : j["truth_free"]["pair_distances"]) {
        if (p["body"] == "eye" || p["frames"].get<long>() < 10) continue;
        INFO(p.dump());
        const double mean = p["mean_error_um"].get<double>();
        if (p["markers"][1] == 2)
            CHECK(mean == Approx(200.0).margin(30.0));
        else
            CHECK(std::abs(mean) < 30.0);
        ++checked;
    }
    CHECK(checked == 6);
    // Each instrument's length (its outermost pair) says the same.
    for (const auto& body : j["truth_free"]["bodies"])
        if (body["body"] != "eye" && body["measured_frames"].get<long>() > 0)
            CHECK(body["length"]["mean_error_um"].get<double>() == Approx(200.0).margin(30.0));
}

TEST_CASE("validate --report writes index.html with the tables and every plot", "[host][validate]") {
    const fs::path rec = sweep();
    const fs::path dir = scratch() / "report";
    const nlohmann::json j = validate_json("--recording " + rec.string() + " --report " + dir.string());
    CHECK(j["report"] == (dir / "index.html").string());
    const std::string h = slurp(dir / "index.html");
    REQUIRE(h.rfind("<!doctype html>", 0) == 0);
    CHECK(h.find("</html>") != std::string::npos);
    for (const char* s : {"Truth-free checks", "reprojection RMS (px)", "ray residual RMS (µm)", "dropout (%)",
                          "Marker-pair distances against the bodies file", "distance in file (mm)",
                          "eye-centre spread RMS (µm)", "Centroids against the rendered truth (field px)",
                          "RMS by eyesim fpga's rule (px)", "Why <code>eyesim fpga</code> gives other centroid figures",
                          "(occluded_fraction 0)", "<code>eyesim validate</code> scores only", "3 px gate", "1.5 px gate", "Poses against the truth", "field end → poses ready (µs)"}) {
        INFO(s);
        CHECK(h.find(s) != std::string::npos);
    }
    CHECK(h.find("<table>") != std::string::npos);
    // Every picture the page shows is there, including a residual histogram per camera.
    std::size_t at = 0, images = 0;
    while ((at = h.find("<img src='", at)) != std::string::npos) {
        at += 10;
        const std::string file = h.substr(at, h.find('\'', at) - at);
        INFO(file);
        CHECK(fs::file_size(dir / file) > 1000);
        ++images;
    }
    CHECK(images >= 11);
    CHECK(h.find("reprojection_hist.png") != std::string::npos);
    CHECK(!fs::exists(dir / "report.md"));
    // Both rules' figures are in the JSON the table is made from, and `fpga`'s rule gives what `eyesim fpga` says
    // (its blobs before the Q16.16 wire format: within a rounding of 1/65536 px).
    const Result f = run_eyesim("fpga --recording " + rec.string() + " --json");
    REQUIRE(f.rc == 0);
    const nlohmann::json fj = nlohmann::json::parse(f.out);
    REQUIRE(fj["cameras"].size() == j["per_camera"].size());
    for (std::size_t c = 0; c < fj["cameras"].size(); ++c) {
        const nlohmann::json &v = j["per_camera"][c], &d = fj["cameras"][c];
        INFO("camera " << c);
        CHECK(v["fpga_rule"]["matched"] == d["matched"]);
        CHECK(v["fpga_rule"]["missed"] == d["missed"]);
        CHECK(v["fpga_rule"]["centroid_rms_px"].get<double>() == Approx(d["centroid_rms_px"].get<double>()).margin(1e-4));
        CHECK(v["fpga_rule"]["matched"].get<long>() > v["matched"].get<long>());
    }

    // A capture's report: the truth-free part alone.
    const fs::path cap = scratch() / "report.cap";
    REQUIRE(run_eyesim("fpga --recording " + rec.string() + " --out " + cap.string()).rc == 0);
    const fs::path cdir = scratch() / "capture_report";
    validate_json("--capture " + cap.string() + " --rig " + (rec / "rig.yaml").string() + " --report " + cdir.string());
    const std::string ch = slurp(cdir / "index.html");
    CHECK(ch.find("Truth-free checks") != std::string::npos);
    CHECK(ch.find("No ground truth") != std::string::npos);
    CHECK(ch.find("Poses against the truth") == std::string::npos);
}

TEST_CASE("validate: a body the truth-centroid chain never measured is a warning too", "[host][validate]") {
    // Truth centroids with 10 px of noise match nothing; the FPGA chain measures every body.
    const fs::path rec = sweep();
    const Result r = run_eyesim("validate --recording " + rec.string() + " --truth-noise-px 10 --json");
    INFO(r.err);
    REQUIRE(r.rc == 0);
    const nlohmann::json j = nlohmann::json::parse(r.out);
    std::vector<std::string> expect;
    for (const char* body : {"eye", "pick", "light_pipe"})
        expect.push_back(rec.string() + ": " + body + " not measured in any of the " +
                         std::to_string(j["truth_centroids"]["frames"].get<long>()) +
                         " scored frames (truth-centroid chain; FPGA chain in ");
    REQUIRE(j["warnings"].size() == expect.size());
    for (std::size_t i = 0; i < expect.size(); ++i) {
        const std::string w = j["warnings"][i].get<std::string>();
        INFO(w);
        CHECK(w.rfind(expect[i], 0) == 0);
        CHECK(w.find("): its truth-centroid figures are not measured") != std::string::npos);
        CHECK(r.err.find("eyesim: warning: " + w + "\n") != std::string::npos);
    }
    CHECK(j["truth_centroids"]["eye_rot_rms_deg"].is_null());
    CHECK(j["eye_rot_rms_deg"].is_number());
}

TEST_CASE("validate: progress with the time left on a terminal, also while the report is written",
          "[host][validate]") {
    // `script` gives the command a terminal; with --json, or stderr not a terminal, there is no progress line.
    const fs::path rec = sweep();
    const fs::path log = scratch() / "tty.txt";
    const std::string cmd = "script -qec \"" + std::string(EYESIM_EXE) + " validate --recording " + rec.string() +
                            " --report " + (scratch() / "tty_report").string() + " >/dev/null\" " + log.string() +
                            " >/dev/null 2>&1";
    REQUIRE(std::system(cmd.c_str()) == 0);
    const std::string tty = slurp(log);
    INFO(tty);
    CHECK(tty.find("validate: 30/30 fields") != std::string::npos);
    CHECK(tty.find(" left") != std::string::npos);
    CHECK(tty.find("validate: writing report: ") != std::string::npos);
    const Result piped = run_eyesim("validate --recording " + rec.string());
    CHECK(piped.err.empty());
}

TEST_CASE("validate: the wand's length error on a wand recording, and 200 um when the file says 0.2 mm longer",
          "[host][validate]") {
    // The wand is not a tracked body: validate finds it among the markers no body claimed and measures its length
    // (outermost markers) against scenes/bodies.json, as a wanding would.
    const fs::path rec = synth("wand", "--scenario wand --seconds 1 --seed 2");
    const Result r = run_eyesim("validate --recording " + rec.string() + " --json");
    REQUIRE(r.rc == 0);
    CHECK(r.err.empty());  // the instruments are lifted out of view: not measured, and nothing to warn about
    const nlohmann::json j = nlohmann::json::parse(r.out);
    CHECK(j["tip_rms_um"].is_null());
    const nlohmann::json& w = j["truth_free"]["wand_length_error_um"];
    REQUIRE(w.is_object());
    CHECK(w["body"] == "wand");
    CHECK(w["frames"].get<long>() >= 20);
    CHECK(std::abs(w["mean_error_um"].get<double>()) < 20.0);
    CHECK(w["rms_error_um"].get<double>() < 30.0);
    // The same recording tracked with a bodies file whose wand is 0.2 mm longer: the wand measures 200 µm short.
    nlohmann::json b = nlohmann::json::parse(slurp(fs::path(EYESIM_SOURCE_DIR) / "scenes/bodies.json"));
    auto& last = b["wand"]["markers"].back()["distance_mm"];
    last = last.get<double>() + 0.2;
    const fs::path bodies = scratch() / "wand_longer.json";
    std::ofstream(bodies, std::ios::trunc) << b.dump(1);
    const nlohmann::json l = validate_json("--recording " + rec.string() + " --bodies " + bodies.string());
    const nlohmann::json& wl = l["truth_free"]["wand_length_error_um"];
    REQUIRE(wl.is_object());
    CHECK(wl["frames"] == w["frames"]);
    CHECK(wl["mean_error_um"].get<double>() == Approx(w["mean_error_um"].get<double>() - 200.0).margin(1.0));
    // A recording without a wand has none.
    CHECK(validate_json("--recording " + sweep().string())["truth_free"]["wand_length_error_um"].is_null());
}
