// The FPGA model alone on a recording: thread CPU time per 720x288 field under several register settings (the
// fast line path and, beside it, the per-pixel path FAST_PATH 0), an output digest per setting (every blob value
// and cycle and every field counter but fast_path_pixels: equal digests = identical output), and a plain read
// pass over the same fields, the memory-read limit a field's 414 720 bytes set on this machine.
//
// Usage: bench_fpga_fields RECORDING_DIR [passes=5] [--json]
//   (make a recording with: eyesim synth --scenario surgery --seconds 2 --out DIR)
// Each pass runs every field of every camera once (all fields held in memory, read once before timing); the figure
// is the median over passes of the pass's thread CPU time / fields.
#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/rig/recording.hpp"
#include "thread_cpu.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <exception>
#include <string>
#include <utility>
#include <vector>

namespace fpga = eyesim::fpga;
namespace rig = eyesim::rig;

namespace {

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}

// FNV-1a over the output.
struct Digest {
    uint64_t h = 1469598103934665603ull;
    template <class T>
    void add(const T& v) {
        const auto* b = reinterpret_cast<const uint8_t*>(&v);
        for (size_t i = 0; i < sizeof v; ++i) {
            h ^= b[i];
            h *= 1099511628211ull;
        }
    }
    void add(const fpga::Blob& b) {
        add(b.field_counter), add(b.index), add(b.class_id), add(b.flags), add(b.parity), add(b.area_px);
        add(b.x_min), add(b.x_max), add(b.y_min), add(b.y_max), add(b.sum_w), add(b.sum_wx), add(b.sum_wy);
        add(b.sum_wxx), add(b.sum_wyy), add(b.sum_wxy), add(b.cx_q16), add(b.cy_q16), add(b.last_pixel_cycle);
        add(b.emit_cycle), add(b.latency_cycles);
    }
    void add(const fpga::FieldStats& s) {
        add(s.field_counter), add(s.lines), add(s.runs), add(s.merges), add(s.blobs_emitted), add(s.blobs_filtered);
        add(s.table_overflows), add(s.dropped_blobs), add(s.max_table_occupancy), add(s.max_runs_per_line);
        add(s.ring_pixels), add(s.last_active_line_end_cycle), add(s.last_emit_cycle), add(s.last_blob_latency_cycles);
    }
};

struct Setting {
    const char* name;
    std::vector<std::pair<uint16_t, uint32_t>> writes;
};

}  // namespace

