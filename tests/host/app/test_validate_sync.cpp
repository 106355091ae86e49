// `eyesim validate --sync async` through the program a user runs: per-body filters updated by each camera field at
// its own time give the poses one field's readout after exposure, where interpolation waits for the other cameras'
// next fields; figures against the truth stay in range; an unknown mode is a usage error.
#include "cli_run.hpp"

#include <catch2/catch.hpp>

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>

namespace {

namespace fs = std::filesystem;

using Result = eyesim::test::CliResult;

const fs::path& scratch() {
    static const eyesim::test::ScratchDir dir("eyesim_test_validate_sync");
    return dir.path();
}

Result run_eyesim(const std::string& args) { return eyesim::test::run_cli(scratch(), EYESIM_EXE, args, 180); }

/// A recording of `scenario` (made once per test run); `genlocked`: every camera's field exposed at once.
fs::path recording(const std::string& scenario, double seconds, int seed, bool genlocked = false) {
    const fs::path d = scratch() / (scenario + (genlocked ? "_genlocked_" : "_") +
                                    std::to_string(int(seconds * 1000.0)) + "ms_" + std::to_string(seed));
    if (fs::exists(d / "rig.yaml")) return d;
    const Result r = run_eyesim("synth --scenario " + scenario + " --seconds " + std::to_string(seconds) + " --seed " +
                                std::to_string(seed) + (genlocked ? " --synchronised" : "") + " --out " + d.string());
    INFO(r.err);
    REQUIRE(r.rc == 0);
    return d;
}

/// A 1 s sweep (50 fields per camera).
fs::path sweep() { return recording("sweep", 1, 3); }

// Frames in which either instrument of an `occlusion` recording (injection, light pipe) was not measured.
int instrument_frames_held(const nlohmann::json& chain) {
    const nlohmann::json& h = chain["instrument_not_measured_frames"];
    return h["injection"].get<int>() + h["light_pipe"].get<int>();
}

/// `validate --json` of `dir` with `--sync sync` and more options.
nlohmann::json validate_dir_json(const fs::path& dir, const std::string& sync, const std::string& more = "") {
    const Result r = run_eyesim("validate --recording " + dir.string() + " --sync " + sync + " --json" + more);
    INFO("--sync " << sync << "\nstderr: " << r.err);
    REQUIRE(r.rc == 0);
    return nlohmann::json::parse(r.out);
}

nlohmann::json validate_json(const std::string& sync, const std::string& more = "") {
    return validate_dir_json(sweep(), sync, more);
}

}  // namespace

TEST_CASE("validate --sync async: poses one field readout after exposure, figures against the truth in range",
          "[host][validate]") {
    const nlohmann::json a = validate_json("async");
    const nlohmann::json i = validate_json("interpolate");
    CHECK(a["sync"] == "async");
    const double a50 = a["exposure_to_pose_us"]["p50"].get<double>(), i50 = i["exposure_to_pose_us"]["p50"].get<double>();
    INFO("exposure -> pose p50: async " << a50 << " us, interpolate " << i50 << " us");
    // The field's own readout: exposure mid → last pixel 21.8 ms (PAL timing, 4 ms shutter), plus transfer and the
    // tracking stage's compute, measured on this machine (a sanitizer build's is ten times a release build's).
    const double compute50 = a["fpga_chain"]["tracking_compute_us"]["p50"].get<double>();
    INFO("async tracking compute p50 " << compute50 << " us");
    CHECK(a50 > 21800.0);
    CHECK(a50 < 23000.0 + compute50);
    // Interpolation waits for the later cameras' next fields (up to a field period more).
    CHECK(i50 > a50 + 10000.0);
    CHECK(a["fpga_chain"]["frames"] == i["fpga_chain"]["frames"]);
    for (const char* k : {"marker3d_rms_um", "marker3d_all_rms_um", "tip_rms_um", "eye_rot_rms_deg"}) {
        INFO(k);
        REQUIRE(a[k].is_number());
        CHECK(a[k].get<double>() > 0.0);
    }
    // Measured over seeds 2-6 (docs/validation.md, motion-model mixture): 3D medians 23-41 um (worst 51), tip
    // medians 32-75 um (worst 103), eye 0.009-0.034 deg.
    CHECK(a["marker3d_all_rms_um"].get<double>() < 200.0);
    CHECK(a["tip_rms_um"].get<double>() < 250.0);
    CHECK(a["eye_rot_rms_deg"].get<double>() < 0.1);
}

