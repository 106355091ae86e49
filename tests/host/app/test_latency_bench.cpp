// The latency gate must flag a 30 % slowdown and must not cry wolf on an unchanged run.
#include "eyesim/app/latency_bench.hpp"

#include <catch2/catch.hpp>

#include <string>

using namespace eyesim::app;

namespace {
// The smallest scene (tracking and collision only, ≈ 33 µs a frame) and one with tissue.
LatencyBenchOptions small() {
    LatencyBenchOptions o;
    o.scenes = {std::string(EYESIM_SCENES_DIR) + "/abstract-shadow.json",
                std::string(EYESIM_SCENES_DIR) + "/retina-relocation.json"};
    o.seconds = 2.0;
    o.repeats = 20;
    return o;
}

const LatencyComparison& row(const std::vector<LatencyComparison>& rows, const std::string& scene,
                             const std::string& stage) {
    for (const auto& r : rows)
        if (r.scene == scene && r.stage == stage) return r;
    FAIL("no row " << scene << " " << stage);
    return rows.front();
}
}  // namespace

TEST_CASE("the latency harness reports every stage as a ratio to its calibration kernel", "[bench][latency]") {
    const nlohmann::json j = run_latency_bench(small());
    for (const char* k : {"dense", "geometry", "springs"}) REQUIRE(j["calibration"][k]["us"].get<double>() > 0.0);
    const auto& s = j["scenes"]["retina-relocation"];
    CHECK(s["frames"].get<int>() >= 95);
    CHECK(s["passes"].get<int>() == 20);
    double sum = 0;
    for (const char* st : {"tracking", "collision", "tissue"}) {
        const double us = s[st]["us"].get<double>();
        CHECK(us > 0.0);
        const std::string kernel = s[st]["calibration"].get<std::string>();
        CHECK(s[st]["ratio"].get<double>() == Approx(us / j["calibration"][kernel]["us"].get<double>()));
        sum += us;
    }
    CHECK(s["host_compute"]["us"].get<double>() == Approx(sum));
    const double kernels = j["calibration"]["dense"]["us"].get<double>() +
                           j["calibration"]["geometry"]["us"].get<double>() +
                           j["calibration"]["springs"]["us"].get<double>();
    CHECK(s["ratio"].get<double>() == Approx(sum / kernels));
    // abstract-shadow runs no tissue code.
    CHECK(j["scenes"]["abstract-shadow"]["tissue"]["us"].get<double>() == 0.0);
}

#if defined(__SANITIZE_ADDRESS__)
constexpr bool kSanitized = true;
#else
constexpr bool kSanitized = false;
#endif

