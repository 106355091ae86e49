// `eyesim validate` on recordings that cannot be scored in full, through the program a user runs: a recording in
// which nothing is found is an error (exit 1), never a perfect score; cameras of different lengths, a truth file
// shorter than the streams and a body never measured are warnings (stderr and the JSON `warnings`); figures with
// nothing behind them are null in the JSON and "not measured" in the text, never 0.
#include "cli_run.hpp"

#include <catch2/catch.hpp>

#include <nlohmann/json.hpp>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;

constexpr std::uintmax_t kFieldBytes = 720 * 288 * 2;  // one UYVY field (rig/pal.hpp kFieldBytes)

using Result = eyesim::test::CliResult;
using eyesim::test::slurp;

std::vector<std::string> lines(const std::string& s) {
    std::vector<std::string> v;
    std::istringstream in(s);
    for (std::string l; std::getline(in, l);) v.push_back(l);
    return v;
}

/// The test's scratch folder, one per process, removed at exit.
const fs::path& scratch() {
    static const eyesim::test::ScratchDir dir("eyesim_test_validate_inputs");
    return dir.path();
}

/// Runs `eyesim args` (shell words) with a time limit; stdout and stderr apart.
Result run_eyesim(const std::string& args) { return eyesim::test::run_cli(scratch(), EYESIM_EXE, args, 120); }

/// A 10-field `static` recording named `name` (extra synth options in `extra`).
fs::path synth(const std::string& name, const std::string& extra = "") {
    const fs::path d = scratch() / name;
    const Result r = run_eyesim("synth --scenario static --seconds 0.2 --seed 3 --out " + d.string() + " " + extra);
    REQUIRE(r.rc == 0);
    REQUIRE(fs::file_size(d / "cam0.uyvy") == 10 * kFieldBytes);
    return d;
}

/// Every camera's fields overwritten with UYVY black (Y 16, Cb = Cr = 128).
void paint_black(const fs::path& rec) {
    for (int c = 0; c < 3; ++c) {
        const fs::path p = rec / ("cam" + std::to_string(c) + ".uyvy");
        const std::uintmax_t size = fs::file_size(p);
        std::string black(size, '\0');
        for (std::uintmax_t k = 0; k < size; k += 2) {
            black[k] = char(0x80);
            black[k + 1] = char(0x10);
        }
        std::ofstream(p, std::ios::binary | std::ios::trunc) << black;
        REQUIRE(fs::file_size(p) == size);
    }
}

/// Camera `cam`'s stream cut to its first `fields` fields (and the manifest made to say so).
void cut_camera(const fs::path& rec, int cam, int fields) {
    fs::resize_file(rec / ("cam" + std::to_string(cam) + ".uyvy"), std::uintmax_t(fields) * kFieldBytes);
    nlohmann::json m = nlohmann::json::parse(slurp(rec / "manifest.json"));
    m["cameras"][std::size_t(cam)]["fields"] = fields;
    std::ofstream(rec / "manifest.json", std::ios::trunc) << m.dump(1);
}

/// truth.jsonl cut to its first `keep` lines.
void cut_truth(const fs::path& rec, std::size_t keep) {
    std::vector<std::string> t = lines(slurp(rec / "truth.jsonl"));
    REQUIRE(t.size() > keep);
    std::ofstream out(rec / "truth.jsonl", std::ios::trunc);
    for (std::size_t i = 0; i < keep; ++i) out << t[i] << '\n';
}

/// A marker bodies file whose eye markers sit deep inside the (opaque) eye: rendered, never seen.
fs::path hidden_eye_bodies() {
    nlohmann::json b = nlohmann::json::parse(slurp(fs::path(EYESIM_SOURCE_DIR) / "scenes/bodies.json"));
    for (auto& m : b["eye"]["markers"])
        for (auto& x : m["position_eye_mm"]) x = 0.3 * x.get<double>();
    const fs::path p = scratch() / "hidden_eye_bodies.json";
    std::ofstream(p, std::ios::trunc) << b.dump(1);
    return p;
}

std::vector<std::string> warning_lines(const std::string& err) {
    std::vector<std::string> w;
    for (const std::string& l : lines(err)) {
        INFO(l);
        CHECK(l.rfind("eyesim: warning: ", 0) == 0);  // nothing else on stderr
        w.push_back(l.substr(17));
    }
    return w;
}

}  // namespace

TEST_CASE("validate: a recording in which nothing is found is an error, not a perfect score", "[host][validate]") {
    const fs::path rec = synth("black");
    paint_black(rec);
    for (const char* json : {"", " --json"}) {
        const Result r = run_eyesim("validate --recording " + rec.string() + json);
        INFO("rc " << r.rc << ", stderr: " << r.err << "stdout: " << r.out);
        CHECK(r.rc == 1);
        CHECK(r.out.empty());
        REQUIRE(lines(r.err).size() == 1);
        CHECK(r.err.rfind("eyesim: error: " + rec.string() + ": no marker found in 10 fields", 0) == 0);
        CHECK(r.err.find("no blob") != std::string::npos);
    }
}