TEST_CASE("validate --sync async --emit blob: each blob fused as it arrives, the pose long before the field ends",
          "[host][validate]") {
    // The device in low-latency mode sends each blob as the FPGA completes it; the filters take each part at once
    // (at the field's exposure time, predicted from the camera's last field), and with --report-delay-ms 0 every
    // part of the reference camera that corrected a filter gives a pose. Markers in the middle of the image are read out about 10 ms
    // before the field's last line.
    const nlohmann::json f = validate_json("async");
    const nlohmann::json b = validate_json("async", " --emit blob --report-delay-ms 0");
    CHECK(b["emit"] == "blob");
    CHECK(f["emit"] == "field");
    const double f50 = f["exposure_to_pose_us"]["p50"].get<double>(), b50 = b["exposure_to_pose_us"]["p50"].get<double>();
    INFO("exposure -> pose p50: per field " << f50 << " us, per blob " << b50 << " us");
    CHECK(b50 < f50 - 4000.0);
    CHECK(b50 < 21000.0);  // the target; measured 14.9 ms on this recording
    CHECK(b50 > 5000.0);   // not before the markers' lines are read out
    // A pose per accepting part: several per reference field.
    CHECK(b["fpga_chain"]["frames"].get<int>() > 3 * f["fpga_chain"]["frames"].get<int>());
    // Parts of a camera whose field began before another camera's newer part arrive after it: the filters fuse them
    // at their own time (docs/tracking.md, "Out-of-order images"). Whole fields come in exposure order.
    CHECK(b["fpga_chain"]["time_ordered_parts"].get<long>() > 100);
    CHECK(f["fpga_chain"]["time_ordered_parts"].get<long>() == 0);
    // As accurate as whole fields (measured on this recording: 3D 21.0 vs 22.5 um, tip 29.6 vs 31.4 um, eye
    // 0.0149 vs 0.0131 deg); the bounds allow 30 %. A filter moved back and forth in time by out-of-order parts,
    // charged with process noise at each step, lost 33-52 % on a 2 s sweep (seed 21).
    for (const char* k : {"marker3d_all_rms_um", "tip_rms_um", "eye_rot_rms_deg"}) {
        INFO(k << ": per field " << f[k] << ", per blob " << b[k]);
        REQUIRE(b[k].is_number());
        CHECK(b[k].get<double>() > 0.0);
        CHECK(b[k].get<double>() < 1.3 * f[k].get<double>());
    }
}

TEST_CASE("validate --sync async --emit blob: fixed-lag frames 19 ms after exposure, smoothed by the parts since",
          "[host][validate]") {
    // The default: each reference field's frame is reported once the clock is 19 ms past its exposure (before the
    // field's own readout ends, 21.8 ms), its poses smoothed by the other cameras' parts exposed after it. On a 1 s
    // `fast` recording (seed 9) against the frames given at once from each part (--report-delay-ms 0).
    const fs::path d = recording("fast", 1, 9);
    const nlohmann::json l = validate_dir_json(d, "async", " --emit blob");
    const nlohmann::json z = validate_dir_json(d, "async", " --emit blob --report-delay-ms 0");
    CHECK(l["report_delay_ms"] == 19.0);
    const nlohmann::json &lc = l["fpga_chain"], &zc = z["fpga_chain"];
    INFO("fixed lag: " << l.dump() << "\nat once: " << z.dump());
    // One frame per reference field (50 in 1 s), each from a body pose smoothed by later parts.
    CHECK(lc["frames"].get<int>() == 50);
    CHECK(zc["frames"].get<int>() > 400);
    CHECK(lc["smoothed_poses"].get<long>() > 100);
    CHECK(zc["smoothed_poses"].get<long>() == 0);
    // The latency targets: p50 <= 21 ms, p99 <= 25 ms (measured 19.0 / 21.9 ms: a frame goes when it falls
    // due, not with the next part; at once 14.0 / 17.8), plus the tracking stage's compute, measured on this
    // machine (a sanitizer build's is ten times a release build's).
    const double compute = lc["tracking_compute_us"]["p99"].get<double>();
    CHECK(l["exposure_to_pose_us"]["p50"].get<double>() > 18900.0);
    CHECK(l["exposure_to_pose_us"]["p50"].get<double>() < 19500.0 + compute);
    CHECK(l["exposure_to_pose_us"]["p99"].get<double>() < 25000.0 + compute);
    // Measured: 3D over all markers 42.2 -> 27.3 um, tip 70.8 -> 57.6 um, eye 0.0414 -> 0.0320 deg; instrument
    // frames held 6 of 2 x 50 (at once 34 of 2 x 559; the first three of each instrument are its acquisition).
    CHECK(l["marker3d_all_rms_um"].get<double>() < 0.75 * z["marker3d_all_rms_um"].get<double>());
    CHECK(l["tip_rms_um"].get<double>() < 0.9 * z["tip_rms_um"].get<double>());
    CHECK(l["eye_rot_rms_deg"].get<double>() < 0.85 * z["eye_rot_rms_deg"].get<double>());
}

