// `eyesim bench latency`: the latency regression harness (see eyesim/app/latency_bench.hpp and docs/benchmarks.md).
#include "eyesim/app/command.hpp"
#include "eyesim/app/frame_loop.hpp"
#include "eyesim/app/latency_bench.hpp"

#include <nlohmann/json.hpp>

#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

extern char** environ;

namespace {

struct BenchOptions {
    eyesim::app::LatencyBenchOptions bench;
    std::string baseline;
    std::string write_baseline;
    double tolerance = 0.15;
    int attempts = 3;
    bool no_heap_shuffle = false;
    bool json = false;
};

/// `eyesim bench latency --json` on the given options in a fresh process (its own heap and pages), its output.
nlohmann::json measure_in_fresh_process(const eyesim::app::LatencyBenchOptions& o) {
    using eyesim::app::Error;
    char self[PATH_MAX];
    const ssize_t n = readlink("/proc/self/exe", self, sizeof self - 1);
    if (n <= 0) throw Error("bench latency: cannot find this program (/proc/self/exe) to measure again");
    self[n] = '\0';
    auto num = [](double v) {
        char b[40];
        std::snprintf(b, sizeof b, "%.17g", v);
        return std::string(b);
    };
    std::vector<std::string> args{self, "bench", "latency", "--json", "--seconds", num(o.seconds), "--repeats",
                                  std::to_string(o.repeats)};
    if (o.inject_collision_us > 0) args.insert(args.end(), {"--inject-collision-us", num(o.inject_collision_us)});
    if (o.inject_slowdown > 0) args.insert(args.end(), {"--inject-slowdown", num(o.inject_slowdown)});
    if (!o.shuffle_heap) args.push_back("--no-heap-shuffle");
    for (const auto& s : o.scenes) args.insert(args.end(), {"--scene", s});
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);

    int fd[2];
    if (pipe(fd) != 0) throw Error(std::string("bench latency: pipe: ") + std::strerror(errno));
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_adddup2(&fa, fd[1], STDOUT_FILENO);
    posix_spawn_file_actions_addclose(&fa, fd[0]);
    posix_spawn_file_actions_addclose(&fa, fd[1]);
    pid_t pid = 0;
    const int rc = posix_spawn(&pid, self, &fa, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&fa);
    close(fd[1]);
    if (rc != 0) {
        close(fd[0]);
        throw Error(std::string("bench latency: cannot start a measurement: ") + std::strerror(rc));
    }
    std::string out;
    char buf[65536];
    for (ssize_t k; (k = read(fd[0], buf, sizeof buf)) != 0;) {
        if (k < 0) {
            if (errno == EINTR) continue;
            break;
        }
        out.append(buf, size_t(k));
    }
    close(fd[0]);
    int status = 0;
    while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
    }
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
        throw Error("bench latency: the repeated measurement failed");
    try {
        return nlohmann::json::parse(out);
    } catch (const nlohmann::json::exception&) {
        throw Error("bench latency: the repeated measurement printed no JSON");
    }
}

std::string change_text(const eyesim::app::LatencyComparison& r) {
    const double c = r.change();
    if (std::isinf(c)) return "new";
    char b[32];
    std::snprintf(b, sizeof b, "%+.1f %%", c * 100.0);
    return b;
}

double host_now() { return eyesim::app::host_now_us(); }

