// `eyesim bench latency`: the latency regression harness (see eyesim/app/latency_bench.hpp and docs/benchmarks.md).
#include "eyesim/app/command.hpp"
#include "eyesim/app/latency_bench.hpp"

#include <nlohmann/json.hpp>

#include <cstdio>
#include <fstream>
#include <memory>

namespace {

struct BenchOptions {
    eyesim::app::LatencyBenchOptions bench;
    std::string baseline;
    std::string write_baseline;
    double tolerance = 0.3;
    bool json = false;
};

int run_latency(const BenchOptions& o) {
    using eyesim::app::Error;
    nlohmann::json baseline;
    if (!o.baseline.empty()) {
        std::ifstream in(o.baseline);
        if (!in) throw Error(o.baseline + ": cannot open baseline");
        try {
            in >> baseline;
        } catch (const nlohmann::json::exception&) {
            throw Error(o.baseline + ": not valid JSON");
        }
    }
    const nlohmann::json j = eyesim::app::run_latency_bench(o.bench);
    std::vector<std::string> regressions;
    if (!o.baseline.empty()) regressions = eyesim::app::latency_regressions(j, baseline, o.tolerance);
    if (!o.write_baseline.empty()) {
        std::ofstream out(o.write_baseline);
        if (!out) throw Error(o.write_baseline + ": cannot write");
        out << j.dump(2) << "\n";
    }
    if (o.json) {
        nlohmann::json r = j;
        r["regressions"] = regressions;
        r["tolerance"] = o.tolerance;
        std::printf("%s\n", r.dump().c_str());
    } else {
        std::printf("calibration workload: %.1f µs (spread %.2f)\n", j["calibration_us"].get<double>(),
                    j["calibration_spread"].get<double>());
        std::printf("%-20s %12s %12s %12s %12s %12s %8s\n", "scene", "tracking p50", "collision p50", "tissue p50",
                    "compute p50", "compute p99", "ratio");
        for (const auto& [name, s] : j["scenes"].items())
            std::printf("%-20s %10.1fµs %11.1fµs %10.1fµs %10.1fµs %10.1fµs %8.2f\n", name.c_str(),
                        s["tracking"]["p50_us"].get<double>(), s["collision"]["p50_us"].get<double>(),
                        s["tissue"]["p50_us"].get<double>(), s["host_compute"]["p50_us"].get<double>(),
                        s["host_compute"]["p99_us"].get<double>(), s["ratio"].get<double>());
        for (const auto& r : regressions) std::printf("REGRESSION %s\n", r.c_str());
        if (!o.baseline.empty() && regressions.empty())
            std::printf("no regression beyond %.0f %% against %s\n", o.tolerance * 100, o.baseline.c_str());
    }
    return regressions.empty() ? 0 : 3;
}

eyesim::app::Registrar reg{"bench", "Benchmarks: `bench latency` is the frame-budget regression harness", [](CLI::App& sub) {
    auto o = std::make_shared<BenchOptions>();
    sub.require_subcommand(1);
    CLI::App* lat = sub.add_subcommand("latency", "Per-stage frame times of fixed scenes, as ratios to a calibration "
                                                  "workload; non-zero exit (3) on a regression against --baseline");
    lat->add_option("--baseline", o->baseline, "baseline JSON to compare with (e.g. bench/latency-baseline.json)");
    lat->add_option("--write-baseline", o->write_baseline, "write this run as a new baseline");
    lat->add_option("--tolerance", o->tolerance, "allowed growth of a scene's ratio (0.3 = 30 %)")
        ->capture_default_str()->check(eyesim::app::finite_in(0.0, 10.0));
    lat->add_option("--scene", o->bench.scenes, "scene files (default: the four shipped scenes)");
    lat->add_option("--seconds", o->bench.seconds, "simulated seconds per scene")->capture_default_str()
        ->check(eyesim::app::finite_in(0.2, 60.0));
    lat->add_option("--repeats", o->bench.repeats, "runs per scene (median kept)")->capture_default_str()
        ->check(CLI::Range(1, 50));
    lat->add_option("--inject-collision-us", o->bench.inject_collision_us,
                    "fault injection: busy time added to every collision stage (to test the harness)")
        ->check(eyesim::app::finite_in(0.0, 1e6));
    lat->add_flag("--json", o->json, "one JSON object on stdout");
    return [o]() -> int { return run_latency(*o); };
}};

}  // namespace