TEST_CASE("validate --sync async: the motion-model mixture holds the eye near a three-view fit per frame, without "
          "its wait", "[host][validate]") {
    // Each body's filter mixes a steady, a middle and an agile motion model: on a sweep (slow strokes, the eye
    // sprung) the steady one carries most of the weight and averages the centroid noise over many fields, where
    // interpolation fits each frame on its own from three views, a field later. Measured on this recording with the
    // markers' image model: eye 0.0073 deg against 0.0063, 3D over all markers 4.7 against 6.9 um, tip 7.0 against
    // 6.0 um (before it, 0.0132 against 0.0141 deg, 21.4 against 21.0 um, 31.2 against 30.6 um; one agile filter:
    // 0.0305 deg).
    const nlohmann::json a = validate_json("async");
    const nlohmann::json i = validate_json("interpolate");
    INFO("async: eye " << a["eye_rot_rms_deg"] << " deg, 3D all " << a["marker3d_all_rms_um"] << " um, tip "
                       << a["tip_rms_um"] << " um; interpolate: " << i["eye_rot_rms_deg"] << ", "
                       << i["marker3d_all_rms_um"] << ", " << i["tip_rms_um"]);
    CHECK(a["eye_rot_rms_deg"].get<double>() < 0.0085);
    CHECK(a["eye_rot_rms_deg"].get<double>() < 1.25 * i["eye_rot_rms_deg"].get<double>());
    CHECK(a["marker3d_all_rms_um"].get<double>() < 1.3 * i["marker3d_all_rms_um"].get<double>());
    CHECK(a["marker3d_all_rms_um"].get<double>() < 9.0);
    CHECK(a["tip_rms_um"].get<double>() < 1.35 * i["tip_rms_um"].get<double>());
}

TEST_CASE("validate --sync async: images the eye partly hides are fused, moved back by the eye's model",
          "[host][validate]") {
    // At the eye's outline the eye hides part of a marker (its own markers at the limb, instrument markers seen past
    // it) and the centroid is the visible part's. The filters left such an image out by its blob area; now each one
    // the eye's outline crosses at the predicted pose is moved back by the shaded sphere less the eye (and the
    // shaft), its sigma grown with the shift, and fused. Measured on this recording with per-blob parts (in time
    // order; the eye's steady model with its acceleration): 246 images so corrected, eye 0.0146 deg, 3D over all
    // markers 19.8 um, tip 29.2 um; left out by area, 0.0162 deg, 21.0 um, 29.6 um.
    const nlohmann::json j = validate_json("async", " --emit blob");
    for (const char* chain : {"fpga_chain", "truth_centroids"}) {
        INFO(chain);
        CHECK(j[chain]["eye_model_views"].get<long>() > 100);
    }
    const nlohmann::json& c = j["fpga_chain"];
    INFO(c.dump());
    CHECK(c["eye_rot_rms_deg"].get<double>() < 0.0154);
    CHECK(c["marker3d_all_rms_um"].get<double>() < 20.5);
    CHECK(c["tip_rms_um"].get<double>() < 30.5);
    // Interpolation corrects the same views in its triangulation and counts them too.
    CHECK(validate_json("interpolate")["fpga_chain"]["eye_model_views"].get<long>() > 100);
}