int run_latency(const BenchOptions& o) {
    using eyesim::app::Error;
    const double t0 = host_now();
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
    nlohmann::json j;
    std::vector<eyesim::app::LatencyComparison> rows;
    std::vector<std::string> regressions;
    int attempts = 1;
    if (o.baseline.empty()) {
        j = eyesim::app::run_latency_bench(o.bench);
    } else {
        // The first measurement here, any repeat in a fresh process.
        int made = 0;
        auto measure = [&made](const eyesim::app::LatencyBenchOptions& b) {
            return made++ == 0 ? eyesim::app::run_latency_bench(b) : measure_in_fresh_process(b);
        };
        try {
            eyesim::app::LatencyGateResult g =
                eyesim::app::run_latency_gate(o.bench, baseline, o.tolerance, o.attempts, measure);
            j = std::move(g.current);
            rows = std::move(g.rows);
            regressions = std::move(g.regressions);
            attempts = g.attempts;
        } catch (const Error& e) {
            throw Error(o.baseline + ": " + e.what());
        }
    }
    if (!o.write_baseline.empty()) {
        std::ofstream out(o.write_baseline);
        if (!out) throw Error(o.write_baseline + ": cannot write");
        // Each scene's file is where this checkout keeps it (the gate measures a flagged scene again from the
        // current run's path, never the baseline's): a committed baseline names its scenes only.
        nlohmann::json base = j;
        for (auto& [name, sc] : base["scenes"].items()) sc.erase("file");
        out << base.dump(2) << "\n";
    }
    if (o.json) {
        nlohmann::json r = j;
        r["regressions"] = regressions;
        r["tolerance"] = o.tolerance;
        r["attempts"] = attempts;
        nlohmann::json cmp = nlohmann::json::array();
        for (const auto& c : rows)
            cmp.push_back({{"scene", c.scene},
                           {"stage", c.stage},
                           {"ratio", c.current_ratio},
                           {"baseline_ratio", c.baseline_ratio},
                           {"us_at_baseline_speed", c.current_us},
                           {"baseline_us", c.baseline_us},
                           {"change", std::isinf(c.change()) ? nlohmann::json(nullptr) : nlohmann::json(c.change())},
                           {"gated", c.gated},
                           {"regression", c.regression}});
        r["comparison"] = cmp;
        std::printf("%s\n", r.dump().c_str());
        return regressions.empty() ? 0 : 3;
    }
    std::printf("calibration kernels (fastest run):");
    for (const auto& [k, v] : j["calibration"].items()) std::printf(" %s %.2f µs", k.c_str(), v["us"].get<double>());
    std::printf("; %d passes per scene, %.1f s wall\n", j["repeats"].get<int>(), j["wall_s"].get<double>());
    if (j["inject_slowdown"].get<double>() > 0 || j["inject_collision_us"].get<double>() > 0)
        std::printf("fault injection in the collision stage: work of %.0f %% of each frame's host compute, busy wait "
                    "%.1f µs\n",
                    j["inject_slowdown"].get<double>() * 100.0, j["inject_collision_us"].get<double>());
    std::printf("%-18s %-17s %9s %9s %9s %-9s %9s", "scene", "stage", "µs", "p50 µs", "p99 µs", "kernel", "ratio");
    if (!o.baseline.empty()) std::printf(" %9s %9s %9s  %s", "baseline", "change", "base µs", "gate");
    std::printf("\n");
    for (const auto& [name, s] : j["scenes"].items()) {
        for (const char* st : {"host_compute", "tracking", "collision", "tissue", "geometry_transfer", "misc"}) {
            const auto& x = s[st];
            const eyesim::app::LatencyComparison* cmp = nullptr;
            for (const auto& r : rows)
                if (r.scene == name && r.stage == st) cmp = &r;
            // Against a baseline, host compute's ratio weighs the stages with the baseline's kernel times.
            std::printf("%-18s %-17s %9.2f %9.2f %9.2f %-9s %9.5f", name.c_str(), st, x["us"].get<double>(),
                        x["p50_us"].get<double>(), x["p99_us"].get<double>(),
                        x.contains("calibration") ? x["calibration"].get<std::string>().c_str() : "all",
                        cmp ? cmp->current_ratio : x["ratio"].get<double>());
            if (cmp)
                std::printf(" %9.5f %9s %9.2f  %s", cmp->baseline_ratio, change_text(*cmp).c_str(), cmp->baseline_us,
                            cmp->regression ? "REGRESSION" : cmp->gated ? "ok" : "(not gated)");
            std::printf("\n");
        }
    }
    for (const auto& r : regressions) std::printf("REGRESSION %s\n", r.c_str());
    if (!o.baseline.empty()) {
        if (regressions.empty())
            std::printf("no regression beyond %.0f %% against %s\n", o.tolerance * 100, o.baseline.c_str());
        // One line for logs: the verdict, every scene's host compute change, the largest change of a gated row.
        std::string hc, flagged;
        const eyesim::app::LatencyComparison* top = nullptr;
        for (const auto& r : rows) {
            if (r.stage == "host_compute") hc += (hc.empty() ? "" : ", ") + r.scene + " " + change_text(r);
            if (r.gated && (!top || r.change() > top->change())) top = &r;
            if (r.regression && flagged.find(r.scene + ",") == std::string::npos) flagged += r.scene + ",";
        }
        const size_t n_flagged = size_t(std::count(flagged.begin(), flagged.end(), ','));
        std::printf("gate: %s; host compute %s; largest gated change %s (%s %s); %d measurement%s, %.1f s\n",
                    regressions.empty()
                        ? "pass"
                        : ("REGRESSION in " + std::to_string(n_flagged) + " of " +
                           std::to_string(j["scenes"].size()) + " scenes (exit 3)")
                              .c_str(),
                    hc.c_str(),
                    top ? change_text(*top).c_str() : "-", top ? top->scene.c_str() : "-",
                    top ? top->stage.c_str() : "-", attempts, attempts == 1 ? "" : "s",
                    (host_now() - t0) * 1e-6);
    }
    return regressions.empty() ? 0 : 3;
}