TEST_CASE("validate: cameras of different lengths and a short truth are warnings naming what was used",
          "[host][validate]") {
    const fs::path rec = synth("short");
    cut_camera(rec, 1, 7);
    cut_truth(rec, 5);

    const Result r = run_eyesim("validate --recording " + rec.string() + " --json");
    INFO("rc " << r.rc << ", stderr: " << r.err);
    REQUIRE(r.rc == 0);
    const std::vector<std::string> w = warning_lines(r.err);
    REQUIRE(w.size() == 2);
    CHECK(w[0] == rec.string() + ": cameras of different lengths (cam0 10 fields, cam1 7 fields, cam2 10 fields): "
                                 "only the first 7 fields of each camera are used");
    CHECK(w[1] == (rec / "truth.jsonl").string() +
                      ": truth for 5 fields, the streams have 7: the last 2 fields are not scored");
    const nlohmann::json j = nlohmann::json::parse(r.out);
    CHECK(j["warnings"] == nlohmann::json(w));
    CHECK(j["fields"] == 5);
    CHECK(j["fpga_chain"]["frames"].get<int>() <= 5);
    CHECK(j["marker3d_rms_um"].get<double>() > 0.0);
    CHECK(j["eye_rot_rms_deg"].get<double>() > 0.0);

    // Text: the same warnings on stderr, none on stdout.
    const Result t = run_eyesim("validate --recording " + rec.string());
    REQUIRE(t.rc == 0);
    CHECK(warning_lines(t.err) == w);
    CHECK(t.out.find("warning") == std::string::npos);
    CHECK(t.out.find(" 5 fields x 3 cameras") != std::string::npos);

    // Fewer fields asked for than every stream and the truth hold: nothing was cut, nothing to warn about.
    const Result few = run_eyesim("validate --recording " + rec.string() + " --max-fields 4 --json");
    REQUIRE(few.rc == 0);
    CHECK(few.err.empty());
    CHECK(nlohmann::json::parse(few.out)["warnings"] == nlohmann::json::array());
}

TEST_CASE("validate: a body never measured is a warning and its figures are null, not 0", "[host][validate]") {
    const fs::path rec = synth("hidden_eye", "--bodies " + hidden_eye_bodies().string());

    const Result r = run_eyesim("validate --recording " + rec.string() + " --json");
    INFO("rc " << r.rc << ", stderr: " << r.err);
    REQUIRE(r.rc == 0);
    const std::vector<std::string> w = warning_lines(r.err);
    REQUIRE(w.size() == 1);
    CHECK(w[0] == rec.string() + ": eye not measured in any of the 10 scored frames (FPGA chain; from truth "
                                 "centroids in 0): its figures are not measured");
    const nlohmann::json j = nlohmann::json::parse(r.out);
    CHECK(j["warnings"] == nlohmann::json(w));
    // The instruments were found and scored ...
    CHECK(j["marker3d_rms_um"].get<double>() > 0.0);
    CHECK(j["tip_rms_um"].get<double>() > 0.0);
    CHECK(j["fpga_chain"]["marker3d_instrument_um"]["count"].get<int>() > 0);
    // ... the eye was not: null, with a count of 0, in both chains.
    CHECK(j["eye_rot_rms_deg"].is_null());
    for (const char* chain : {"fpga_chain", "truth_centroids"}) {
        INFO(chain);
        const nlohmann::json& c = j[chain];
        CHECK(c["eye_rot_rms_deg"].is_null());
        CHECK(c["eye_rot_deg"]["count"] == 0);
        for (const char* k : {"rms", "mean", "p50", "p95", "p99", "max"}) CHECK(c["eye_rot_deg"][k].is_null());
        CHECK(c["marker3d_eye_um"]["count"] == 0);
        CHECK(c["marker3d_eye_um"]["rms"].is_null());
        CHECK(c["eye_not_measured_frames"] == c["frames"]);
    }

    const Result t = run_eyesim("validate --recording " + rec.string());
    REQUIRE(t.rc == 0);
    CHECK(warning_lines(t.err) == w);
    const std::vector<std::string> out = lines(t.out);
    const auto chain = std::find_if(out.begin(), out.end(),
                                    [](const std::string& l) { return l.find("FPGA chain") != std::string::npos; });
    REQUIRE(chain != out.end());
    INFO(*chain);
    CHECK(chain->find("eye RMS not measured") != std::string::npos);
    CHECK(chain->find("tip RMS not measured") == std::string::npos);
    CHECK(t.out.find("0.0000 deg") == std::string::npos);
}

TEST_CASE("validate: a complete recording has no warnings and every figure measured", "[host][validate]") {
    const fs::path rec = synth("complete");
    const Result r = run_eyesim("validate --recording " + rec.string() + " --json");
    REQUIRE(r.rc == 0);
    CHECK(r.err.empty());
    const nlohmann::json j = nlohmann::json::parse(r.out);
    CHECK(j["warnings"] == nlohmann::json::array());
    for (const char* k : {"centroid_rms_px", "marker3d_rms_um", "tip_rms_um", "eye_rot_rms_deg"}) {
        INFO(k);
        REQUIRE(j[k].is_number());
        CHECK(j[k].get<double>() > 0.0);
    }
}
