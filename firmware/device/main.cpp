// `eyesim-device`: the simulated eyesim device. Plays a recording directory as three PAL camera streams through
// the firmware core (three FPGA pipelines, packetiser, commands, bounded queue) and serves the wire protocol
// over TCP. Device time is modelled (PAL pixel clock), so its output does not depend on this PC's speed.
#include "eyesim/firmware/device_core.hpp"
#include "eyesim/firmware/pc/field_source.hpp"
#include "eyesim/firmware/pc/latency_log.hpp"
#include "eyesim/firmware/pc/modelled_clock.hpp"
#include "eyesim/firmware/pc/pedal_track.hpp"
#include "eyesim/firmware/pc/tcp_server.hpp"

#include "eyesim/rig/pal.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/scenario.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/rig/truth.hpp"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <exception>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace {

volatile std::sig_atomic_t g_stop = 0;
void on_signal(int) { g_stop = 1; }

struct Options {
    std::string recording;
    std::string scenario;
    double seconds = 10.0;
    std::uint64_t seed = 1;
    std::string address = "127.0.0.1";
    std::string bind;
    int port = 7431;
    bool realtime = false;
    bool loop = false;
    bool free_run = false;
    bool low_latency = false;
    bool stream = false;
    bool allow_drops = false;
    bool json = false;
    long long max_fields = -1;
    int send_buffer = 0;
    int linger_ms = 5000;
    std::vector<std::string> regs;  // ADDRESS=VALUE register writes at power-up
};

/// A command-line value the device refuses (exit 2, like a parse error).
struct UsageError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

using Clock = std::chrono::steady_clock;

/// Where the camera fields come from: a recording directory or the rig's renderer, live.
class FieldProvider {
public:
    virtual ~FieldProvider() = default;
    /// Fields per camera.
    virtual std::int64_t fields() const = 0;
    /// The cameras (clock offsets, parities).
    virtual const std::vector<eyesim::rig::CameraModel>& cameras() const = 0;
    /// Field `index` of camera `cam` as UYVY.
    virtual void read(int cam, std::int64_t index, std::uint8_t* uyvy) = 0;
    /// The foot pedal over the recording (recording clock); empty: no pedal track (pedal at rest).
    virtual std::vector<eyesim::firmware::pc::PedalSample> pedal_track() const = 0;
};

using eyesim::firmware::pc::pedal_sample;

class RecordingProvider final : public FieldProvider {
public:
    explicit RecordingProvider(const std::string& dir) : rec_(eyesim::rig::Recording::open(dir)) {
        if (rec_.camera_count() < static_cast<int>(eyesim::firmware::kCameras))
            throw std::runtime_error(dir + "/rig.yaml: camera_count " + std::to_string(rec_.camera_count()) +
                                     " but the device has 3 cameras");
        if (rec_.common_field_count() <= 0) throw std::runtime_error(dir + ": the recording has no complete field");
        print_warnings();
    }
    std::int64_t fields() const override { return rec_.common_field_count(); }
    const std::vector<eyesim::rig::CameraModel>& cameras() const override { return rec_.cameras(); }
    void read(int cam, std::int64_t index, std::uint8_t* uyvy) override {
        if (!rec_.read_field(cam, index, uyvy)) print_warnings();  // a video field lost: sent black
    }
    std::vector<eyesim::firmware::pc::PedalSample> pedal_track() const override {
        // The pedal of a recording is in its truth.jsonl (one sample per field time); a recording without it
        // (a real rig's video) plays with the pedal at rest.
        const std::string path = rec_.truth_path();
        if (path.empty()) {
            std::fprintf(stderr, "eyesim-device: warning: %s has no truth.jsonl: the pedal stays at rest\n",
                         rec_.dir().c_str());
            return {};
        }
        return eyesim::firmware::pc::pedal_track_of(eyesim::rig::read_truth(path));
    }

private:
    void print_warnings() {
        for (const std::string& w : rec_.take_warnings()) std::fprintf(stderr, "eyesim-device: warning: %s\n", w.c_str());
    }
    eyesim::rig::Recording rec_;
};