int main(int argc, char** argv) {
    std::string dir;
    int passes = 5;
    bool json = false;
    std::string only;  // --setting NAME: run that setting alone (e.g. under a profiler)
    int positional = 0;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--json") {
            json = true;
        } else if (a == "--setting" && i + 1 < argc) {
            only = argv[++i];
        } else if (positional == 0) {
            dir = a;
            ++positional;
        } else if (positional == 1) {
            char* end = nullptr;
            const long v = std::strtol(a.c_str(), &end, 10);
            if (*end != '\0' || v < 1 || v > 1000) {
                std::fprintf(stderr, "eyesim: error: passes: an integer 1..1000\n");
                return 2;
            }
            passes = static_cast<int>(v);
            ++positional;
        } else {
            std::fprintf(stderr, "eyesim: error: unexpected argument %s\nusage: bench_fpga_fields RECORDING_DIR [passes=5] [--json] [--setting NAME]\n",
                         a.c_str());
            return 2;
        }
    }
    if (dir.empty()) {
        std::fprintf(stderr, "eyesim: error: no recording\nusage: bench_fpga_fields RECORDING_DIR [passes=5] [--json] [--setting NAME]\n");
        return 2;
    }
    std::vector<std::vector<uint8_t>> fields;
    try {
        rig::Recording rec = rig::Recording::open(dir);
        for (int c = 0; c < rec.camera_count(); ++c)
            for (int64_t i = 0; i < rec.common_field_count(); ++i) {
                fields.emplace_back(static_cast<size_t>(rig::kFieldBytes));
                if (!rec.read_field(c, i, fields.back().data())) {
                    std::fprintf(stderr, "eyesim: error: %s: camera %d field %lld unreadable\n", dir.c_str(), c,
                                 static_cast<long long>(i));
                    return 1;
                }
            }
    } catch (const std::exception& e) {
        std::fprintf(stderr, "eyesim: error: %s\n", e.what());
        return 1;
    }
    if (fields.empty()) {
        std::fprintf(stderr, "eyesim: error: %s: no fields\n", dir.c_str());
        return 1;
    }

    const std::vector<Setting> settings = {
        {"reset", {}},
        {"map 1.1 (BG_TRACK 0, levels 3/3/3/5)", {{fpga::reg::kBgTrack, 0}, {fpga::reg::kWeightBg, 0x05030303u}}},
        {"binary", {{fpga::reg::kWeightMode, 0}}},
        {"no edge ring", {{fpga::reg::kEdgeRing, 0}}},
        {"BG_OFFSET", {{fpga::reg::kBgOffset, 1}}},
        {"reset, per-pixel path (FAST_PATH 0)", {{fpga::reg::kFastPath, 0}}},
    };
    nlohmann::json out = {{"recording", dir}, {"fields", fields.size()}, {"passes", passes}};
    if (!json)
        std::printf("recording %s: %zu fields (all cameras), %d passes, thread CPU per field (median of passes)\n\n"
                    "| registers | us per field | blobs | output digest |\n|---|---:|---:|---|\n",
                    dir.c_str(), fields.size(), passes);
    std::vector<fpga::Blob> blobs;
    blobs.reserve(1024);
    for (const Setting& s : settings) {
        if (!only.empty() && only != s.name) continue;
        fpga::RegisterMap regs;
        for (const auto& [a, v] : s.writes) regs.write(a, v);
        fpga::Pipeline pipe(regs);
        pipe.set_sink([](void* c, const fpga::Blob& b) { static_cast<std::vector<fpga::Blob>*>(c)->push_back(b); },
                      &blobs);
        Digest d;
        size_t n_blobs = 0;
        for (size_t i = 0; i < fields.size(); ++i) {  // untimed: the digest
            blobs.clear();
            pipe.process_field(fields[i].data(), rig::kFieldHeight, static_cast<uint32_t>(i), static_cast<uint8_t>(i & 1));
            for (const fpga::Blob& b : blobs) d.add(b);
            d.add(pipe.field_stats());
            n_blobs += blobs.size();
        }
        std::vector<double> us;
        for (int p = 0; p < passes; ++p) {
            const double t0 = eyesim::bench::thread_cpu_s();
            for (size_t i = 0; i < fields.size(); ++i) {
                blobs.clear();
                pipe.process_field(fields[i].data(), rig::kFieldHeight, static_cast<uint32_t>(i), static_cast<uint8_t>(i & 1));
            }
            us.push_back((eyesim::bench::thread_cpu_s() - t0) / static_cast<double>(fields.size()) * 1e6);
        }
        char digest[17];
        std::snprintf(digest, sizeof digest, "%016llx", static_cast<unsigned long long>(d.h));
        if (json)
            out["settings"][s.name] = {{"us_per_field", median(us)}, {"blobs", n_blobs}, {"digest", digest}};
        else
            std::printf("| %s | %.1f | %zu | %s |\n", s.name, median(us), n_blobs, digest);
    }
    // Memory-read limit: every byte of every field read once per pass (64-bit loads, summed so nothing is elided).
    std::vector<double> us;
    uint64_t sink = 0;
    for (int p = 0; p < passes; ++p) {
        const double t0 = eyesim::bench::thread_cpu_s();
        for (const auto& f : fields) {
            uint64_t acc = 0;
            for (size_t k = 0; k + 8 <= f.size(); k += 8) {
                uint64_t v;
                std::memcpy(&v, f.data() + k, 8);
                acc += v;
            }
            sink += acc;
        }
        us.push_back((eyesim::bench::thread_cpu_s() - t0) / static_cast<double>(fields.size()) * 1e6);
    }
    if (json) {
        out["read_pass_us_per_field"] = median(us);
        std::printf("%s\n", out.dump().c_str());
    } else {
        std::printf("\nread pass (every byte once, 64-bit loads): %.1f us per field (checksum bit %llu)\n", median(us),
                    static_cast<unsigned long long>(sink & 1));
    }
    return 0;
}
