// Firmware core benchmark: modelled device latency per blob (last pixel → blob complete → frame queued → bytes
// written) in per-field mode against low-latency (per-blob) mode on the same fields, and the core's PC run time
// against its peer, the three bare FPGA pipelines on the same fields. Error column: markers that differ from the
// FPGA model's (must be 0).
//
// With --patches CLASSES (PATCH_ENABLE bits, e.g. 0xF) the core also runs precision mode on every camera and the
// table adds the BlobPatch traffic: patches sent and dropped, bytes per camera field, MB/s at 50 fields/s.
//
// Usage: firmware_latency_bench [--seconds S] [--repeats N] [--patches CLASSES] [--json]
#include "eyesim/firmware/device_core.hpp"
#include "eyesim/firmware/pc/field_source.hpp"
#include "eyesim/firmware/pc/latency_log.hpp"
#include "eyesim/firmware/pc/modelled_clock.hpp"
#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/fpga/wire.hpp"
#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/stream_parser.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/camera.hpp"
#include "eyesim/rig/synth.hpp"

#include "../../tests/firmware/field_gen.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <memory>
#include <string>
#include <vector>

using namespace eyesim;
using firmware::pc::LatencyLog;
using firmware::pc::LatencySummary;

namespace {

using Streams = std::array<std::vector<std::uint8_t>, 3>;
constexpr std::size_t kFieldBytes = test::kFieldBytes;

struct ByteCounter final : firmware::ByteSink {
    std::vector<std::uint8_t> bytes;
    std::size_t write_some(const std::uint8_t* d, std::size_t n) noexcept override {
        bytes.insert(bytes.end(), d, d + n);
        return n;
    }
    bool connected() const noexcept override { return true; }
};

struct Commands final : firmware::ByteSource {
    std::vector<std::uint8_t> pending;
    std::size_t read_some(std::uint8_t* out, std::size_t cap) noexcept override {
        const std::size_t n = std::min(cap, pending.size());
        std::memcpy(out, pending.data(), n);
        pending.erase(pending.begin(), pending.begin() + static_cast<long>(n));
        return n;
    }
};

struct CoreRun {
    LatencyLog log{1u << 20};
    double seconds = 0;
    std::map<std::pair<int, std::uint32_t>, std::vector<protocol::Marker>> markers;
    std::uint64_t frames = 0;
    std::map<std::pair<int, std::uint32_t>, std::size_t> patch_bytes;  // BlobPatch frame bytes per camera field
    std::uint64_t patches_sent = 0, patches_dropped = 0, patches_too_large = 0;
};

/// PATCH_ENABLE written to every camera before streaming (0: precision mode off).
std::uint32_t g_patch_enable = 0;

/// Runs the firmware core over the streams (fields start at k·20 000 µs) and decodes what it sent.
void run_core(const Streams& streams, bool low_latency, CoreRun& out) {
    firmware::pc::ModelledClock clock;
    std::vector<std::unique_ptr<firmware::pc::FieldSource>> cams;
    firmware::DeviceHal hal;
    for (int c = 0; c < 3; ++c) {
        const auto* s = &streams[c];
        cams.push_back(std::make_unique<firmware::pc::FieldSource>(
            [s](std::uint64_t k, std::uint8_t* o, std::uint8_t& parity, std::uint64_t&) {
                if ((k + 1) * kFieldBytes > s->size()) return false;
                std::memcpy(o, s->data() + k * kFieldBytes, kFieldBytes);
                parity = static_cast<std::uint8_t>(k % 2);
                return true;
            }));
        hal.cameras[c] = cams.back().get();
    }
    ByteCounter sink;
    sink.bytes.reserve(64u << 20);
    Commands cmds;
    protocol::Command patches;
    patches.command_id = 1;
    patches.opcode = static_cast<std::uint8_t>(protocol::Opcode::RegisterWrite);
    patches.address = fpga::reg::kPatchEnable;  // the all-cameras window
    patches.value = g_patch_enable;
    protocol::Command start;
    start.command_id = 2;
    start.opcode = static_cast<std::uint8_t>(protocol::Opcode::StreamStart);
    std::vector<std::uint8_t> frame(protocol::kMaxFrameBytes);
    for (const auto& [c, seq] : {std::pair{patches, 0}, std::pair{start, 1}}) {
        frame.resize(protocol::kMaxFrameBytes);
        frame.resize(protocol::encode_frame(protocol::Message{c}, static_cast<std::uint16_t>(seq), frame));
        cmds.pending.insert(cmds.pending.end(), frame.begin(), frame.end());
    }
    hal.sink = &sink;
    hal.source = &cmds;
    hal.clock = &clock;
    out.log.clear();
    hal.latency = &out.log;
    firmware::CoreConfig cfg;
    cfg.low_latency = low_latency;
    auto core = std::make_unique<firmware::DeviceCore>(hal, cfg);
    core->service();
    const auto t0 = std::chrono::steady_clock::now();
    while (core->step_cameras() != firmware::StepStatus::finished) core->service();
    while (!core->tx_idle()) core->service();
    out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    out.markers.clear();
    out.patch_bytes.clear();
    out.frames = 0;
    out.patches_sent = core->counters().patches_sent;
    out.patches_dropped = core->counters().patches_dropped;
    out.patches_too_large = core->counters().patches_too_large;
    protocol::StreamParser parser;
    parser.parse(sink.bytes, [&](const protocol::DecodedFrame& f) {
        ++out.frames;
        if (const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message)) {
            auto& v = out.markers[{fm->camera_id, fm->field_counter}];
            for (int i = 0; i < fm->marker_count; ++i) v.push_back(fm->markers[i]);
        } else if (const auto* bp = std::get_if<protocol::BlobPatch>(&f.message)) {
            out.patch_bytes[{bp->camera_id, bp->field_counter}] += protocol::frame_size(f.header.payload_bytes);
        }
    });
}

