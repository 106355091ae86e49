// `eyesim fpga --refine` on recorded video, through the program a user runs: the fields before the hint tracker's
// first pose (two on the rig) are fitted with the poses a look ahead finds, so their partly hidden markers are as
// accurate as the later fields' (without it about 6× worse on this recording). Scored from its CSV against the rig's truth.
#include "cli_run.hpp"

#include "eyesim/rig/match.hpp"
#include "eyesim/rig/truth.hpp"

#include <catch2/catch.hpp>

#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace {

namespace fs = std::filesystem;
namespace rig = eyesim::rig;

using Result = eyesim::test::CliResult;

const fs::path& scratch() {
    static const eyesim::test::ScratchDir dir("eyesim_test_fpga_refine");
    return dir.path();
}

Result run_eyesim(const std::string& args) { return eyesim::test::run_cli(scratch(), EYESIM_EXE, args, 300); }

// The CSV's blobs as detections, by (camera, field).
std::map<std::pair<int, int>, std::vector<rig::DetectedMarker>> read_blobs(const fs::path& csv) {
    std::map<std::pair<int, int>, std::vector<rig::DetectedMarker>> out;
    std::ifstream in(csv);
    std::string line;
    std::getline(in, line);  // header
    while (std::getline(in, line)) {
        std::stringstream ss(line);
        std::string cell;
        std::vector<double> v;
        while (std::getline(ss, cell, ',') && v.size() < 7) v.push_back(std::stod(cell));
        REQUIRE(v.size() == 7);  // camera, field, parity, index, class, cx, cy
        out[{static_cast<int>(v[0]), static_cast<int>(v[1])}].push_back(
            {static_cast<int>(v[4]), Eigen::Vector2d(v[5], v[6])});
    }
    return out;
}

// The CSV as rows of named cells.
std::vector<std::map<std::string, std::string>> read_rows(const fs::path& csv) {
    std::ifstream in(csv);
    std::string line, cell;
    std::getline(in, line);
    std::vector<std::string> names;
    for (std::stringstream ss(line); std::getline(ss, cell, ',');) names.push_back(cell);
    std::vector<std::map<std::string, std::string>> rows;
    while (std::getline(in, line)) {
        std::map<std::string, std::string> row;
        std::stringstream ss(line);
        for (const std::string& name : names) {
            cell.clear();
            std::getline(ss, cell, ',');
            row[name] = cell;
        }
        rows.push_back(std::move(row));
    }
    return rows;
}

struct Sums {
    double se = 0;
    int n = 0;
    double rms() const { return n ? std::sqrt(se / n) : 0.0; }
};

}  // namespace

TEST_CASE("fpga --refine: the first fields' partly hidden markers are fitted with the poses a look ahead finds",
          "[app][refine][rig]") {
    // DVCPRO25 (4:1:1): where a partly hidden marker's pipeline centroid is furthest off and its fit needs the hint.
    const fs::path rec = scratch() / "sweep_dv411";
    Result r = run_eyesim("synth --scenario sweep --seconds 0.4 --seed 3 --format dv411 --out " + rec.string());
    INFO(r.err);
    REQUIRE(r.rc == 0);
    const fs::path csv = scratch() / "blobs.csv";
    r = run_eyesim("fpga --recording " + rec.string() + " --refine --json --csv " + csv.string());
    INFO(r.err);
    REQUIRE(r.rc == 0);
    const nlohmann::json j = nlohmann::json::parse(r.out);
    REQUIRE(j.at("fields").get<int>() == 60);
    REQUIRE(j.at("hinted_fits").get<int>() > 0);

    const std::vector<rig::FieldTruth> truth = rig::read_truth((rec / "truth.jsonl").string());
    REQUIRE(truth.size() == 20);
    const auto blobs = read_blobs(csv);
    Sums first, later;  // partly hidden markers of fields 0–1 and of fields 2–19
    std::vector<bool> used;
    for (int f = 0; f < 20; ++f)
        for (int cam = 0; cam < 3; ++cam) {
            const auto it = blobs.find({cam, f});
            if (it == blobs.end()) continue;
            rig::match_markers(
                truth[static_cast<size_t>(f)], cam, std::span<const rig::DetectedMarker>(it->second), 3.0,
                [](const rig::MarkerTruth&, const rig::MarkerCameraTruth& v) {
                    return v.visible && v.area_px >= 2.0 && v.occluded_fraction > 0.0;
                },
                [&](const rig::MarkerMatch& m) {
                    if (m.detection < 0) return;
                    const double se = (it->second[static_cast<size_t>(m.detection)].centroid_px -
                                       m.view->centroid_px).squaredNorm();
                    Sums& s = f < 2 ? first : later;
                    s.se += se;
                    ++s.n;
                },
                used);
        }
    INFO("fields 0-1: " << first.n << " markers, RMS " << first.rms() << " px; fields 2-19: " << later.n
                        << " markers, RMS " << later.rms() << " px");
    REQUIRE(first.n >= 40);
    REQUIRE(later.n >= 300);
    CHECK(later.rms() < 0.05);
    // Without the look ahead the first two fields were fitted plain: 0.139 px against 0.024 on this recording.
    CHECK(first.rms() < 1.5 * later.rms());

    SECTION("the CSV names each blob's refinement outcome and, against the truth, its marker and error") {
        const auto rows = read_rows(csv);
        REQUIRE(rows.size() == j.at("blobs").get<size_t>());
        std::map<std::string, int64_t> outcomes;
        for (const auto& row : rows) ++outcomes[row.at("refine")];
        CHECK(outcomes["fitted"] + outcomes["hinted"] == j.at("refined").get<int64_t>());
        for (const auto& [why, n] : j.at("refused").items()) CHECK(outcomes[why] == n.get<int64_t>());
        CHECK(outcomes["hinted"] > 0);
        // Each matched blob's error, recomputed from the truth: the marker of its class whose rendered centroid
        // the blob's is within 3 px of, and the error the CSV states.
        int64_t matched = 0;
        double se = 0;
        for (const auto& row : rows) {
            if (row.at("truth_body").empty()) continue;
            ++matched;
            const auto& ft = truth[static_cast<size_t>(std::stoi(row.at("field")))];
            const int cam = std::stoi(row.at("camera")), id = std::stoi(row.at("truth_marker"));
            const Eigen::Vector2d c(std::stod(row.at("x_px")), std::stod(row.at("y_px")));
            const Eigen::Vector2d e(std::stod(row.at("error_x_px")), std::stod(row.at("error_y_px")));
            bool found = false;
            for (const rig::MarkerTruth& m : ft.markers)
                if (m.body == row.at("truth_body") && m.id == id) {
                    const rig::MarkerCameraTruth& v = m.cams[static_cast<size_t>(cam)];
                    CHECK(m.colour_class == std::stoi(row.at("class")));
                    CHECK((c - v.centroid_px - e).norm() < 3e-6);
                    CHECK(std::fabs(v.occluded_fraction - std::stod(row.at("occluded_fraction"))) < 1e-4);
                    found = true;
                }
            CHECK(found);
            se += e.squaredNorm();
        }
        // Every matched blob is in the CSV with its error: their RMS is the summary's.
        CHECK(matched == j.at("cameras")[0].at("matched").get<int64_t>() + j.at("cameras")[1].at("matched").get<int64_t>() +
                             j.at("cameras")[2].at("matched").get<int64_t>());
        CHECK(std::sqrt(se / static_cast<double>(matched)) == Approx(j.at("centroid_rms_px").get<double>()).epsilon(1e-4));
    }
}
