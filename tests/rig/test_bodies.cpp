// Marker bodies: identifiability of the default layout and validation of bodies.json.
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/error.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <set>

using namespace eyesim::rig;
namespace fs = std::filesystem;

TEST_CASE("default bodies: every body identifiable from colour classes and their order", "[rig][bodies]") {
    const Bodies b = load_bodies(default_bodies_path());
    REQUIRE(b.instruments.size() == 5);
    std::set<std::vector<int>> sequences;
    for (const auto& ib : b.instruments) {
        REQUIRE(ib.markers.size() == 3);
        std::vector<int> seq;
        for (const auto& m : ib.markers) {
            seq.push_back(m.colour_class);
            CHECK(m.colour_class != 4);  // yellow is the eye's
        }
        // Distinct per kind, read from the tip; unequal gaps tell the tip end from the handle end.
        CHECK(sequences.insert(seq).second);
        const double g1 = ib.markers[1].distance_from_tip_mm - ib.markers[0].distance_from_tip_mm;
        const double g2 = ib.markers[2].distance_from_tip_mm - ib.markers[1].distance_from_tip_mm;
        CHECK(std::abs(g1 - g2) > 1.0);
        // Markers stay outside the eye at the deepest insertion.
        CHECK(ib.markers[0].distance_from_tip_mm - ib.max_insertion_mm > 2.0);
        CHECK(ib.markers[0].radius_mm > ib.shaft_radius_mm);
    }
    CHECK(b.instrument(InstrumentKind::kForceps).tip_offset_mm > 0);
    REQUIRE(b.eye.markers.size() >= 6);
    for (const auto& m : b.eye.markers) {
        CHECK(m.colour_class == 4);
        CHECK(m.position_eye_mm.norm() == Approx(b.eye.radius_mm + m.radius_mm).margin(1e-5));
        CHECK(m.position_eye_mm.z() < 0);  // on the lower, camera-facing half
    }
    // No two pairs of eye markers have the same angular separation: rotation is fixed without symmetry.
    std::set<long> separations;
    size_t pairs = 0;
    for (size_t i = 0; i < b.eye.markers.size(); ++i)
        for (size_t j = i + 1; j < b.eye.markers.size(); ++j) {
            const double d = (b.eye.markers[i].position_eye_mm - b.eye.markers[j].position_eye_mm).norm();
            separations.insert(std::lround(d * 20));  // 0.05 mm bins
            ++pairs;
        }
    CHECK(separations.size() > pairs / 2);
    REQUIRE(b.eye.trocars.size() == 2);
    for (const auto& t : b.eye.trocars) CHECK(t.position_eye_mm.norm() == Approx(b.eye.radius_mm).margin(1e-5));
    CHECK(marker_class_rgb(1) == std::array<uint8_t, 3>{220, 40, 40});
    CHECK(marker_class_rgb(4) == std::array<uint8_t, 3>{230, 210, 40});
}

TEST_CASE("the calibration wand: collinear markers of one class, unequal gaps, optional in the file", "[rig][bodies]") {
    const Bodies b = load_bodies(default_bodies_path());
    REQUIRE(b.wand.present());
    REQUIRE(b.wand.markers.size() == 3);
    CHECK(b.wand.markers[0].distance_mm == 0.0);
    CHECK(b.wand.length_mm() == 20.0);
    for (const auto& m : b.wand.markers) CHECK(m.colour_class == b.wand.markers[0].colour_class);
    // The end gaps differ by far more than the image's depth ratio can make up at the rig's distances.
    const double g1 = b.wand.markers[1].distance_mm, g2 = b.wand.markers[2].distance_mm - g1;
    CHECK(std::max(g1, g2) / std::min(g1, g2) > 1.4);
    CHECK(b.wand.marker_position_mm(2) == Eigen::Vector3d(0, 0, 20.0));

    std::ifstream in(default_bodies_path());
    nlohmann::json j = nlohmann::json::parse(in);
    j.erase("wand");
    const fs::path p = fs::temp_directory_path() / ("eyesim_test_bodies_wand_" + std::to_string(::getpid()) + ".json");
    std::ofstream(p) << j.dump();
    CHECK(!load_bodies(p.string()).wand.present());
    fs::remove(p);
}

TEST_CASE("malformed bodies.json gives one-line errors naming the JSON pointer", "[rig][bodies]") {
    std::ifstream in(default_bodies_path());
    const nlohmann::json good = nlohmann::json::parse(in);
    const fs::path p = fs::temp_directory_path() / ("eyesim_test_bodies_" + std::to_string(::getpid()) + ".json");
    auto expect = [&](const nlohmann::json& j, const std::string& needle) {
        std::ofstream(p) << j.dump();
        try {
            load_bodies(p.string());
            FAIL("no error, expected " << needle);
        } catch (const RigError& e) {
            INFO(e.what());
            CHECK(std::string(e.what()).find(needle) != std::string::npos);
        }
    };
    nlohmann::json j = good;
    j["instruments"][1]["markers"][2]["class"] = 5;
    expect(j, "/instruments/1/markers/2/class: must be 1..4");
    j = good;
    j["eye"].erase("radius_mm");
    expect(j, "/eye/radius_mm: missing");
    j = good;
    j["instruments"][0]["kind"] = "scalpel";
    expect(j, "unknown instrument kind 'scalpel'");
    j = good;
    j["eye"]["markers"][0]["position_eye_mm"] = {1.0, 2.0};
    expect(j, "/eye/markers/0/position_eye_mm: must be an array of 3 numbers");
    j = good;
    j["eye"]["radius_mm"] = 1e308;  // finite, but its square overflows
    expect(j, "/eye/radius_mm: out of range");
    j = good;
    j["eye"]["markers"][3]["position_eye_mm"][1] = -2e4;
    expect(j, "/eye/markers/3/position_eye_mm/1: out of range");
    j = good;
    j["eye"]["markers"] = nlohmann::json::array({j["eye"]["markers"][0], j["eye"]["markers"][1]});
    expect(j, "/eye/markers: needs at least 3 markers, has 2");
    j = good;
    j["instruments"][2]["markers"] = nlohmann::json::array({j["instruments"][2]["markers"][0]});
    expect(j, "/instruments/2/markers: needs at least 2 markers, has 1");
    j = good;
    j["wand"]["markers"][0]["distance_mm"] = 1.0;
    expect(j, "/wand/markers/0/distance_mm: must be 0 for marker 0");
    j = good;
    j["wand"]["markers"][2]["distance_mm"] = 8.0;
    expect(j, "/wand/markers/2/distance_mm: must exceed the previous marker's 8");
    j = good;
    j["wand"]["markers"] = nlohmann::json::array({j["wand"]["markers"][0]});
    expect(j, "/wand/markers: needs at least 2 markers, has 1");
    std::ofstream(p) << "{ not json";
    CHECK_THROWS_WITH(load_bodies(p.string()), Catch::Contains("malformed JSON"));
    fs::remove(p);
}
