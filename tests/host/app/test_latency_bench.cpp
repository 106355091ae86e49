// The latency harness must detect a slowdown and must not cry wolf on an unchanged run.
#include "eyesim/app/latency_bench.hpp"

#include <catch2/catch.hpp>

using namespace eyesim::app;

namespace {
LatencyBenchOptions small() {
    LatencyBenchOptions o;
    o.scenes = {std::string(EYESIM_SCENES_DIR) + "/membrane-peel.json"};
    o.seconds = 0.6;
    o.repeats = 5;
    return o;
}
}  // namespace

TEST_CASE("the latency harness reports every stage as a ratio to the calibration workload", "[bench][latency]") {
    const nlohmann::json j = run_latency_bench(small());
    REQUIRE(j["calibration_us"].get<double>() > 0.0);
    const auto& s = j["scenes"]["membrane-peel"];
    CHECK(s["frames"].get<int>() >= 25);
    CHECK(s["tracking"]["p50_us"].get<double>() > 0.0);
    CHECK(s["collision"]["p50_us"].get<double>() > 0.0);
    CHECK(s["tissue"]["p50_us"].get<double>() > 0.0);
    CHECK(s["ratio"].get<double>() ==
          Approx(s["host_compute"]["p50_us"].get<double>() / j["calibration_us"].get<double>()));
}

TEST_CASE("the latency harness detects an injected slowdown and passes an unchanged run", "[bench][latency]") {
    const nlohmann::json base = run_latency_bench(small());
    const double compute_us = base["scenes"]["membrane-peel"]["host_compute"]["p50_us"].get<double>();
    // Same code again: a generous tolerance absorbs machine noise.
    CHECK(latency_regressions(run_latency_bench(small()), base, 1.0).empty());
    // Collision made slower by 3× the whole frame's compute time: must be flagged even at that tolerance.
    LatencyBenchOptions slow = small();
    slow.inject_collision_us = 3.0 * compute_us + 200.0;
    const auto regressions = latency_regressions(run_latency_bench(slow), base, 1.0);
    REQUIRE(regressions.size() == 1);
    CHECK(regressions[0].find("membrane-peel") == 0);
}

TEST_CASE("a malformed baseline is a clear error", "[bench][latency]") {
    const nlohmann::json cur = {{"scenes", {{"a", {{"ratio", 1.0}}}}}};
    CHECK_THROWS_WITH(latency_regressions(cur, nlohmann::json::object(), 0.3),
                      Catch::Contains("baseline: scenes: missing"));
    CHECK_THROWS_WITH(latency_regressions(cur, {{"scenes", {{"a", {{"ratio", "x"}}}}}}, 0.3),
                      Catch::Contains("baseline: scenes.a.ratio: missing"));
    CHECK(latency_regressions(cur, {{"scenes", {{"b", {{"ratio", 1.0}}}}}}, 0.3).size() == 1);
}