/// Renders the rig's scenario as the cameras ask for fields (all three cameras of a field at once).
class ScenarioProvider final : public FieldProvider {
public:
    ScenarioProvider(const std::string& name, double seconds, std::uint64_t seed)
        : cams_(eyesim::rig::default_rig()),
          fields_(std::max<std::int64_t>(1, std::llround(seconds * eyesim::rig::kFieldRateHz))) {
        const eyesim::rig::Bodies bodies = eyesim::rig::load_bodies(eyesim::rig::default_bodies_path());
        eyesim::rig::RenderOptions ro;
        ro.seed = seed;
        const auto scenario =
            eyesim::rig::Scenario::make(name, seed, static_cast<double>(fields_) * eyesim::rig::kFieldPeriodUs, bodies);
        // The pedal every 1 ms over the run (the core samples it at 1 kHz).
        const double end_us = static_cast<double>(fields_ + 1) * eyesim::rig::kFieldPeriodUs;
        for (double t = 0.0; t <= end_us; t += 1000.0) pedal_.push_back(pedal_sample(t, scenario.state_at(t).pedal));
        synth_ = std::make_unique<eyesim::rig::RigSynth>(cams_, bodies, scenario, ro);
        for (auto& f : buffers_) f.resize(eyesim::rig::kFieldBytes);
    }
    std::int64_t fields() const override { return fields_; }
    const std::vector<eyesim::rig::CameraModel>& cameras() const override { return cams_; }
    void read(int cam, std::int64_t index, std::uint8_t* uyvy) override {
        if (index != rendered_) {
            eyesim::rig::FieldTruth truth;
            synth_->render(index, {buffers_[0].data(), buffers_[1].data(), buffers_[2].data()}, truth);
            rendered_ = index;
        }
        std::copy(buffers_[static_cast<std::size_t>(cam)].begin(), buffers_[static_cast<std::size_t>(cam)].end(), uyvy);
    }
    std::vector<eyesim::firmware::pc::PedalSample> pedal_track() const override { return pedal_; }

private:
    std::vector<eyesim::firmware::pc::PedalSample> pedal_;
    std::vector<eyesim::rig::CameraModel> cams_;
    std::int64_t fields_;
    std::unique_ptr<eyesim::rig::RigSynth> synth_;
    std::array<std::vector<std::uint8_t>, 3> buffers_;
    std::int64_t rendered_ = -1;
};

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

nlohmann::json summary_json(const eyesim::firmware::pc::LatencySummary& s) {
    return {{"count", s.count}, {"p50", s.p50_us}, {"p99", s.p99_us}, {"max", s.max_us}, {"mean", s.mean_us}};
}