// Real timings on a shared machine: in the `stress` label (scripts/test.sh --stress), not in the default unit run.
// It passes alone (3 of 3 on 2026-12-02) but failed in CI with nothing else running (tracking +17-18 % in both
// scenes on unchanged code), and once before beside sanitizer builds. The gate's logic is asserted
// deterministically below, on made-up measurements.
TEST_CASE("the latency gate passes an unchanged run and flags a 30 % slowdown", "[bench][latency][stress]") {
    const nlohmann::json base = run_latency_bench(small());
    const double tol = 0.15;  // the gate's defaults: 15 %, 3 measurements at most

    // Same code again, against its own baseline.
    const LatencyGateResult same = run_latency_gate(small(), base, tol, 3);
    CHECK(same.regressions.empty());
    for (const auto& r : same.rows)
        if (r.gated) {
            INFO(r.scene << " " << r.stage << " " << r.change());
            CHECK(r.change() < tol);  // no growth the gate would flag (a run that happened to be faster is fine)
        }

    // The baseline for the slowed run: the less disturbed of the two clean measurements (interference only adds
    // time, and a baseline measured while the machine was busy would hide part of the slowdown).
    auto stage_ratios = [](const nlohmann::json& j) {
        double sum = 0;
        for (const auto& [name, sc] : j["scenes"].items())
            for (const char* st : {"tracking", "collision", "tissue"}) sum += sc[st]["ratio"].get<double>();
        return sum;
    };
    const bool same_whole = same.attempts == 1;  // measured every scene once, no stage replaced by a later attempt
    const nlohmann::json& ref = same_whole && stage_ratios(same.current) < stage_ratios(base) ? same.current : base;

    // Every frame 30 % slower: busy time in the collision stage equal to 30 % of the frame's host compute.
    LatencyBenchOptions slow = small();
    slow.inject_slowdown = 0.3;
    const LatencyGateResult g = run_latency_gate(slow, ref, tol, 3);
    CHECK(g.attempts == 3);  // flagged in every measurement
    for (const char* scene : {"abstract-shadow", "retina-relocation"}) {
        const auto& hc = row(g.rows, scene, "host_compute");
        INFO(scene << " host compute " << hc.change());
        CHECK(hc.regression);
        CHECK(hc.change() > 0.2);
        // Upper bound loose: on a shared 2-core machine the slowed passes run minutes after the baseline and
        // may see a slower machine on top of the injected 30 %.
        CHECK(hc.change() < 0.6);
        // Under AddressSanitizer the stages' shares move (instrumentation slows some code more than other), so
        // a stage may fall below the 10 % share that gates it: there only host compute is asserted.
        // Since the markers' image model (2026-12-08) tracking takes ≈ 0.42 of the 0.47–0.57 ms frames, and
        // collision may fall below that share: asserted where it is gated.
        const auto& col = row(g.rows, scene, "collision");
        if (!kSanitized && col.gated) CHECK(col.regression);
        CHECK_FALSE(row(g.rows, scene, "tracking").regression);
    }
    // Host compute of both scenes (and collision where gated); a stage that merely shared a slower machine
    // (tissue) may be flagged too, tracking (asserted above) never.
    if (!kSanitized) REQUIRE(g.regressions.size() >= 2);
    REQUIRE(!g.regressions.empty());
    CHECK(g.regressions[0].find("abstract-shadow host_compute") == 0);
}

TEST_CASE("the gate measures a scene with a regression again and keeps each stage's lower ratio",
          "[bench][latency]") {
    auto scene = [](double tracking_ratio) {
        auto st = [](double ratio, const char* k) {
            return nlohmann::json{{"us", ratio * 10.0}, {"ratio", ratio}, {"calibration", k}, {"p50_us", 0.0},
                                  {"p99_us", 0.0}};
        };
        return nlohmann::json{{"tracking", st(tracking_ratio, "geometry")}, {"collision", st(0.5, "dense")},
                              {"tissue", st(1.0, "springs")}, {"geometry_transfer", st(0.0, "dense")},
                              {"misc", st(0.0, "geometry")}};
    };
    auto run = [&](double a_tracking, double b_tracking) {
        nlohmann::json j;
        j["calibration"] = {{"dense", {{"us", 10.0}}}, {"geometry", {{"us", 10.0}}}, {"springs", {{"us", 10.0}}}};
        j["scenes"]["a"] = scene(a_tracking);
        j["scenes"]["a"]["file"] = "a.json";
        j["scenes"]["b"] = scene(b_tracking);
        j["scenes"]["b"]["file"] = "b.json";
        return j;
    };
    const nlohmann::json base = run(1.0, 1.0);
    // A disturbed first measurement of scene a (+50 % tracking), a clean second one: passes after two.
    std::vector<std::vector<std::string>> asked;
    int calls = 0;
    auto flaky = [&](const LatencyBenchOptions& o) {
        asked.push_back(o.scenes);
        return ++calls == 1 ? run(1.5, 1.02) : run(1.01, 9.0);
    };
    LatencyGateResult g = run_latency_gate(LatencyBenchOptions{}, base, 0.15, 3, flaky);
    CHECK(g.regressions.empty());
    CHECK(g.attempts == 2);
    REQUIRE(asked.size() == 2);
    CHECK(asked[1] == std::vector<std::string>{"a.json"});  // only the scene with a regression
    CHECK(g.current["scenes"]["a"]["tracking"]["ratio"].get<double>() == Approx(1.01));
    CHECK(g.current["scenes"]["b"]["tracking"]["ratio"].get<double>() == Approx(1.02));  // b was not measured again
    // A slowdown in every measurement fails after all of them.
    calls = 0;
    auto slow = [&](const LatencyBenchOptions&) {
        ++calls;
        return run(1.4, 1.0);
    };
    g = run_latency_gate(LatencyBenchOptions{}, base, 0.15, 3, slow);
    CHECK(calls == 3);
    CHECK(g.attempts == 3);
    CHECK(g.regressions.size() == 2);  // a's host compute and tracking
}