TEST_CASE("validate: each marker view moved back by its image at the pose, its shaft's and the field lines' parts "
          "included", "[host][validate]") {
    // The centroid of a marker's image is not its centre's projection: the shaft hides a strip of an instrument
    // marker (tenths of a pixel along it), and the shading and the field's lines two frame rows apart move every
    // marker by hundredths, the last alternating with the field parity. The tracker moved instrument markers back by
    // a uniform disc less the strip and left clear eye markers as they were (--no-image-model); now by the shaded
    // sphere less the shaft sampled on the field's lines, at the pose. Measured on this recording: with parts
    // (--sync async --emit blob) eye 0.0120 -> 0.0073 deg, tip 28.2 -> 6.0 um, 3D over all markers 18.0 -> 2.9 um;
    // interpolated 0.0132 -> 0.0063 deg, 30.2 -> 6.0 um, 20.0 -> 6.9 um.
    for (const char* mode : {"async --emit blob", "interpolate"}) {
        INFO(mode);
        const nlohmann::json on = validate_json(mode);
        const nlohmann::json off = validate_json(mode, " --no-image-model");
        CHECK(on["marker_image_model"].get<bool>());
        CHECK_FALSE(off["marker_image_model"].get<bool>());
        INFO("eye " << on["eye_rot_rms_deg"] << " deg (off " << off["eye_rot_rms_deg"] << "), tip " << on["tip_rms_um"]
                    << " um (" << off["tip_rms_um"] << "), 3D all " << on["marker3d_all_rms_um"] << " um ("
                    << off["marker3d_all_rms_um"] << ")");
        CHECK(on["eye_rot_rms_deg"].get<double>() < 0.0085);
        CHECK(on["tip_rms_um"].get<double>() < 9.0);
        CHECK(on["marker3d_all_rms_um"].get<double>() < 9.0);
        CHECK(on["eye_rot_rms_deg"].get<double>() < 0.75 * off["eye_rot_rms_deg"].get<double>());
        CHECK(on["tip_rms_um"].get<double>() < 0.4 * off["tip_rms_um"].get<double>());
        CHECK(on["marker3d_all_rms_um"].get<double>() < 0.5 * off["marker3d_all_rms_um"].get<double>());
        // Every frame still scored: nothing was left out to get there.
        CHECK(on["fpga_chain"]["frames"].get<long>() == off["fpga_chain"]["frames"].get<long>());
        CHECK(on["fpga_chain"]["marker3d_all_um"]["count"].get<long>() >=
              0.98 * off["fpga_chain"]["marker3d_all_um"]["count"].get<long>());
    }
}

TEST_CASE("validate --sync async: the pose predicted to the next field beats the pose held, on fast motion",
          "[host][validate]") {
    // A 1 s `fast` recording (seed 9, not one the prediction was looked at on): the filters' velocities, shrunk by
    // their uncertainty, carry the pose 20 ms ahead; measured on seeds 3-8: tip 305-630 um predicted vs 826-1221
    // held, eye 0.14-0.20 deg vs 0.67-0.95.
    const fs::path d = recording("fast", 1, 9);
    const nlohmann::json p = validate_dir_json(d, "async")["display_prediction"];
    INFO(p.dump());
    CHECK(p["horizon_us"] == 20000.0);  // the next reference field, 20 ms on
    CHECK(p["frames"].get<int>() > 40);
    CHECK(p["tip_rms_um"].get<double>() < 0.7 * p["held_tip_rms_um"].get<double>());
    CHECK(p["eye_rot_rms_deg"].get<double>() < 0.7 * p["held_eye_rot_rms_deg"].get<double>());
    // No filter to predict with: the figures are null, never 0.
    const nlohmann::json q = validate_dir_json(d, "interpolate")["display_prediction"];
    CHECK(q["horizon_us"].is_null());
    CHECK(q["tip_rms_um"].is_null());
    CHECK(q["frames"] == 0);
}

