// `eyesim protocol decode` on every test vector of docs/protocol.md prints exactly the documented JSON lines,
// its --json summary carries the documented counters, and it exits 0 for clean vectors and 3 for damaged ones;
// lost frames (sequence gaps) exit 3, an empty or unreadable file is one error line and exit 1.
#include "doc_vectors.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <sys/wait.h>

using namespace eyesim::protocol::test;
namespace fs = std::filesystem;

namespace {

std::vector<std::string> lines_of(const fs::path& p) {
    std::ifstream f(p);
    std::vector<std::string> out;
    std::string line;
    while (std::getline(f, line))
        if (!line.empty()) out.push_back(line);
    return out;
}

}  // namespace

TEST_CASE("eyesim protocol decode prints what docs/protocol.md says for every vector", "[protocol][cli]") {
    const fs::path dir = fs::temp_directory_path() / "eyesim_protocol_cli_tests";
    fs::create_directories(dir);
    const auto vectors = doc_vectors(read_doc());
    REQUIRE(!vectors.empty());
    for (const auto& [name, v] : vectors) {
        INFO("vector " << name);
        const fs::path in = dir / (name + ".bin"), out = dir / (name + ".out"), err = dir / (name + ".err");
        {
            std::ofstream f(in, std::ios::binary);
            f.write(reinterpret_cast<const char*>(v.bytes.data()), static_cast<std::streamsize>(v.bytes.size()));
        }
        const std::string cmd = std::string("\"") + EYESIM_EXE + "\" protocol decode --json \"" + in.string() +
                                "\" > \"" + out.string() + "\" 2> \"" + err.string() + "\"";
        const int status = std::system(cmd.c_str());
        REQUIRE(WIFEXITED(status));
        const auto got = lines_of(out);
        REQUIRE(got.size() == v.expect.size());
        for (std::size_t i = 0; i < got.size(); ++i) CHECK(nlohmann::json::parse(got[i]) == nlohmann::json::parse(v.expect[i]));
        const auto summary_lines = lines_of(err);
        REQUIRE(summary_lines.size() == 1);
        const auto summary = nlohmann::json::parse(summary_lines[0]);
        const auto stats = nlohmann::json::parse(v.stats);
        CHECK(summary.at("parser") == stats);
        CHECK(summary.at("messages") == v.expect.size());
        const bool clean = stats.at("skipped_bytes") == 0 && summary.at("errors") == 0 && stats.at("sequence_gaps") == 0;
        CHECK(WEXITSTATUS(status) == (clean ? 0 : 3));
    }
}

namespace {

struct Run {
    int exit_code = -1;
    std::vector<std::string> out, err;
};

Run decode(const fs::path& in, bool json) {
    const fs::path out = in.string() + ".out", err = in.string() + ".err";
    const std::string cmd = std::string("\"") + EYESIM_EXE + "\" protocol decode " + (json ? "--json " : "") + "\"" +
                            in.string() + "\" > \"" + out.string() + "\" 2> \"" + err.string() + "\"";
    const int status = std::system(cmd.c_str());
    REQUIRE(WIFEXITED(status));
    return {WEXITSTATUS(status), lines_of(out), lines_of(err)};
}

void write_file(const fs::path& p, const std::vector<std::uint8_t>& bytes) {
    std::ofstream f(p, std::ios::binary | std::ios::trunc);
    f.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

}  // namespace

TEST_CASE("eyesim protocol decode: lost frames exit 3; empty, unreadable and unsupported files are errors",
          "[protocol][cli]") {
    const fs::path dir = fs::temp_directory_path() / "eyesim_protocol_cli_tests";
    fs::create_directories(dir);
    const auto vectors = doc_vectors(read_doc());

    // Two intact frames, sequence 3 then 7: every byte decodes, but three frames were lost in between.
    std::vector<std::uint8_t> gap = vectors.at("pedal-state").bytes;
    const auto& pong = vectors.at("reply-pong").bytes;
    gap.insert(gap.end(), pong.begin(), pong.end());
    const fs::path gap_file = dir / "gap.bin";
    write_file(gap_file, gap);
    for (const bool json : {true, false}) {
        INFO("json " << json);
        const Run r = decode(gap_file, json);
        CHECK(r.exit_code == 3);
        CHECK(r.out.size() == 2);
        REQUIRE(r.err.size() == 1);
        if (json) {
            const auto summary = nlohmann::json::parse(r.err[0]);
            CHECK(summary.at("parser").at("sequence_gaps") == 1);
            CHECK(summary.at("parser").at("skipped_bytes") == 0);
            CHECK(summary.at("errors") == 0);
        } else {
            CHECK(r.err[0].find("sequence_gaps 1") != std::string::npos);
        }
    }
    // The same frames without the gap exit 0.
    std::vector<std::uint8_t> no_gap = vectors.at("pedal-state").bytes;
    const auto& status = vectors.at("device-status").bytes;  // sequence 4
    no_gap.insert(no_gap.end(), status.begin(), status.end());
    write_file(dir / "no_gap.bin", no_gap);
    CHECK(decode(dir / "no_gap.bin", true).exit_code == 0);

    auto one_error = [&](const fs::path& file, const std::string& reason) {
        for (const bool json : {true, false}) {
            INFO(file << ", json " << json);
            const Run r = decode(file, json);
            CHECK(r.exit_code == 1);
            CHECK(r.out.empty());
            REQUIRE(r.err.size() == 1);
            CHECK(r.err[0] == "eyesim: error: " + file.string() + ": " + reason);
        }
    };
    // An empty file: nothing was received.
    write_file(dir / "empty.bin", {});
    one_error(dir / "empty.bin", "no bytes");
    // A capture of a format this build does not read names the version.
    std::vector<std::uint8_t> v7 = {'E', 'Y', 'E', 'S', 'I', 'M', 'C', 'P', 7, 0, 16, 0, 0, 0, 0, 0};
    v7.insert(v7.end(), gap.begin(), gap.end());
    write_file(dir / "v7.cap", v7);
    one_error(dir / "v7.cap", "capture format version 7 not supported (this build reads 1 to 2)");
    std::vector<std::uint8_t> h20 = {'E', 'Y', 'E', 'S', 'I', 'M', 'C', 'P', 1, 0, 20, 0, 0, 0, 0, 0};
    write_file(dir / "h20.cap", h20);
    one_error(dir / "h20.cap", "capture header size 20 not supported (this build reads 16)");
    fs::remove(dir / "missing.bin");
    one_error(dir / "missing.bin", "cannot open for reading: No such file or directory");
}
