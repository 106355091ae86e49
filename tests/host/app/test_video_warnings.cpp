// A recording whose video a camera cut short: every program that reads it says which fields it lost, as it finds
// them, and one that is no video at all is an error. Through the programs a user runs.
#include "cli_run.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <random>
#include <string>

namespace fs = std::filesystem;
using eyesim::test::run_cli;
using eyesim::test::ScratchDir;

namespace {

const std::string kExe = EYESIM_EXE;
const std::string kDevice = EYESIM_DEVICE_EXE;

/// The warning line for the cut of camera 1 (fields from `first` on), as the programs print it.
bool names_the_cut(const std::string& err, const std::string& prefix) {
    const size_t at = err.find(prefix + ": warning: ");
    if (at == std::string::npos) return false;
    const std::string line = err.substr(at, err.find('\n', at) - at);
    return line.find("cam1.mkv: camera 1 (cam1) field ") != std::string::npos &&
           line.find("lost: the stream ends after") != std::string::npos;
}

}  // namespace

TEST_CASE("a cut video: fpga, validate, sim and eyesim-device print the lost fields, random bytes are an error",
          "[host][cli][video]") {
    ScratchDir scratch("eyesim_video_warnings");
    const fs::path rec = scratch.path() / "rec";
    auto r = run_cli(scratch.path(), kExe,
                     "synth --scenario sweep --seconds 0.4 --seed 3 --format ffv1 --out " + rec.string(), 120);
    REQUIRE(r.rc == 0);
    fs::remove(rec / "manifest.json");
    fs::resize_file(rec / "cam1.mkv", fs::file_size(rec / "cam1.mkv") / 2);

    r = run_cli(scratch.path(), kExe, "fpga --recording " + rec.string() + " --json", 120);
    INFO(r.err);
    CHECK(r.rc == 0);
    CHECK(names_the_cut(r.err, "eyesim"));
    const nlohmann::json j = nlohmann::json::parse(r.out);
    CHECK(j["lost_fields"].get<int>() > 0);
    CHECK(j["cameras"][1]["lost_fields"] == j["lost_fields"]);
    CHECK(j["cameras"][0]["lost_fields"] == 0);
    REQUIRE(j["warnings"].size() == 1);
    CHECK(j["warnings"][0].get<std::string>().find("camera 1 (cam1) field") != std::string::npos);

    r = run_cli(scratch.path(), kExe, "validate --recording " + rec.string() + " --json", 120);
    INFO(r.err);
    CHECK(r.rc == 0);
    CHECK(names_the_cut(r.err, "eyesim"));

    r = run_cli(scratch.path(), kExe,
                "sim --scene " + std::string(EYESIM_SOURCE_DIR) + "/scenes/vitrectomy.json --recording " + rec.string() +
                    " --json",
                120);
    INFO(r.err);
    CHECK(r.rc == 0);
    CHECK(names_the_cut(r.err, "eyesim"));

    r = run_cli(scratch.path(), kDevice, "--recording " + rec.string() + " --port 0 --free-run --linger-ms 0", 120);
    INFO(r.err);
    CHECK(names_the_cut(r.err, "eyesim-device"));

    // Not a video at all: one line naming the file, exit 1.
    {
        std::ofstream o(rec / "cam1.mkv", std::ios::binary | std::ios::trunc);
        std::mt19937 rng(5);
        for (int k = 0; k < 1 << 20; ++k) o.put(static_cast<char>(rng() & 0xff));
    }
    r = run_cli(scratch.path(), kExe, "fpga --recording " + rec.string(), 60);
    CHECK(r.rc == 1);
    CHECK(r.err.rfind("eyesim: error: ", 0) == 0);
    CHECK(r.err.find("cam1.mkv: ") != std::string::npos);
    CHECK(r.err.find('\n') == r.err.size() - 1);
}