int run(const Options& opt) {
    using namespace eyesim;
    using namespace eyesim::firmware;
    const Clock::time_point power_up = Clock::now();  // device time 0

    std::shared_ptr<FieldProvider> recording;
    if (!opt.recording.empty()) recording = std::make_shared<RecordingProvider>(opt.recording);
    else recording = std::make_shared<ScenarioProvider>(opt.scenario, opt.seconds, opt.seed);
    const std::int64_t fields_in_file = recording->fields();
    const bool allow_any = !opt.bind.empty();
    pc::TcpServer server(allow_any ? opt.bind : opt.address, static_cast<std::uint16_t>(opt.port), allow_any);
    if (opt.send_buffer > 0) server.set_send_buffer(opt.send_buffer);
    std::FILE* announce = opt.json ? stderr : stdout;
    std::fprintf(announce, "listening tcp://%s:%u\n", (allow_any ? opt.bind : opt.address).c_str(), server.port());
    std::fflush(announce);

    // Device clock: µs since start-up. While the cameras play, the PAL model sets it (deterministic timestamps);
    // otherwise (before stream_start, after stream_stop or the recording's end) it follows the wall clock.
    // The recording's t = 0 is played at device time `epoch_us`, so every field is stamped after start-up.
    pc::ModelledClock clock;
    auto epoch_us = std::make_shared<std::uint64_t>(0);
    pc::PedalTrack pedal(recording->pedal_track(), &clock);
    std::vector<std::unique_ptr<pc::FieldSource>> sources;
    DeviceHal hal;
    const long long limit = opt.max_fields;
    for (std::size_t c = 0; c < kCameras; ++c) {
        const int cam = static_cast<int>(c);
        const rig::CameraModel model = recording->cameras()[c];
        auto loader = [recording, cam, model, fields_in_file, loop = opt.loop, limit, epoch_us](
                          std::uint64_t k, std::uint8_t* out, std::uint8_t& parity, std::uint64_t& start_us) {
            if (limit >= 0 && k >= static_cast<std::uint64_t>(limit)) return false;
            if (!loop && k >= static_cast<std::uint64_t>(fields_in_file)) return false;
            const auto index = static_cast<std::int64_t>(k % static_cast<std::uint64_t>(fields_in_file));
            recording->read(cam, index, out);
            // Field k (also past the file's end when looping) on the rig's clock: camera offset + k·20 ms, plus
            // half a line for a bottom field, as `eyesim fpga` stamps it, so both write identical packets.
            const rig::FieldTiming t = rig::field_timing(static_cast<std::int64_t>(k), model.field_time_offset_us,
                                                         model.exposure_us, model.first_field_parity);
            parity = static_cast<std::uint8_t>(t.parity);
            start_us = *epoch_us +
                       static_cast<std::uint64_t>(std::llround(std::max(0.0, t.start_us + (t.parity ? 32.0 : 0.0))));
            return true;
        };
        sources.push_back(std::make_unique<pc::FieldSource>(loader));
        hal.cameras[c] = sources.back().get();
    }
    pc::LatencyLog latency(1u << 20);
    hal.sink = &server;
    hal.source = &server;
    hal.clock = &clock;
    hal.latency = &latency;
    hal.pedal = &pedal;
    CoreConfig config;
    config.low_latency = opt.low_latency;
    config.stream_on_start = opt.stream;
    auto core = std::make_unique<DeviceCore>(hal, config);
    // Power-up register settings (as a configuration tool would leave them): executed as host commands would be,
    // so they are validated the same way.
    for (const std::string& w : opt.regs) {
        const std::size_t eq = w.find('=');
        eyesim::protocol::Command c;
        c.opcode = static_cast<std::uint8_t>(eyesim::protocol::Opcode::RegisterWrite);
        bool ok = eq != std::string::npos && eq > 0 && eq + 1 < w.size();
        try {
            std::size_t a = 0, v = 0;
            const unsigned long address = ok ? std::stoul(w.substr(0, eq), &a, 0) : 0;
            const unsigned long value = ok ? std::stoul(w.substr(eq + 1), &v, 0) : 0;
            ok = ok && a == eq && v == w.size() - eq - 1 && address <= 0xFFFFu && value <= 0xFFFFFFFFul;
            c.address = static_cast<std::uint32_t>(address);
            c.value = static_cast<std::uint32_t>(value);
        } catch (const std::exception&) {
            ok = false;
        }
        if (!ok) throw UsageError("--reg: '" + w + "': expected ADDRESS=VALUE");
        const eyesim::protocol::Reply r = core->execute(c);
        if (r.status != static_cast<std::uint8_t>(eyesim::protocol::ReplyStatus::Ack))
            throw UsageError("--reg: '" + w + "': register write refused (NACK reason " + std::to_string(r.reason) + ")");
    }

    // Fields per camera this run will play (-1: endless loop).
    const long long expected_fields =
        opt.loop ? opt.max_fields : (opt.max_fields >= 0 ? std::min<long long>(opt.max_fields, fields_in_file) : fields_in_file);
    bool finished = false;
    bool ever_connected = false;
    Clock::time_point play_t0{};
    std::uint64_t play_model0_us = 0;
    bool play_started = false;
    Clock::time_point finished_at{};
    // Idle: the device clock follows the wall clock from this anchor.
    bool was_playing = false;
    Clock::time_point idle_wall0 = power_up;
    std::uint64_t idle_model0_us = 0, paused_model_us = 0;
    const std::size_t queue_pause_bytes = DeviceCore::TxQueue::byte_capacity() / 2;

    while (!g_stop) {
        if (server.poll_accept()) ever_connected = true;
        if (server.take_disconnect()) {
            core->host_disconnected();
            // The host left after the last field was out: the run is over (otherwise wait for the next host).
            bool all_out = expected_fields >= 0;
            for (const auto& s : sources) all_out = all_out && s->fields_delivered() >= static_cast<std::uint64_t>(expected_fields);
            if (finished || all_out) break;
        }
        const bool playing = !finished && (opt.free_run || (server.connected() && core->streaming()));
        if (!playing) {
            if (was_playing) {
                idle_wall0 = Clock::now();
                idle_model0_us = paused_model_us = clock.now_us();
            }
            clock.advance_to(idle_model0_us +
                             static_cast<std::uint64_t>(std::max(0.0, seconds_since(idle_wall0) * 1e6)));
        } else if (!was_playing) {
            // (Re)start: the recording's timeline continues after the idle time, on a whole millisecond.
            const std::uint64_t now = clock.now_us();
            const std::uint64_t shift = play_started ? now - paused_model_us : (now + 999) / 1000 * 1000;
            *epoch_us += shift;
            pedal.set_epoch_us(*epoch_us);
        }
        was_playing = playing;
        core->service();
        if (!playing) {
            if (finished) {
                // Recording over: let the host drain what is queued, then leave when it goes (or after linger).
                if (!server.connected() && ever_connected) break;
                if (!server.connected() && seconds_since(finished_at) * 1000 > opt.linger_ms) break;
                if (core->tx_idle() && seconds_since(finished_at) * 1000 > opt.linger_ms) break;
            }
            server.wait(finished ? 20 : 5, !core->tx_idle());
            continue;
        }
        if (!play_started) {
            play_started = true;
            play_t0 = Clock::now();
            play_model0_us = clock.now_us();
        }
        if (opt.realtime) {
            // PAL pace: do not run ahead of the wall clock.
            const double ahead_us = static_cast<double>(clock.now_us() - play_model0_us) - seconds_since(play_t0) * 1e6;
            if (ahead_us > 200) {
                server.wait(static_cast<int>(std::min(ahead_us / 1000.0, 5.0)), !core->tx_idle());
                continue;
            }
        } else if (!opt.allow_drops && core->tx_queued_bytes() > queue_pause_bytes) {
            // As fast as possible, but the recording player waits for a slow host instead of dropping: runs stay
            // deterministic. (--realtime, or --allow-drops, shows the device's real drop-oldest behaviour.)
            server.wait(5, true);
            continue;
        }
        if (core->step_cameras() == StepStatus::finished) {
            finished = true;
            finished_at = Clock::now();
            // The host may still send commands (stream_stop, pings for its clock offset) and wait for their
            // replies: the link stays open until it hangs up or --linger-ms passes. Say so, or the wait looks
            // like a hang.
            if (opt.linger_ms > 0 && server.connected())
                std::fprintf(stderr,
                             "eyesim-device: recording ended; keeping the link open %.1f s for late commands "
                             "(--linger-ms)\n",
                             opt.linger_ms / 1000.0);
            else if (opt.linger_ms > 0 && !ever_connected)
                std::fprintf(stderr, "eyesim-device: recording ended; waiting %.1f s for a host (--linger-ms)\n",
                             opt.linger_ms / 1000.0);
        }
    }

    const double wall_s = play_started ? seconds_since(play_t0) : 0.0;
    const auto st = core->status();
    const auto fields = static_cast<std::uint64_t>(st.fields_processed[0]);
    using Span = pc::LatencyLog::Span;
    const auto written = latency.summarise(Span::last_pixel_to_written);
    if (opt.json) {
        nlohmann::json j;
        j["fields"] = fields;
        j["fields_per_s"] = wall_s > 0 ? static_cast<double>(fields) / wall_s : 0.0;
        j["latency_us"] = summary_json(written);
        j["latency_queued_us"] = summary_json(latency.summarise(Span::last_pixel_to_queued));
        j["latency_complete_us"] = summary_json(latency.summarise(Span::last_pixel_to_complete));
        j["blobs_sent"] = core->counters().blobs_sent;
        j["blobs_dropped"] = st.blobs_dropped;
        j["queue_overflows"] = st.queue_overflows;
        j["bytes_sent"] = st.bytes_sent;
        j["commands"] = core->counters().commands;
        j["nacks"] = core->counters().nacks;
        j["errors"] = st.crc_errors + st.parse_errors;
        std::printf("%s\n", j.dump().c_str());
    } else {
        std::fprintf(stderr,
                     "eyesim-device: %llu fields per camera, %llu blobs sent, %u queue overflows, modelled latency "
                     "p50 %.1f us p99 %.1f us max %.1f us (last pixel to bytes written)\n",
                     static_cast<unsigned long long>(fields),
                     static_cast<unsigned long long>(core->counters().blobs_sent), st.queue_overflows,
                     written.p50_us, written.p99_us, written.max_us);
    }
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    CLI::App app{"eyesim-device: the simulated eyesim tracking device (three PAL cameras, FPGA pipelines, firmware "
                 "core) serving the wire protocol over TCP"};
    Options opt;
    auto* rec_opt = app.add_option("--recording", opt.recording, "recording directory (rig.yaml + cam0..2 streams)");
    auto* scn_opt = app.add_option("--scenario", opt.scenario,
                                   "render this rig scenario live instead (static, sweep, surgery, fast, occlusion, injection, peel, peel-hard, vitrectomy)")
                        ->check(CLI::IsMember(eyesim::rig::scenario_names()));
    rec_opt->excludes(scn_opt);
    app.add_option("--seconds", opt.seconds, "--scenario: length in seconds, 0.02 to 3600 (fields = 50 per second)")
        ->check(CLI::Validator(
            [](std::string& text) -> std::string {
                double v = 0;
                if (!CLI::detail::lexical_cast(text, v) || !std::isfinite(v) || v < 0.02 || v > 3600.0)
                    return "Value " + text + " not a finite number in [0.02, 3600]";
                return {};
            },
            "FINITE in [0.02 - 3600]"))
        ->capture_default_str();
    app.add_option("--seed", opt.seed, "--scenario: scenario and noise seed")
        ->check(CLI::Validator(
            [](std::string& text) -> std::string {  // CLI11 would read "-1" as 2^64 - 1
                const auto digit = [](char c) { return c >= '0' && c <= '9'; };
                if (text.empty() || !std::all_of(text.begin(), text.end(), digit))
                    return "Value " + text + " not a whole number in [0, 18446744073709551615]";
                return {};
            },
            "UINT64"))
        ->capture_default_str();
    app.add_option("--address", opt.address, "loopback address to listen on")->capture_default_str();
    app.add_option("--bind", opt.bind, "listen on this address even if it is not loopback (explicit opt-in)");
    app.add_option("--port", opt.port, "TCP port; 0 picks a free one (printed as 'listening tcp://ADDR:PORT')")
        ->check(CLI::Range(0, 65535))
        ->capture_default_str();
    app.add_flag("--realtime", opt.realtime, "play at PAL pace (50 fields/s) instead of as fast as possible");
    app.add_flag("--loop", opt.loop, "start the recording again at its end (field counters keep counting)");
    app.add_option("--fields", opt.max_fields, "stop after this many fields per camera")
        ->check(CLI::Range(1LL, std::numeric_limits<long long>::max()));
    app.add_flag("--free-run", opt.free_run, "run the cameras from start-up, whether or not a host listens");
    app.add_flag("--stream", opt.stream, "stream without waiting for a stream_start command");
    app.add_flag("--low-latency", opt.low_latency, "start in per-blob (low-latency) mode");
    app.add_option("--reg", opt.regs,
                   "register write ADDRESS=VALUE at power-up, as a configuration tool would leave it (repeatable; "
                   "device address space: 0x0000-0x0FFF every camera, 0x1000/0x2000/0x3000 + offset one camera)");
    app.add_flag("--allow-drops", opt.allow_drops,
                 "as-fast-as-possible mode: let the queue drop for a slow host instead of pausing the player");
    app.add_option("--send-buffer", opt.send_buffer, "kernel send buffer of the host socket, bytes")
        ->check(CLI::Range(1, std::numeric_limits<int>::max()));
    app.add_option("--linger-ms", opt.linger_ms, "after the recording ends, wait this long for the host to finish")
        ->check(CLI::Range(0, 3600000))
        ->capture_default_str();
    app.add_flag("--json", opt.json, "print one JSON summary on stdout at exit");
    try {
        app.parse(argc, argv);
    } catch (const CLI::Success& e) {  // --help
        return app.exit(e);
    } catch (const CLI::ParseError& e) {  // usage error: one line, exit 2
        std::fprintf(stderr, "eyesim-device: error: %s (see --help)\n", e.what());
        return 2;
    }
    if (opt.recording.empty() == opt.scenario.empty()) {  // --recording excludes --scenario: none was given
        std::fprintf(stderr,
                     "eyesim-device: error: give exactly one of --recording DIR or --scenario NAME (see --help)\n");
        return 2;
    }
    std::signal(SIGINT, on_signal);
    std::signal(SIGTERM, on_signal);
    std::signal(SIGPIPE, SIG_IGN);
    try {
        return run(opt);
    } catch (const UsageError& e) {
        std::fprintf(stderr, "eyesim-device: error: %s (see --help)\n", e.what());
        return 2;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "eyesim-device: error: %s\n", e.what());
        return 1;
    }
}