TEST_CASE("validate --sync async: an instrument that one camera alone still sees is held, not measured",
          "[host][validate]") {
    // A 2 s `occlusion` recording (seed 22): the injection cannula is pulled out and pushed back at up to 0.6 m/s
    // while its markers leave the other cameras' views. Camera 0 looks nearly along its shaft and keeps finding two
    // markers that fit the drifting filter; before a field needed another camera's support, the filter reported
    // the tip 26 mm off as measured (tip RMS 3.8 mm, 3D 439 um; interpolation 238 um and 61 um).
    const nlohmann::json j = validate_dir_json(recording("occlusion", 2, 22), "async");
    const nlohmann::json& c = j["fpga_chain"];
    INFO(j.dump());
    // Measured 219 um and 101 um (2026-12-06: 191 um and 51 um, the instrument a camera suddenly loses held);
    // the frames it could not support are counted as not measured.
    CHECK(j["tip_rms_um"].get<double>() < 400.0);
    CHECK(j["marker3d_all_rms_um"].get<double>() < 200.0);
    CHECK(c["instrument_not_measured_frames"]["injection"].get<int>() >= 5);
    CHECK(c["frames"].get<int>() == 100);
}

TEST_CASE("validate --sync async --emit blob: an instrument pulled out faster than the gate is held, not reported "
          "where it was",
          "[host][validate]") {
    // A 2 s `occlusion` recording (seed 76): at 0.6 s the injection cannula is pulled out of the eye, from 4 mm/s
    // to 0.85 m/s within three fields. The field after the pull began, its filter still put it where the cameras
    // had last seen it, 13 ms before, and reported that as measured: 1.5 mm off (tip RMS 119 um, 3D 74 um). Now the
    // camera whose field before showed it and whose field now shows none of its markers holds it.
    const nlohmann::json j = validate_dir_json(recording("occlusion", 2, 76), "async", " --emit blob --report-delay-ms 0");
    const nlohmann::json& c = j["fpga_chain"];
    INFO(j.dump());
    // Measured 21.9 um and 15.6 um, the injection not measured in 443 of 988 frames (434 before: it is out of
    // the eye and out of view for most of the recording).
    CHECK(j["tip_rms_um"].get<double>() < 40.0);
    CHECK(j["marker3d_all_rms_um"].get<double>() < 30.0);
    CHECK(c["tip_um"]["max"].get<double>() < 400.0);
    CHECK(c["instrument_not_measured_frames"]["injection"].get<int>() < 500);
    CHECK(c["frames"].get<int>() > 900);
}

TEST_CASE("validate --sync async --emit blob: an instrument whose filter is unsure is held, not reported drifting",
          "[host][validate]") {
    // A 2 s `occlusion` recording (seed 77): the injection cannula, 52 mm out of the eye (no trocar line), is
    // pushed back in at 1.3 s at up to 0.85 m/s. In the field after the push began the filter, still counted as
    // supported, put it 1.5 mm off with its position σ above 0.15 mm (tip RMS 109 um, 3D 70 um).
    const nlohmann::json j = validate_dir_json(recording("occlusion", 2, 77), "async", " --emit blob --report-delay-ms 0");
    const nlohmann::json& c = j["fpga_chain"];
    INFO(j.dump());
    // Measured 33.4 um and 18.3 um, 143 instrument frames not measured of 2 x 1026 (131 before).
    CHECK(j["tip_rms_um"].get<double>() < 60.0);
    CHECK(j["marker3d_all_rms_um"].get<double>() < 35.0);
    CHECK(instrument_frames_held(c) < 250);
}

TEST_CASE("validate --sync async --emit blob: an instrument the readout has passed without finding it is held from "
          "that part on", "[host][validate]") {
    // A 2 s `occlusion` recording (seed 79): the injection cannula is pushed into the eye at 1.3 s at up to 0.85 m/s.
    // Camera 0's field after the push began showed none of its markers, but that was decided at the field's last
    // part: the six parts before it reported the prediction from the field before as measured, 1.6 mm off (tip RMS
    // 148 um, 3D 92 um). Now each part decides it over the markers the readout has passed.
    const nlohmann::json j = validate_dir_json(recording("occlusion", 2, 79), "async", " --emit blob --report-delay-ms 0");
    const nlohmann::json& c = j["fpga_chain"];
    INFO(j.dump());
    // Measured 83.8 um and 44.6 um (the pull-out at 0.6 s keeps three parts 1.4 mm off: its markers were below
    // the readout), 122 instrument frames not measured of 2 x 982 (102 before).
    CHECK(j["tip_rms_um"].get<double>() < 110.0);
    CHECK(j["marker3d_all_rms_um"].get<double>() < 65.0);
    CHECK(instrument_frames_held(c) < 150);
    CHECK(c["frames"].get<int>() > 900);
}

