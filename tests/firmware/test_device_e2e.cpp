// End to end: `eyesim-device --recording DIR` as a child process, a host client over TCP loopback recording a
// capture; the capture decodes to the FPGA model's markers (what `eyesim fpga --out` writes).
#include "child_process.hpp"

#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/fpga/wire.hpp"
#include "eyesim/protocol/capture_replay.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/rig/truth.hpp"
#include "eyesim/transport/device_link.hpp"
#include "eyesim/transport/tcp.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <memory>
#include <chrono>
#include <set>
#include <thread>

using namespace eyesim;
namespace fs = std::filesystem;

namespace {

const std::string kDevice = EYESIM_DEVICE_EXE;

/// Removes the generated recording when the test program ends.
struct RemoveAtExit {
    std::string path;
    ~RemoveAtExit() {
        std::error_code ec;
        if (!path.empty()) fs::remove_all(path, ec);
    }
};

/// A short synthetic recording (0.2 s = 10 fields per camera), generated once per test process (its own folder,
/// so parallel test processes never share one).
const std::string& recording_dir() {
    static RemoveAtExit cleanup;
    static const std::string dir = [] {
        const std::string d = std::string(EYESIM_TEST_TMP) + "/e2e_recording_" + std::to_string(::getpid());
        cleanup.path = d;
        fs::remove_all(d);
        rig::SynthRequest req;
        req.out_dir = d;
        req.scenario = "sweep";
        req.seconds = 0.2;
        req.seed = 11;
        rig::write_recording(req);
        return d;
    }();
    return dir;
}

/// The FPGA model over the recording, stamped and converted as `eyesim fpga --out` does.
std::vector<protocol::FieldMarkers> reference_messages(const std::string& dir) {
    rig::Recording rec = rig::Recording::open(dir);
    std::vector<protocol::FieldMarkers> out;
    fpga::RegisterMap regs;
    std::vector<std::uint8_t> field(rig::kFieldBytes);
    for (int c = 0; c < 3; ++c) {
        fpga::PipelineConfig cfg;
        cfg.camera = static_cast<std::uint8_t>(c);
        auto pipe = std::make_unique<fpga::Pipeline>(regs, cfg);
        for (std::int64_t i = 0; i < rec.common_field_count(); ++i) {
            rec.read_field(c, i, field.data());
            const int parity = rec.field_parity(c, i);
            const rig::FieldTiming t = rec.field_timing(c, i);
            const auto start_us = static_cast<std::uint64_t>(std::llround(std::max(0.0, t.start_us + (parity ? 32.0 : 0.0))));
            REQUIRE(pipe->process_field(field.data(), rig::kFieldHeight, static_cast<std::uint32_t>(i),
                                        static_cast<std::uint8_t>(parity)) == fpga::PipelineStatus::kOk);
            std::vector<fpga::Blob> blobs;
            fpga::Blob b;
            while (pipe->pop_blob(b)) blobs.push_back(b);
            std::vector<protocol::FieldMarkers> parts(fpga::field_markers_messages(blobs.size()));
            const auto info = fpga::field_info(pipe->field_stats(), static_cast<std::uint8_t>(c),
                                               static_cast<std::uint8_t>(parity), start_us);
            parts.resize(fpga::to_field_markers(blobs.data(), blobs.size(), info, parts.data(), parts.size()));
            out.insert(out.end(), parts.begin(), parts.end());
        }
    }
    return out;
}

struct Run {
    std::vector<protocol::FieldMarkers> messages;  // from the capture, in arrival order
    std::vector<protocol::PedalState> pedals;      // from the capture, in arrival order
    std::uint64_t pong_before_start_us = 0;        // device time in the reply to a ping sent before stream_start
    int exit_code = -1;
    std::string stderr_text;
    protocol::ParserStats stats;
};

/// Starts the device on a free port, records a capture of one whole playback, returns what the capture holds.
Run run_device(bool low_latency, const std::string& capture, std::vector<std::string> source = {}) {
    const std::string& dir = recording_dir();
    rig::Recording rec = rig::Recording::open(dir);
    const auto fields = static_cast<std::uint32_t>(rec.common_field_count());
    if (source.empty()) source = {"--recording", dir};
    std::vector<std::string> argv{kDevice, "--port", "0", "--linger-ms", "3000"};
    argv.insert(argv.end(), source.begin(), source.end());
    test::ChildProcess child(argv);
    REQUIRE(child.started());
    const std::string line = child.read_line(10000);
    INFO("device said: " << line);
    const std::string prefix = "listening tcp://127.0.0.1:";
    REQUIRE(line.rfind(prefix, 0) == 0);
    const auto port = static_cast<std::uint16_t>(std::stoi(line.substr(prefix.size())));

    Run run;
    {
        transport::DeviceLink link(transport::connect_tcp("127.0.0.1", port, 2000));
        link.record_to(capture);
        if (low_latency) {
            const auto id = link.command(protocol::Opcode::SetLowLatency, 0, 1);
            const auto r = link.wait_reply(id, 5000);
            REQUIRE(r.has_value());
            REQUIRE(r->status == 0);
        }
        for (int i = 0; i < 4; ++i) link.ping();
        // The device clock runs from start-up: a pong before streaming carries a real time.
        std::this_thread::sleep_for(std::chrono::milliseconds(30));
        const auto pong = link.wait_reply(link.ping(), 5000);
        REQUIRE(pong.has_value());
        run.pong_before_start_us = pong->device_us;
        link.command(protocol::Opcode::StreamStart);
        // Until the last part of the last field of every camera is in (bounded).
        std::set<int> done;
        const std::uint64_t deadline = transport::host_now_us() + 60'000'000;
        while (done.size() < 3 && transport::host_now_us() < deadline) {
            const int n = link.poll(100, [&](const protocol::DecodedFrame& f) {
                if (const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message))
                    if (fm->field_counter + 1 == fields && !(fm->flags & protocol::kFieldFlagMoreFollows))
                        done.insert(fm->camera_id);
            });
            if (n < 0) break;
        }
        REQUIRE(done.size() == 3);
        REQUIRE(link.clock().valid());
        // Modelled device time vs host steady clock: any offset, but a finite round trip on loopback.
        REQUIRE(link.clock().delay_us() < 1e6);
        link.transport().close();
    }
    run.exit_code = child.wait(10000);
    run.stderr_text = child.drain_stderr();
    // Replay the capture, as the host tracker would.
    auto replay = std::make_unique<protocol::CaptureReplay>();
    REQUIRE(replay->open(capture.c_str()));
    protocol::DecodedFrame f;
    std::uint64_t rx = 0, last_rx = 0;
    while (replay->next(f, rx)) {
        REQUIRE(rx >= last_rx);
        last_rx = rx;
        if (const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message)) run.messages.push_back(*fm);
        if (const auto* p = std::get_if<protocol::PedalState>(&f.message)) run.pedals.push_back(*p);
    }
    REQUIRE(replay->status() == protocol::CaptureStatus::End);
    run.stats = replay->stats();
    replay.reset();
    fs::remove(capture);
    return run;
}