eyesim::app::Registrar reg{"bench", "Benchmarks: `bench latency` is the frame-budget regression harness", [](CLI::App& sub) {
    auto o = std::make_shared<BenchOptions>();
    sub.require_subcommand(1);
    CLI::App* lat = sub.add_subcommand("latency", "Per-stage frame times of fixed scenes, as ratios to calibration "
                                                  "kernels; non-zero exit (3) on a regression against --baseline");
    lat->add_option("--baseline", o->baseline, "baseline JSON to compare with (e.g. bench/latency-baseline.json)");
    lat->add_option("--write-baseline", o->write_baseline, "write this run as a new baseline");
    lat->add_option("--tolerance", o->tolerance,
                    "allowed growth of a gated ratio (host compute; a stage of at least 10 % of it), 0.15 = 15 %")
        ->capture_default_str()->check(eyesim::app::finite_in(0.0, 10.0));
    lat->add_option("--scene", o->bench.scenes, "scene files (default: the four shipped scenes)");
    lat->add_option("--seconds", o->bench.seconds, "simulated seconds per scene")->capture_default_str()
        ->check(eyesim::app::finite_in(0.2, 60.0));
    lat->add_option("--repeats", o->bench.repeats,
                    "passes per scene, round robin over the scenes; each frame's fastest pass is kept")
        ->capture_default_str()->check(CLI::Range(1, 500));
    lat->add_option("--inject-collision-us", o->bench.inject_collision_us,
                    "fault injection: busy time added to every collision stage (to test the gate)")
        ->check(eyesim::app::finite_in(0.0, 1e6));
    lat->add_option("--inject-slowdown", o->bench.inject_slowdown,
                    "fault injection: after the clean passes, as many again with real work in the collision stage "
                    "taking this fraction of each frame's clean host compute (0.3: 30 % slower); reports those")
        ->check(eyesim::app::finite_in(0.0, 10.0));
    lat->add_flag("--no-heap-shuffle", o->no_heap_shuffle,
                  "diagnosis: every pass of a scene at the same addresses (shows how much placement in memory moves "
                  "the figures)");
    lat->add_option("--attempts", o->attempts,
                    "measurements at most: a scene with a regression is measured again in a fresh process and each "
                    "stage keeps its lower ratio; the gate fails only on a regression in every one")
        ->capture_default_str()->check(CLI::Range(1, 10));
    lat->add_flag("--json", o->json, "one JSON object on stdout");
    return [o]() -> int {
        o->bench.shuffle_heap = !o->no_heap_shuffle;
        return run_latency(*o);
    };
}};

}  // namespace
