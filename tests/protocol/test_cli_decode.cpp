// `eyesim protocol decode` on every test vector of docs/protocol.md prints exactly the documented JSON lines,
// its --json summary carries the documented counters, and it exits 0 for clean vectors and 3 for damaged ones.
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
        const bool clean = stats.at("skipped_bytes") == 0 && summary.at("errors") == 0;
        CHECK(WEXITSTATUS(status) == (clean ? 0 : 3));
    }
}
