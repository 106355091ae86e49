// `eyesim demo`: the main job. Synthesises a short `surgery` recording, starts `eyesim-device` serving it over
// TCP loopback, tracks it, runs the `membrane-peel` scene, prints the Table-4 breakdown beside the paper's, the
// tracking accuracy against truth and the events, and writes a report folder.
#include "eyesim/app/command.hpp"
#include "eyesim/app/run_scene.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/scenario.hpp"
#include "eyesim/tracking/async_fusion.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/sim/scenes/scene.hpp"

#include <fmt/format.h>

#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

extern char** environ;

namespace {

namespace fs = std::filesystem;
using eyesim::app::Error;

struct DemoOptions {
    std::string out = "eyesim-demo";
    std::string scene;
    std::string scenario;
    double seconds = 0.0;
    uint64_t seed = 1;
    bool json = false;
    bool precision = false;
    bool no_hints = false;
    std::string device;
    std::string sync = "async";
    double report_delay_ms = 19.0;
};

/// Finds `eyesim-device`: beside `eyesim`, in the build tree's firmware folder, or on PATH.
std::string find_device(const std::string& given) {
    if (!given.empty()) return given;
    const fs::path here = eyesim::app::executable_dir();
    for (const fs::path& p : {here / "eyesim-device", here / ".." / ".." / "firmware" / "eyesim-device"})
        if (fs::exists(p)) return fs::canonical(p).string();
    return "eyesim-device";  // PATH
}

/// The device as a child process; killed and reaped on destruction.
class DeviceChild {
public:
    DeviceChild(const std::string& exe, const std::string& recording, bool low_latency) {
        int fds[2];
        if (::pipe(fds) != 0) throw Error("cannot create a pipe for eyesim-device");
        posix_spawn_file_actions_t fa;
        posix_spawn_file_actions_init(&fa);
        posix_spawn_file_actions_adddup2(&fa, fds[1], STDOUT_FILENO);
        posix_spawn_file_actions_addclose(&fa, fds[0]);
        std::vector<std::string> args = {exe, "--recording", recording, "--port", "0", "--realtime", "--linger-ms", "3000"};
        if (low_latency) args.push_back("--low-latency");
        std::vector<char*> argv;
        for (auto& a : args) argv.push_back(a.data());
        argv.push_back(nullptr);
        const int rc = posix_spawnp(&pid_, exe.c_str(), &fa, nullptr, argv.data(), environ);
        posix_spawn_file_actions_destroy(&fa);
        ::close(fds[1]);
        if (rc != 0) {
            ::close(fds[0]);
            throw Error(exe + ": cannot start the device (" + std::strerror(rc) + "); build it with "
                        "`cmake --build --preset release --target eyesim-device`");
        }
        out_ = ::fdopen(fds[0], "r");
        char line[256];
        while (out_ && std::fgets(line, sizeof line, out_)) {
            unsigned port = 0;
            if (std::sscanf(line, "listening tcp://%*[^:]:%u", &port) == 1) {
                uri_ = fmt::format("tcp://127.0.0.1:{}", port);
                return;
            }
        }
        throw Error(exe + ": the device exited before listening");
    }
    ~DeviceChild() {
        if (pid_ > 0) {
            int status = 0;
            if (::waitpid(pid_, &status, WNOHANG) == 0) {
                ::kill(pid_, SIGTERM);
                ::waitpid(pid_, &status, 0);
            }
        }
        if (out_) std::fclose(out_);
    }
    DeviceChild(const DeviceChild&) = delete;
    DeviceChild& operator=(const DeviceChild&) = delete;
    const std::string& uri() const { return uri_; }

private:
    pid_t pid_ = -1;
    std::FILE* out_ = nullptr;
    std::string uri_;
};

int run_demo(const DemoOptions& opt) {
    const bool progress = eyesim::app::show_progress(opt.json);
    const std::string rec_dir = opt.out + "/recording";
    const std::string report_dir = opt.out + "/report";
    const std::string scene = opt.scene.empty() ? std::string(EYESIM_SCENES_DIR) + "/membrane-peel.json" : opt.scene;

    // 0. The scene first: a bad scene file fails before anything is synthesised or started.
    eyesim::sim::scenes::Scene sc;
    try {
        sc = eyesim::sim::scenes::load_scene(scene);
    } catch (const eyesim::sim::scenes::SceneError& e) {
        throw Error(e.what());
    }
    const std::string scenario = opt.scenario.empty() ? sc.scenario : opt.scenario;
    const double seconds = opt.seconds > 0 ? opt.seconds : sc.duration_s;

    // 1. The synthetic surgeon performs the scene's procedure on the rig (three PAL cameras, noise on, truth).
    eyesim::rig::SynthRequest sreq;
    sreq.out_dir = rec_dir;
    sreq.scenario = scenario;
    sreq.seconds = seconds;
    sreq.seed = opt.seed;
    if (progress)
        std::fprintf(stderr, "demo: synthesising %.1f s of '%s' (three-camera PAL fields) into %s\n", seconds,
                     scenario.c_str(), rec_dir.c_str());
    try {
        eyesim::rig::write_recording(sreq, [&](int64_t done, int64_t total) {
            if (progress && (done % 25 == 0 || done == total)) std::fprintf(stderr, "\r  field %lld/%lld", (long long)done, (long long)total);
        });
    } catch (const eyesim::rig::RigError& e) {
        throw Error(e.what());
    }
    if (progress) std::fprintf(stderr, "\n");

    // 2. The simulated device serving it over TCP loopback, at PAL pace.
    // Asynchronous fusion takes each blob as the device sends it: the device in its per-blob (low-latency) mode.
    const bool low_latency = opt.sync == "async" && !opt.precision;
    DeviceChild device(find_device(opt.device), rec_dir, low_latency);
    if (progress) std::fprintf(stderr, "demo: eyesim-device listening on %s; tracking and simulating\n", device.uri().c_str());

    // 3. Track, simulate, report.
    eyesim::app::SceneRunRequest req;
    req.scene_path = scene;
    req.source.connect = device.uri();
    req.rig_path = rec_dir + "/rig.yaml";
    req.truth_path = rec_dir + "/truth.jsonl";
    req.seconds = seconds + 10.0;  // a time-out only: the device closes the link at the end of the recording
    req.expected_s = seconds;
    req.report_dir = report_dir;
    req.snapshots = 3;
    req.json = opt.json;
    req.precision = opt.precision;
    req.no_hints = opt.no_hints;
    req.sync = opt.sync;
    req.report_delay_ms = opt.report_delay_ms;
    req.title = "eyesim demo: " + fs::path(scene).stem().string() + " on a live device (synthetic surgeon '" +
                scenario + "')";
    return eyesim::app::run_scene(req);
}

eyesim::app::Registrar reg{
    "demo", "The main job: a synthetic surgeon peels a membrane → device over TCP → tracking → simulation, with a report",
    [](CLI::App& sub) {
        auto opt = std::make_shared<DemoOptions>();
        sub.add_option("--out", opt->out, "folder for the recording and the report")->capture_default_str();
        sub.add_option("--scene", opt->scene, "scene file (default: scenes/membrane-peel.json)");
        sub.add_option("--scenario", opt->scenario,
                       "synthetic surgeon (default: the scene's, e.g. peel; peel-hard pulls too hard)")
            ->check(CLI::IsMember(eyesim::rig::scenario_names()));
        sub.add_option("--seconds", opt->seconds, "length of the synthetic recording (default: the scene's duration)")
            ->check(eyesim::app::finite_in(0.5, 60.0));
        sub.add_option("--seed", opt->seed, "scenario and noise seed")
            ->check(eyesim::app::unsigned_integer())
            ->capture_default_str();
        sub.add_option("--device", opt->device, "path of eyesim-device (default: beside eyesim, then PATH)");
        sub.add_flag("--precision", opt->precision,
                     "precision mode: the device sends every marker's pixel patch, the host refines each centroid on it");
        sub.add_flag("--no-hints", opt->no_hints,
                     "with --precision: fit every marker as a whole sphere (by default a marker's fit leaves out what "
                     "the newest poses say hides part of it: its shaft, the eye)");
        sub.add_option("--sync", opt->sync,
                       "tracking: async (per-body filters fed each blob as the device sends it, in its per-blob "
                       "mode) or interpolate (whole fields, the cameras interpolated to one time)")
            ->check(CLI::IsMember({"async", "interpolate"}))
            ->capture_default_str();
        eyesim::app::add_report_delay_option(sub, opt->report_delay_ms,
                                             eyesim::tracking::AsyncOptions::kMaxReportDelayUs * 1e-3);
        sub.add_flag("--json", opt->json, "one JSON object on stdout");
        return [opt]() -> int { return run_demo(*opt); };
    }};

}  // namespace