TEST_CASE("the gate weighs a stage's change by its share of host compute and gates large stages only",
          "[bench][latency]") {
    // Kernel times 10 / 20 / 40 µs; baseline stages 20 µs tracking (geometry), 2 µs collision (dense),
    // 78 µs tissue (springs): host compute 100 µs.
    auto run = [](double tracking_us, double collision_us, double tissue_us, double scale) {
        nlohmann::json j;
        j["calibration"] = {{"dense", {{"us", 10.0 * scale}}},
                            {"geometry", {{"us", 20.0 * scale}}},
                            {"springs", {{"us", 40.0 * scale}}}};
        auto st = [&](double us, const char* k, double kernel) {
            return nlohmann::json{{"us", us * scale}, {"ratio", us / kernel}, {"calibration", k}};
        };
        j["scenes"]["s"] = {{"tracking", st(tracking_us, "geometry", 20.0)},
                            {"collision", st(collision_us, "dense", 10.0)},
                            {"tissue", st(tissue_us, "springs", 40.0)}};
        return j;
    };
    const nlohmann::json base = run(20, 2, 78, 1.0);
    // A machine twice as slow, same code: no change anywhere.
    for (const auto& r : compare_latency(run(20, 2, 78, 2.0), base, 0.15)) CHECK(r.change() == Approx(0.0));
    // Tracking +50 %: host compute +10 % (its 20 % share), tracking itself flagged.
    auto rows = compare_latency(run(30, 2, 78, 1.0), base, 0.15);
    CHECK(row(rows, "s", "host_compute").change() == Approx(0.10));
    CHECK_FALSE(row(rows, "s", "host_compute").regression);
    CHECK(row(rows, "s", "tracking").regression);
    CHECK(row(rows, "s", "host_compute").current_us == Approx(110.0));
    // Collision (2 % of host compute) tripled: not gated on its own, host compute +4 %.
    rows = compare_latency(run(20, 6, 78, 1.0), base, 0.15);
    CHECK_FALSE(row(rows, "s", "collision").gated);
    CHECK(row(rows, "s", "host_compute").change() == Approx(0.04));
    CHECK(latency_regressions(run(20, 6, 78, 1.0), base, 0.15).empty());
    // Tissue +20 %: host compute +15.6 %, both flagged at 15 %.
    CHECK(latency_regressions(run(20, 2, 93.6, 1.0), base, 0.15).size() == 2);
}

TEST_CASE("a malformed or old baseline is a clear error", "[bench][latency]") {
    const nlohmann::json cur = {{"scenes", {{"a", {{"ratio", 1.0}}}}}};
    CHECK_THROWS_WITH(latency_regressions(cur, nlohmann::json::object(), 0.15),
                      Catch::Contains("baseline: scenes: missing"));
    // The previous harness's baseline had one ratio per scene.
    CHECK_THROWS_WITH(latency_regressions(cur, {{"scenes", {{"a", {{"ratio", 1.0}}}}}}, 0.15),
                      Catch::Contains("write a new one with --write-baseline"));
    // A baseline scene that was not measured is reported.
    CHECK(latency_regressions(cur, {{"scenes", {{"b", {{"ratio", 1.0}}}}}}, 0.15) ==
          std::vector<std::string>{"b: in the baseline but not measured"});
}