TEST_CASE("validate --sync async --emit blob: an instrument only one camera gives two markers is held",
          "[host][validate]") {
    // A 2 s `occlusion` recording (seed 171): from 0.84 s the injection cannula, pulled out of the eye, gives camera
    // 2 three markers, camera 0 one and camera 1 none. It counted as supported (another camera saw a marker) and its
    // filter, sure to 0.10-0.13 mm, put the tip 0.4-0.9 mm off for 0.2 s (tip RMS 145 um, 3D 35.7 um). Now an
    // instrument needs two cameras with two of its markers each within a field period.
    const nlohmann::json j = validate_dir_json(recording("occlusion", 2, 171), "async", " --emit blob --report-delay-ms 0");
    const nlohmann::json& c = j["fpga_chain"];
    INFO(j.dump());
    // Measured 50.7 um and 19.6 um, 301 instrument frames not measured of 2 x 884 (189 before).
    CHECK(j["tip_rms_um"].get<double>() < 90.0);
    CHECK(j["marker3d_all_rms_um"].get<double>() < 28.0);
    CHECK(c["tip_um"]["max"].get<double>() < 800.0);
    CHECK(instrument_frames_held(c) < 400);
    CHECK(c["frames"].get<int>() > 800);
}

TEST_CASE("validate --sync async --emit blob: an instrument re-found by one fit is held until its filter starts",
          "[host][validate]") {
    // A 2 s `occlusion` recording (seed 180): the injection cannula, lost while it was pulled out of the eye, is
    // re-found at 0.72 s by a fit of the cameras' fields extrapolated to one time while it still moves fast; that
    // first fit was reported as measured, its markers 1.5-1.9 mm off (tip max 1.50 mm, 3D over all markers 39.5 um).
    // Now it is held until a second fit in a row starts the filter.
    const nlohmann::json j = validate_dir_json(recording("occlusion", 2, 180), "async", " --emit blob --report-delay-ms 0");
    const nlohmann::json& c = j["fpga_chain"];
    INFO(j.dump());
    // Measured: tip max 567 um (the cannula out of the eye, 0.3-0.5 mm off in two views), 3D 28.4 um, 232
    // instrument frames not measured of 2 x 975 (228 before).
    CHECK(c["tip_um"]["max"].get<double>() < 1000.0);
    CHECK(j["marker3d_all_rms_um"].get<double>() < 34.0);
    CHECK(instrument_frames_held(c) < 300);
    CHECK(c["frames"].get<int>() > 900);
}

TEST_CASE("validate --sync async: after a camera's miss an instrument needs another camera's images since the miss",
          "[host][validate]") {
    // A 2 s `occlusion` recording (seed 269): at 0.61 s the injection cannula starts out of the eye along its
    // shaft, 1.7 mm within a field. Camera 2's field rejected all three of its images; camera 0's, which looks
    // nearly along that motion, then fitted the prediction 1.5 mm behind, and with camera 1's images from before the
    // miss as the second view the frame was reported measured (tip max 1.53 mm, tip RMS 127 um, 3D 81 um). Now
    // after a miss only images of another camera since the miss count as the second view.
    const nlohmann::json j = validate_dir_json(recording("occlusion", 2, 269), "async");
    const nlohmann::json& c = j["fpga_chain"];
    INFO(j.dump());
    // Measured: tip max 46 um, tip RMS 25.8 um (all of it inside the eye), 3D 17.3 um, 48 instrument frames not
    // measured of 2 x 100 (47 before).
    CHECK(c["tip_um"]["max"].get<double>() < 200.0);
    CHECK(c["tip_in_eye_rms_um"].get<double>() < 40.0);
    CHECK(j["marker3d_all_rms_um"].get<double>() < 30.0);
    CHECK(instrument_frames_held(c) < 60);
    CHECK(c["frames"].get<int>() == 100);
}