/// Peer: the three FPGA pipelines alone on the same fields; returns seconds and fills the reference markers.
double run_pipelines(const Streams& streams,
                     std::map<std::pair<int, std::uint32_t>, std::vector<protocol::Marker>>& ref) {
    fpga::RegisterMap regs;
    std::array<std::unique_ptr<fpga::Pipeline>, 3> pipes;
    for (int c = 0; c < 3; ++c) {
        fpga::PipelineConfig pc;
        pc.camera = static_cast<std::uint8_t>(c);
        pipes[c] = std::make_unique<fpga::Pipeline>(regs, pc);
    }
    const int fields = static_cast<int>(streams[0].size() / kFieldBytes);
    std::vector<fpga::Blob> blobs;
    blobs.reserve(1024);
    ref.clear();
    double seconds = 0;
    for (int k = 0; k < fields; ++k)
        for (int c = 0; c < 3; ++c) {
            blobs.clear();
            const auto t0 = std::chrono::steady_clock::now();
            // Line by line, as the core feeds them.
            pipes[c]->begin_field(static_cast<std::uint32_t>(k), static_cast<std::uint8_t>(k % 2));
            for (int y = 0; y < test::kH; ++y) {
                pipes[c]->push_line(streams[c].data() + kFieldBytes * k + static_cast<std::size_t>(y) * 1440, y);
                fpga::Blob b;
                while (pipes[c]->pop_blob(b)) blobs.push_back(b);
            }
            pipes[c]->end_field();
            fpga::Blob b;
            while (pipes[c]->pop_blob(b)) blobs.push_back(b);
            seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            auto& v = ref[{c, static_cast<std::uint32_t>(k)}];
            for (const auto& blob : blobs) v.push_back(fpga::to_marker(blob, 20000ull * static_cast<std::uint64_t>(k)));
        }
    return seconds;
}

std::size_t mismatches(const std::map<std::pair<int, std::uint32_t>, std::vector<protocol::Marker>>& a,
                       const std::map<std::pair<int, std::uint32_t>, std::vector<protocol::Marker>>& b) {
    std::size_t bad = 0;
    for (const auto& [k, v] : a) {
        const auto it = b.find(k);
        const std::vector<protocol::Marker> empty;
        const auto& w = it == b.end() ? empty : it->second;
        const std::size_t n = std::max(v.size(), w.size());
        for (std::size_t i = 0; i < n; ++i) bad += i >= v.size() || i >= w.size() || !(v[i] == w[i]);
    }
    return bad;
}

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}

nlohmann::json js(const LatencySummary& s) {
    return {{"count", s.count}, {"p50", s.p50_us}, {"p99", s.p99_us}, {"max", s.max_us}};
}

}  // namespace