/// The device plays the recording's t = 0 at device time `epoch` (after start-up): its stamps minus the epoch
/// are the recording clock's, as `eyesim fpga` writes them. Returns the epoch found in the first message.
std::uint64_t to_recording_clock(std::vector<protocol::FieldMarkers>& got, const std::vector<protocol::FieldMarkers>& want) {
    std::map<std::pair<int, std::uint32_t>, std::uint64_t> end_us;
    for (const auto& m : want)
        if (m.field_end_us) end_us[{m.camera_id, m.field_counter}] = m.field_end_us;
    std::uint64_t epoch = 0;
    bool found = false;
    for (const auto& m : got) {
        const auto it = end_us.find({m.camera_id, m.field_counter});
        if (m.field_end_us == 0 || it == end_us.end()) continue;
        REQUIRE(m.field_end_us >= it->second);
        epoch = m.field_end_us - it->second;
        found = true;
        break;
    }
    REQUIRE(found);
    for (auto& m : got) {
        if (m.field_end_us) m.field_end_us -= epoch;
        for (int i = 0; i < m.marker_count; ++i) m.markers[i].complete_us -= epoch;
    }
    return epoch;
}

}  // namespace

TEST_CASE("eyesim-device over TCP: the capture equals the FPGA model's packets (per-field mode)", "[firmware][e2e]") {
    const auto want = reference_messages(recording_dir());
    const Run run = run_device(false, std::string(EYESIM_TEST_TMP) + "/e2e_field_" + std::to_string(::getpid()) + ".capture");
    INFO(run.stderr_text);
    REQUIRE(run.exit_code == 0);
    REQUIRE(run.stats.errors() == 0);
    REQUIRE(run.stats.sequence_gaps == 0);
    auto got = run.messages;
    std::stable_sort(got.begin(), got.end(), [](const auto& a, const auto& b) { return a.camera_id < b.camera_id; });
    REQUIRE(got.size() == want.size());
    // Device time runs from start-up: the playback began after the pings, on a whole millisecond.
    const std::uint64_t epoch = to_recording_clock(got, want);
    CHECK(epoch % 1000 == 0);
    CHECK(run.pong_before_start_us > 20000);
    CHECK(epoch >= run.pong_before_start_us);
    std::size_t markers = 0;
    for (std::size_t i = 0; i < got.size(); ++i) {
        INFO("message " << i);
        REQUIRE(got[i] == want[i]);
        markers += got[i].marker_count;
    }
    REQUIRE(markers > 0);

    // The pedal of the recording (truth.jsonl, one sample per field time) goes out as PedalState on the device
    // clock: from stream start, at least every 20 ms (PEDAL_PERIOD_MS) and on each change.
    const auto truth = rig::read_truth(recording_dir() + "/truth.jsonl");
    REQUIRE(truth.size() >= 2);
    auto pedal_at = [&](double t_us) {  // linear between field times, held at the ends
        if (t_us <= truth.front().t_us) return truth.front().pedal.axes[0];
        for (std::size_t i = 1; i < truth.size(); ++i)
            if (t_us <= truth[i].t_us) {
                const double u = (t_us - truth[i - 1].t_us) / (truth[i].t_us - truth[i - 1].t_us);
                return truth[i - 1].pedal.axes[0] + u * (truth[i].pedal.axes[0] - truth[i - 1].pedal.axes[0]);
            }
        return truth.back().pedal.axes[0];
    };
    REQUIRE(run.pedals.size() >= 10);
    int lo = 65535, hi = 0;
    for (std::size_t i = 0; i < run.pedals.size(); ++i) {
        const auto& p = run.pedals[i];
        INFO("pedal message " << i << " at device " << p.device_us << " us");
        REQUIRE(p.device_us >= run.pong_before_start_us);  // sent after stream_start
        // Before the first field the pedal holds the recording's first sample.
        const double want_counts = std::clamp(pedal_at(double(p.device_us) - double(epoch)), 0.0, 1.0) * 65535.0;
        CHECK(std::abs(double(p.axes[0]) - want_counts) <= 1.0);
        if (i > 0) CHECK(p.device_us - run.pedals[i - 1].device_us <= 20000 + 1000);
        lo = std::min<int>(lo, p.axes[0]);
        hi = std::max<int>(hi, p.axes[0]);
    }
    CHECK(hi - lo > 64);  // the pedal moved over the recording (sweep: a slow press)
}