TEST_CASE("validate --sync async --emit blob --refine: a field whose images the filter partly refuses is a miss",
          "[host][validate]") {
    // A 2 s `occlusion` recording (seed 275), refined centroids: at 1.3 s the injection cannula is pushed back into
    // the eye at up to 0.85 m/s. Camera 0's field at its onset gave three of its images inside the gate; the filter
    // refused one and took two, which pulled it part of the way, and the frame went out measured 1.05 mm behind
    // (tip max 1.07 mm, tip RMS 91.6 um, 3D 57.7 um). Now such a field is a miss and supports nothing.
    const nlohmann::json j = validate_dir_json(recording("occlusion", 2, 275), "async", " --emit blob --refine");
    const nlohmann::json& c = j["fpga_chain"];
    INFO(j.dump());
    // Measured: tip max 218 um (the cannula out of the eye), tip RMS 44.0 um, 3D 24.8 um (max 221 um), 23
    // instrument frames not measured of 2 x 100 (22 before).
    CHECK(c["tip_um"]["max"].get<double>() < 500.0);
    CHECK(j["tip_rms_um"].get<double>() < 60.0);
    CHECK(j["marker3d_all_rms_um"].get<double>() < 35.0);
    CHECK(instrument_frames_held(c) < 35);
    CHECK(c["frames"].get<int>() == 100);
}

TEST_CASE("validate on a genlocked rig: every mode uses each camera's field of the frame's time", "[host][validate]") {
    // With every camera's field exposed at once, the reference camera's field arrives first and the others just
    // after it. Before, `--sync nearest` built each frame from the reference field alone (no marker matched, exit
    // 1), `extrapolate` carried the other cameras a whole field ahead, and `async` reported each frame before the
    // other cameras' fields of its time were in (with whole fields the light pipe held in 49 of 50 frames).
    const fs::path d = recording("sweep", 1, 3, true);  // `synth --synchronised`
    const nlohmann::json in = validate_dir_json(d, "interpolate");
    const double in_3d = in["marker3d_all_rms_um"].get<double>();
    for (const char* mode : {"nearest", "extrapolate"}) {
        const nlohmann::json j = validate_dir_json(d, mode);
        const nlohmann::json& m = j["fpga_chain"]["markers"];
        INFO(mode << ": " << j.dump() << "\ninterpolate: " << in.dump());
        // Measured: 683 of 700 markers, 3D 22.4 um, tip 34.3 um (interpolate, which needs no later field here:
        // 697, 22.4, 34.4); extrapolate before 36.8 / 57.5 um.
        CHECK(m["found"].get<int>() >= 0.95 * m["truth_visible_in_2_cameras"].get<int>());
        CHECK(j["marker3d_all_rms_um"].get<double>() < 1.05 * in_3d);
        CHECK(j["tip_rms_um"].get<double>() < 40.0);
        // The fields' readout plus the tracking stage's compute (a sanitizer build's is ten times a release build's).
        const double compute = j["fpga_chain"]["tracking_compute_us"]["p50"].get<double>();
        CHECK(j["exposure_to_pose_us"]["p50"].get<double>() < 23000.0 + compute);
    }
    for (const char* emit : {"field", "blob"}) {
        const nlohmann::json j = validate_dir_json(d, "async", std::string(" --emit ") + emit);
        const nlohmann::json& c = j["fpga_chain"];
        INFO("async --emit " << emit << ": " << j.dump());
        // Measured: light pipe and pick held in 2 and 2 frames of 50 (before: whole fields 49 and 3, parts 4 and 4),
        // 3D 18.6 um, tip 28.6 um (35.6 / 31.7), eye 0.0093 deg; the frame waits for its fields: p50 21.8-21.9 ms.
        CHECK(c["instrument_not_measured_frames"]["light_pipe"].get<int>() <= 5);
        CHECK(j["tip_rms_um"].get<double>() < 35.0);
        CHECK(j["eye_rot_rms_deg"].get<double>() < 0.011);  // before 0.0136 / 0.0125
        CHECK(j["marker3d_all_rms_um"].get<double>() < in_3d);
        // Plus the tracking stage's compute, measured on this machine (a sanitizer build's is ten times a release
        // build's).
        const double compute = c["tracking_compute_us"]["p99"].get<double>();
        CHECK(j["exposure_to_pose_us"]["p50"].get<double>() > 21000.0);
        CHECK(j["exposure_to_pose_us"]["p99"].get<double>() < 23000.0 + compute);
    }
}

TEST_CASE("validate --sync with an unknown mode is a usage error", "[host][validate]") {
    const Result r = run_eyesim("validate --recording " + sweep().string() + " --sync later --json");
    CHECK(r.rc == 2);
    CHECK(r.out.empty());
    CHECK(r.err.find("--sync") != std::string::npos);
}