int main(int argc, char** argv) {
    double seconds = 1.0;
    int repeats = 5;
    bool json = false;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--seconds" && i + 1 < argc) seconds = std::atof(argv[++i]);
        else if (a == "--repeats" && i + 1 < argc) repeats = std::max(1, std::atoi(argv[++i]));
        else if (a == "--patches" && i + 1 < argc) g_patch_enable = static_cast<std::uint32_t>(std::strtoul(argv[++i], nullptr, 0));
        else if (a == "--json") json = true;
        else {
            std::fprintf(stderr, "usage: firmware_latency_bench [--seconds S] [--repeats N] [--patches CLASSES] [--json]\n");
            return 2;
        }
    }
    const int fields = std::max(2, static_cast<int>(std::lround(seconds * 50)));

    // Workload 1: the rig's "surgery" scenario (instrument and eye markers), rendered with sensor noise.
    // Workload 2: a dense synthetic scene, 20 markers per camera in rows (bursts of blobs completing together).
    std::vector<std::pair<std::string, Streams>> workloads;
    {
        Streams s;
        for (auto& v : s) v.resize(kFieldBytes * static_cast<std::size_t>(fields));
        rig::Bodies bodies = rig::load_bodies(rig::default_bodies_path());
        rig::RenderOptions ro;
        rig::RigSynth synth(rig::default_rig(), bodies,
                            rig::Scenario::make("surgery", 7, fields * 20000.0, bodies), ro);
        rig::FieldTruth truth;
        for (int k = 0; k < fields; ++k)
            synth.render(k, {s[0].data() + kFieldBytes * k, s[1].data() + kFieldBytes * k, s[2].data() + kFieldBytes * k},
                         truth);
        workloads.emplace_back("rig surgery scenario", std::move(s));
    }
    {
        Streams s;
        for (int c = 0; c < 3; ++c) s[c] = test::make_stream(c, fields, 20);
        workloads.emplace_back("dense: 20 markers/camera", std::move(s));
    }

    nlohmann::json out = nlohmann::json::array();
    if (!json) {
        std::printf("firmware_latency_bench: %d fields x 3 cameras per workload, run time = median of %d repeats\n\n",
                    fields, repeats);
        std::printf("| workload | mode | blobs | last px→complete p50/p99 µs | →queued p50/p99 µs | →written p50 / p99 / "
                    "max µs | ≤ 100 µs | marker errors | core ms/field | vs 3 bare pipelines |\n");
        std::printf("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    }
    std::vector<std::string> patch_rows;
    for (const auto& [name, streams] : workloads) {
        std::map<std::pair<int, std::uint32_t>, std::vector<protocol::Marker>> ref;
        std::vector<double> peer_s;
        for (int r = 0; r < repeats; ++r) peer_s.push_back(run_pipelines(streams, ref));
        const double peer = median(peer_s);
        for (const bool ll : {false, true}) {
            CoreRun run;
            std::vector<double> t;
            for (int r = 0; r < repeats; ++r) {
                run_core(streams, ll, run);
                t.push_back(run.seconds);
            }
            const double core_s = median(t);
            const auto complete = run.log.summarise(LatencyLog::Span::last_pixel_to_complete);
            const auto queued = run.log.summarise(LatencyLog::Span::last_pixel_to_queued);
            const auto written = run.log.summarise(LatencyLog::Span::last_pixel_to_written);
            std::size_t within = 0;
            for (const auto& rec : run.log.records()) within += rec.total_ns() <= 100'000;
            const double frac = written.count ? static_cast<double>(within) / static_cast<double>(written.count) : 0;
            const std::size_t errors = mismatches(ref, run.markers) + mismatches(run.markers, ref);
            const double ms_per_field = 1e3 * core_s / (3.0 * fields);
            // Precision mode's traffic: BlobPatch bytes per camera field (fields without patches count as 0).
            std::size_t patch_total = 0, patch_max = 0;
            for (const auto& [key, b] : run.patch_bytes) patch_total += b, patch_max = std::max(patch_max, b);
            const double patch_mean = static_cast<double>(patch_total) / (3.0 * fields);
            const double patch_mb_s = patch_mean * 3.0 * 50.0 / 1e6;
            if (json) {
                out.push_back({{"workload", name},
                               {"mode", ll ? "low_latency" : "per_field"},
                               {"fields", fields},
                               {"blobs", written.count},
                               {"latency_complete_us", js(complete)},
                               {"latency_queued_us", js(queued)},
                               {"latency_us", js(written)},
                               {"within_100us", frac},
                               {"errors", errors},
                               {"core_ms_per_field", ms_per_field},
                               {"core_vs_pipelines", core_s / peer},
                               {"patch_enable", g_patch_enable},
                               {"patches_sent", run.patches_sent},
                               {"patches_dropped", run.patches_dropped},
                               {"patches_too_large", run.patches_too_large},
                               {"patch_bytes_per_camera_field", {{"mean", patch_mean}, {"max", patch_max}}},
                               {"patch_mb_per_s", patch_mb_s}});
            } else {
                std::printf("| %s | %s | %zu | %.1f / %.1f | %.1f / %.1f | %.1f / %.1f / %.1f | %.1f %% | %zu | %.3f | "
                            "%.2fx |\n",
                            name.c_str(), ll ? "low-latency (per blob)" : "per field", written.count, complete.p50_us,
                            complete.p99_us, queued.p50_us, queued.p99_us, written.p50_us, written.p99_us,
                            written.max_us, 100.0 * frac, errors, ms_per_field, core_s / peer);
                if (g_patch_enable != 0) {
                    char row[512];
                    std::snprintf(row, sizeof row, "| %s | %s | %llu | %llu | %llu | %.0f / %zu | %.2f |\n", name.c_str(),
                                  ll ? "low-latency (per blob)" : "per field",
                                  static_cast<unsigned long long>(run.patches_sent),
                                  static_cast<unsigned long long>(run.patches_dropped),
                                  static_cast<unsigned long long>(run.patches_too_large), patch_mean, patch_max,
                                  patch_mb_s);
                    patch_rows.emplace_back(row);
                }
            }
        }
    }
    if (json) std::printf("%s\n", out.dump().c_str());
    if (!json && !patch_rows.empty()) {
        std::printf("\nPrecision mode (PATCH_ENABLE 0x%X on every camera):\n\n", g_patch_enable);
        std::printf("| workload | mode | patches sent | dropped | too large | BlobPatch bytes per camera field mean / max | "
                    "MB/s (3 cameras, 50 fields/s) |\n|---|---|---:|---:|---:|---:|---:|\n");
        for (const auto& r : patch_rows) std::printf("%s", r.c_str());
    }
    return 0;
}