TEST_CASE("eyesim-device over TCP: low-latency parts carry the same markers", "[firmware][e2e]") {
    const auto want = reference_messages(recording_dir());
    const Run run = run_device(true, std::string(EYESIM_TEST_TMP) + "/e2e_blob_" + std::to_string(::getpid()) + ".capture");
    INFO(run.stderr_text);
    REQUIRE(run.exit_code == 0);
    REQUIRE(run.stats.errors() == 0);
    std::map<std::pair<int, std::uint32_t>, std::vector<protocol::Marker>> a, b;
    for (const auto& m : want)
        for (int i = 0; i < m.marker_count; ++i) a[{m.camera_id, m.field_counter}].push_back(m.markers[i]);
    auto got = run.messages;
    (void)to_recording_clock(got, want);
    for (const auto& m : got) {
        REQUIRE((m.flags & protocol::kFieldFlagLowLatency) != 0);
        auto& v = b[{m.camera_id, m.field_counter}];
        for (int i = 0; i < m.marker_count; ++i) v.push_back(m.markers[i]);
    }
    // Fields without blobs: a closing part with no markers in both; compare fields that have markers.
    std::erase_if(a, [](const auto& kv) { return kv.second.empty(); });
    std::erase_if(b, [](const auto& kv) { return kv.second.empty(); });
    REQUIRE(!a.empty());
    REQUIRE(a == b);
}

TEST_CASE("eyesim-device --scenario renders live what the synthesiser writes", "[firmware][e2e]") {
    // The recording was synthesised from scenario "sweep", 0.2 s, seed 11 on the default rig: live rendering with
    // the same parameters gives the same fields, hence the same packets.
    const auto want = reference_messages(recording_dir());
    const Run run = run_device(false, std::string(EYESIM_TEST_TMP) + "/e2e_live_" + std::to_string(::getpid()) + ".capture",
                               {"--scenario", "sweep", "--seconds", "0.2", "--seed", "11"});
    INFO(run.stderr_text);
    REQUIRE(run.exit_code == 0);
    auto got = run.messages;
    std::stable_sort(got.begin(), got.end(), [](const auto& a, const auto& b) { return a.camera_id < b.camera_id; });
    REQUIRE(got.size() == want.size());
    (void)to_recording_clock(got, want);
    for (std::size_t i = 0; i < got.size(); ++i) REQUIRE(got[i] == want[i]);
}

TEST_CASE("eyesim-device with a host that stops reading: oldest frames dropped and counted, never blocked",
          "[firmware][e2e]") {
    // 400 fields (the 10-field recording looped) into a small socket buffer while the host sleeps.
    test::ChildProcess child({kDevice, "--recording", recording_dir(), "--loop", "--fields", "400", "--port", "0",
                              "--allow-drops", "--send-buffer", "4096", "--linger-ms", "3000", "--json"});
    REQUIRE(child.started());
    const std::string line = child.read_line(10000, true);
    const std::string prefix = "listening tcp://127.0.0.1:";
    REQUIRE(line.rfind(prefix, 0) == 0);
    const auto port = static_cast<std::uint16_t>(std::stoi(line.substr(prefix.size())));
    std::uint64_t lost = 0, frames = 0;
    bool saw_last = false;
    std::set<int> last_field_done;  // cameras whose field 399 ended (their fields end up to 13 ms apart)
    {
        transport::DeviceLink link(transport::connect_tcp("127.0.0.1", port, 2000));
        link.command(protocol::Opcode::StreamStart);
        std::this_thread::sleep_for(std::chrono::milliseconds(1500));  // the host stalls; the device must not
        const std::uint64_t deadline = transport::host_now_us() + 30'000'000;
        while (!saw_last && transport::host_now_us() < deadline) {
            if (link.poll(100, [&](const protocol::DecodedFrame& f) {
                    ++frames;
                    if (const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message))
                        if (fm->field_counter == 399 && !(fm->flags & protocol::kFieldFlagMoreFollows)) {
                            last_field_done.insert(fm->camera_id);
                            saw_last = last_field_done.size() == 3;
                        }
                }) < 0)
                break;
        }
        REQUIRE(link.stats().errors() == 0);  // only whole frames were dropped
        REQUIRE(link.stats().sequence_gaps > 0);
        lost = link.stats().sequence_gaps;
        link.transport().close();
    }
    REQUIRE(saw_last);  // the newest frames survive drop-oldest
    REQUIRE(child.wait(10000) == 0);
    const std::string out = child.drain_stdout();
    INFO(out);
    const auto j = nlohmann::json::parse(out);
    REQUIRE(j["fields"] == 400);
    REQUIRE(j["queue_overflows"].get<std::uint64_t>() >= lost);  // each gap is at least one dropped frame
    REQUIRE(j["blobs_dropped"].get<std::uint64_t>() > 0);
    REQUIRE(frames > 0);
}

TEST_CASE("eyesim-device refuses bad input with one clear line and a non-zero exit", "[firmware][e2e]") {
    struct Case {
        std::vector<std::string> args;
        std::string expect;
        int rc = 1;  // 1: bad input; 2: usage error
    };
    const std::vector<Case> cases = {
        {{"--recording", recording_dir(), "--address", "0.0.0.0", "--port", "0"}, "not loopback"},
        {{"--recording", recording_dir(), "--address", "example", "--port", "0"}, "not loopback"},
        {{"--recording", std::string(EYESIM_TEST_TMP) + "/no_such_recording", "--port", "0"}, "no_such_recording"},
        {{"--scenario", "no_such_scenario", "--port", "0"}, "no_such_scenario", 2},
        {{"--port", "0"}, "exactly one of --recording DIR or --scenario NAME", 2},
        {{"--scenario", "static", "--seconds", "nan", "--port", "0"}, "--seconds: Value nan not a finite number", 2},
        {{"--recording", recording_dir(), "--port", "70000"}, "--port: Value 70000 not in range", 2},
        {{"--recording", recording_dir(), "--fields", "0"}, "--fields: Value 0 not in range", 2},
        {{"--recording", recording_dir(), "--linger-ms", "-1"}, "--linger-ms: Value -1 not in range", 2},
        {{"--recording", recording_dir(), "--no-such-option"}, "--no-such-option", 2},
    };
    for (const auto& c : cases) {
        std::vector<std::string> argv{kDevice};
        argv.insert(argv.end(), c.args.begin(), c.args.end());
        test::ChildProcess child(argv);
        REQUIRE(child.started());
        const int rc = child.wait(10000);
        const std::string err = child.drain_stderr();
        INFO(err);
        REQUIRE(rc == c.rc);
        REQUIRE(err.rfind("eyesim-device: error: ", 0) == 0);
        REQUIRE(err.find(c.expect) != std::string::npos);
        REQUIRE(std::count(err.begin(), err.end(), '\n') == 1);
    }
}
