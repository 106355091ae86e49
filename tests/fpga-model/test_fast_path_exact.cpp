// The software model's fast line path (one scan per line for the grey-box test of every 8-px cell and the cells'
// chroma sums; per-pixel classification only around out-of-box cells; background tracking from the kept cell sums)
// against the per-pixel path (FAST_PATH 0: every pixel classified, the background learnt from the stored line):
// every blob with every value and cycle, every field's counters and every captured patch identical, for each line
// scan (portable, SSE2, AVX2 where the CPU has it), on rig recordings and on generated fields, under many register
// settings.
#include "field_gen.hpp"
#if __has_include("eyesim/rig/recording.hpp")
#include "rig_fixture.hpp"
#define EYESIM_FAST_PATH_RIG_TEST 1
#endif

#include "eyesim/fpga/patch_capture.hpp"

#include <catch2/catch.hpp>

#include <cstddef>
#include <cstring>
#include <random>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

using namespace eyesim::fpga;
using namespace eyesim::fpga::test;

namespace {

using Writes = std::vector<std::pair<uint16_t, uint32_t>>;

struct Setting {
    std::string name;
    Writes writes;
};

// Register settings the fast path must not change anything under (PATCH_ENABLE on in most).
std::vector<Setting> settings() {
    const uint32_t roi_a = (200u << 16) | 0u, roi_a_y = (120u << 16) | 0u;      // top-left corner window
    const uint32_t roi_b = (719u << 16) | 333u, roi_b_y = (287u << 16) | 101u;  // bottom-right, odd x0
    return {
        {"reset", {}},
        {"patches", {{reg::kPatchEnable, 0xF}}},
        {"map 1.1 (BG_TRACK 0, levels 3/3/3/5)", {{reg::kBgTrack, 0}, {reg::kWeightBg, 0x05030303u}, {reg::kPatchEnable, 0x5}}},
        {"BG_TRACK 1", {{reg::kBgTrack, 1}, {reg::kPatchEnable, 0xF}}},
        {"BG_TRACK 7", {{reg::kBgTrack, 7}}},
        {"binary", {{reg::kWeightMode, 0}, {reg::kPatchEnable, 0xF}}},
        {"luma", {{reg::kWeightMode, 2}, {reg::kWeightBg, 0x1E1E1E1Eu}}},
        {"4-bit weights, no ring", {{reg::kWeightBits, 4}, {reg::kEdgeRing, 0}}},
        {"SAT_MIN 40 (wide box)", {{reg::class_sat(1), 0xFF28}, {reg::class_sat(2), 0xFF28}, {reg::class_sat(3), 0xFF28},
                                   {reg::class_sat(4), 0xFF28}, {reg::kPatchEnable, 0xF}}},
        {"SAT_MIN 5 (narrow box)", {{reg::class_sat(1), 0xFF05}, {reg::class_sat(2), 0xFF05}}},
        {"classes 2, 4 only, MIN_AREA 1", {{reg::kClassEnable, 0xA}, {reg::kMinArea, 1}}},
        {"BG_OFFSET", {{reg::kBgOffset, 1}, {reg::kPatchEnable, 0x3}}},
        {"BG_OFFSET, ROI windows", {{reg::kBgOffset, 1}, {reg::kRoiEnable, 0x3}, {reg::roi_x(0), roi_a}, {reg::roi_y(0), roi_a_y},
                                    {reg::roi_x(1), roi_b}, {reg::roi_y(1), roi_b_y}}},
        {"ROI windows", {{reg::kRoiEnable, 0x3}, {reg::roi_x(0), roi_a}, {reg::roi_y(0), roi_a_y},
                         {reg::roi_x(1), roi_b}, {reg::roi_y(1), roi_b_y}, {reg::kPatchEnable, 0xF}}},
    };
}

// How a field is fed: process_field (the field in memory), line by line with patch capture, or line by line with
// lines left out (each gap is background and completes the open blobs).
enum class Feed { kProcessField, kLinesWithPatches, kLinesWithGaps };

// A captured patch without its unused sample capacity (fields with thousands of tiny blobs capture thousands).
struct PatchCopy {
    uint8_t camera, parity, class_id, flags;
    uint32_t field_counter;
    uint16_t blob_index, origin_x, origin_y, width_px, height_px;
    std::vector<uint8_t> samples;
};

struct Output {
    std::vector<Blob> blobs;
    std::vector<FieldStats> stats;
    std::vector<PatchCopy> patches;
    ScanIsa isa = ScanIsa::kAuto;
    uint64_t skipped_px = 0;  // FieldStats::fast_path_pixels, summed
};

Output run(const std::vector<const uint8_t*>& fields, const Setting& s, bool fast, ScanIsa isa) {
    RegisterMap regs;
    for (const auto& [a, v] : s.writes) REQUIRE(regs.write(a, v) == RegWriteResult::kOk);
    REQUIRE(regs.write(reg::kFastPath, fast ? 1 : 0) == RegWriteResult::kOk);
    PipelineConfig cfg;
    cfg.scan_isa = isa;
    Pipeline pipe(regs, cfg);
    PatchCapture cap(0);
    Output out;
    out.isa = pipe.scan_isa();
    struct Ctx {
        Output* out;
        PatchCapture* cap;
        uint16_t first;  // index of the field's first blob in out->blobs
    } ctx{&out, &cap, 0};
    pipe.set_sink(
        [](void* c, const Blob& b) {
            auto* x = static_cast<Ctx*>(c);
            x->cap->add_blob(b, static_cast<uint16_t>(x->out->blobs.size() - x->first));
            x->out->blobs.push_back(b);
        },
        &ctx);
    cap.set_sink(
        [](void* c, const Patch& p) {
            PatchCopy copy{p.camera,   p.parity,   p.class_id, p.flags,    p.field_counter, p.blob_index,
                           p.origin_x, p.origin_y, p.width_px, p.height_px, {}};
            copy.samples.assign(p.samples.begin(), p.samples.begin() + static_cast<std::ptrdiff_t>(p.bytes()));
            static_cast<Output*>(c)->patches.push_back(std::move(copy));
        },
        &out);
    for (size_t i = 0; i < fields.size(); ++i) {
        const uint32_t counter = static_cast<uint32_t>(i);
        const uint8_t parity = static_cast<uint8_t>(i & 1);
        ctx.first = static_cast<uint16_t>(out.blobs.size());
        const Feed feed = static_cast<Feed>(i % 3);
        if (feed == Feed::kProcessField) {
            REQUIRE(pipe.process_field(fields[i], 288, counter, parity) == PipelineStatus::kOk);
        } else {
            REQUIRE(pipe.begin_field(counter, parity) == PipelineStatus::kOk);
            cap.begin_field(pipe.params(), counter, parity);
            // A reused line buffer, as the firmware's line FIFO: the pipeline must keep its own copy.
            std::vector<uint8_t> line(kLineBytes);
            bool pushed = true;
            for (int y = 0; y < 288; ++y) {
                if (feed == Feed::kLinesWithGaps && (y % 53 == 52 || (y >= 200 && y < 203))) continue;
                std::memcpy(line.data(), fields[i] + static_cast<size_t>(y) * kLineBytes, kLineBytes);
                cap.push_line(line.data(), y);
                pushed = pushed && pipe.push_line(line.data(), y) == PipelineStatus::kOk;
            }
            REQUIRE(pushed);
            REQUIRE(pipe.end_field() == PipelineStatus::kOk);
            cap.end_field();
        }
        FieldStats st = pipe.field_stats();
        out.skipped_px += st.fast_path_pixels;
        st.fast_path_pixels = 0;  // what the model skipped, not an output
        out.stats.push_back(st);
    }
    return out;
}

std::string blob_diff(const Blob& a, const Blob& b) {
    std::ostringstream o;
    auto f = [&](const char* name, auto x, auto y) {
        if (x != y) o << name << " " << +x << " vs " << +y << "; ";
    };
    f("field", a.field_counter, b.field_counter);
    f("index", a.index, b.index);
    f("camera", a.camera, b.camera);
    f("class", a.class_id, b.class_id);
    f("flags", a.flags, b.flags);
    f("parity", a.parity, b.parity);
    f("area", a.area_px, b.area_px);
    f("x_min", a.x_min, b.x_min);
    f("x_max", a.x_max, b.x_max);
    f("y_min", a.y_min, b.y_min);
    f("y_max", a.y_max, b.y_max);
    f("sum_w", a.sum_w, b.sum_w);
    f("sum_wx", a.sum_wx, b.sum_wx);
    f("sum_wy", a.sum_wy, b.sum_wy);
    f("sum_wxx", a.sum_wxx, b.sum_wxx);
    f("sum_wyy", a.sum_wyy, b.sum_wyy);
    f("sum_wxy", a.sum_wxy, b.sum_wxy);
    f("pos_count", a.pos_count, b.pos_count);
    f("pos_sum_x", a.pos_sum_x, b.pos_sum_x);
    f("band_sum_r", a.band_sum_r, b.band_sum_r);
    f("band_count", a.band_count, b.band_count);
    f("cx_q16", a.cx_q16, b.cx_q16);
    f("cy_q16", a.cy_q16, b.cy_q16);
    f("last_pixel_cycle", a.last_pixel_cycle, b.last_pixel_cycle);
    f("emit_cycle", a.emit_cycle, b.emit_cycle);
    f("latency_cycles", a.latency_cycles, b.latency_cycles);
    f("ref_sum_w", a.ref_sum_w, b.ref_sum_w);
    return o.str();
}

std::string stats_diff(const FieldStats& a, const FieldStats& b) {
    std::ostringstream o;
    auto f = [&](const char* name, uint32_t x, uint32_t y) {
        if (x != y) o << name << " " << x << " vs " << y << "; ";
    };
    f("field_counter", a.field_counter, b.field_counter);
    f("lines", a.lines, b.lines);
    f("runs", a.runs, b.runs);
    f("merges", a.merges, b.merges);
    f("blobs_emitted", a.blobs_emitted, b.blobs_emitted);
    f("blobs_filtered", a.blobs_filtered, b.blobs_filtered);
    f("table_overflows", a.table_overflows, b.table_overflows);
    f("dropped_blobs", a.dropped_blobs, b.dropped_blobs);
    f("max_table_occupancy", a.max_table_occupancy, b.max_table_occupancy);
    f("max_runs_per_line", a.max_runs_per_line, b.max_runs_per_line);
    f("fast_path_pixels", a.fast_path_pixels, b.fast_path_pixels);
    f("ring_pixels", a.ring_pixels, b.ring_pixels);
    f("last_active_line_end_cycle", a.last_active_line_end_cycle, b.last_active_line_end_cycle);
    f("last_emit_cycle", a.last_emit_cycle, b.last_emit_cycle);
    f("last_blob_latency_cycles", a.last_blob_latency_cycles, b.last_blob_latency_cycles);
    return o.str();
}

std::string patch_diff(const PatchCopy& a, const PatchCopy& b) {
    std::ostringstream o;
    if (a.camera != b.camera || a.parity != b.parity || a.class_id != b.class_id || a.flags != b.flags ||
        a.field_counter != b.field_counter || a.blob_index != b.blob_index || a.origin_x != b.origin_x ||
        a.origin_y != b.origin_y || a.width_px != b.width_px || a.height_px != b.height_px)
        o << "header (field " << a.field_counter << " blob " << a.blob_index << " vs field " << b.field_counter
          << " blob " << b.blob_index << "); ";
    else if (a.samples != b.samples)
        o << "samples of field " << a.field_counter << " blob " << a.blob_index << "; ";
    return o.str();
}

// Runs the per-pixel path and the fast path with every line scan on `fields` under every setting; returns the
// blobs the reference found (so the caller can check the fields were not trivially empty).
size_t check_identical(const std::vector<const uint8_t*>& fields, const std::string& what) {
    size_t blobs = 0;
    for (const Setting& s : settings()) {
        const Output ref = run(fields, s, false, ScanIsa::kScalar);
        REQUIRE(ref.skipped_px == 0);
        blobs += ref.blobs.size();
        for (const ScanIsa isa : {ScanIsa::kScalar, ScanIsa::kSse2, ScanIsa::kAvx2, ScanIsa::kAvx512, ScanIsa::kAuto}) {
            const Output got = run(fields, s, true, isa);
            INFO(what << ", " << s.name << ", line scan " << static_cast<int>(got.isa));
            if (isa == ScanIsa::kScalar) CHECK(got.isa == ScanIsa::kScalar);
            CHECK(got.isa != ScanIsa::kAuto);
            REQUIRE(got.blobs.size() == ref.blobs.size());
            REQUIRE(got.stats.size() == ref.stats.size());
            REQUIRE(got.patches.size() == ref.patches.size());
            std::string first;
            int mismatches = 0;
            for (size_t i = 0; i < ref.blobs.size(); ++i) {
                const std::string d = blob_diff(got.blobs[i], ref.blobs[i]);
                if (!d.empty() && mismatches++ == 0) first = "blob " + std::to_string(i) + ": " + d;
            }
            for (size_t i = 0; i < ref.stats.size(); ++i) {
                const std::string d = stats_diff(got.stats[i], ref.stats[i]);
                if (!d.empty() && mismatches++ == 0) first = "field " + std::to_string(i) + " stats: " + d;
            }
            for (size_t i = 0; i < ref.patches.size(); ++i) {
                const std::string d = patch_diff(got.patches[i], ref.patches[i]);
                if (!d.empty() && mismatches++ == 0) first = "patch " + std::to_string(i) + ": " + d;
            }
            INFO("first difference: " << first);
            CHECK(mismatches == 0);
        }
    }
    return blobs;
}

// Chroma in or just around the grey box the fast path trusts (half-width 8 at reset, 5..9 under the settings),
// luma anywhere, and single coloured pixels on both sides of every cell boundary.
std::vector<uint8_t> near_grey_field(uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_int_distribution<int> dc(-11, 11), dy(0, 255), pick(0, 99), cls(1, 4);
    std::vector<uint8_t> f(288 * kLineBytes);
    for (size_t i = 0; i < f.size(); i += 2) {
        f[i] = static_cast<uint8_t>(128 + (pick(rng) < 70 ? dc(rng) / 3 : dc(rng)));
        f[i + 1] = static_cast<uint8_t>(dy(rng));
    }
    for (int y = 0; y < 288; ++y)
        for (int x : {0, 1, 6, 7, 8, 9, 15, 16, 711, 712, 718, 719}) {
            if (pick(rng) < 80) continue;
            const auto& c = kColours[static_cast<size_t>(cls(rng))];
            const Ycc ycc = rgb_to_ycc(c[0], c[1], c[2]);
            uint8_t* q = f.data() + static_cast<size_t>(y) * kLineBytes + 4 * static_cast<size_t>(x / 2);
            q[0] = to_byte(ycc.cb);
            q[2] = to_byte(ycc.cr);
            q[1 + 2 * (x & 1)] = to_byte(ycc.y);
        }
    return f;
}

}  // namespace

TEST_CASE("fast line path identical to the per-pixel path on generated fields", "[fpga][exact][fastpath]") {
    std::vector<std::vector<uint8_t>> store;
    // Uniform random bytes: runs of every class everywhere, table overflows, every cell out of the box.
    std::mt19937 rng(21);
    std::uniform_int_distribution<int> byte(0, 255);
    for (int i = 0; i < 2; ++i) {
        store.emplace_back(288 * kLineBytes);
        for (uint8_t& b : store.back()) b = static_cast<uint8_t>(byte(rng));
    }
    // Near-grey noise with single coloured pixels at cell boundaries and the field's edges.
    for (uint32_t seed : {1u, 2u, 3u}) store.push_back(near_grey_field(seed));
    // Anti-aliased noisy markers on dark, grey and tinted backgrounds, many across the field's four edges and in
    // its corners, touching each other.
    std::uniform_real_distribution<double> ux(-6, 726), uy(-3, 291), ur(1.5, 9.0);
    std::uniform_int_distribution<int> uc(1, 4);
    const std::array<std::array<double, 3>, 3> bgs{{{14, 14, 18}, {120, 118, 124}, {236, 226, 200}}};
    for (int i = 0; i < 6; ++i) {
        std::vector<Marker> ms;
        for (int k = 0; k < 50; ++k) {
            const double r = ur(rng);
            ms.push_back({uc(rng), ux(rng), uy(rng), r, r / 2});
        }
        const std::array<std::pair<double, double>, 8> edges{{{0.5, 0.5}, {719.0, 0.0}, {0.0, 287.5}, {718.5, 287.0},
                                                              {360.0, 0.0}, {360.0, 287.0}, {0.0, 144.0}, {719.0, 144.0}}};
        for (const auto& [cx, cy] : edges) ms.push_back({uc(rng), cx, cy, 5.0, 2.5});
        const Field f = render_markers(ms, i % 2 == 0 ? 1.0 : 3.0, static_cast<uint32_t>(100 + i), 288, 4,
                                       bgs[static_cast<size_t>(i % 3)]);
        store.push_back(f.bytes);
    }
    std::vector<const uint8_t*> fields;
    for (const auto& f : store) fields.push_back(f.data());
    CHECK(check_identical(fields, "generated fields") > 1000);
}

#if defined(EYESIM_FAST_PATH_RIG_TEST)
TEST_CASE("fast line path identical to the per-pixel path on rig recordings", "[fpga][exact][fastpath][rig]") {
    for (const char* scenario : {"sweep", "fast", "occlusion", "surgery"}) {
        RigRecording rr(std::string("eyesim_fpga_fastpath_") + scenario, scenario, 0.06, 1.0);  // 3 fields × 3 cameras
        std::vector<std::vector<uint8_t>> store;
        for (int cam = 0; cam < rr.rec.camera_count(); ++cam)
            for (int64_t i = 0; i < 3 && i < rr.rec.common_field_count(); ++i) {
                store.emplace_back(static_cast<size_t>(eyesim::rig::kFieldBytes));
                REQUIRE(rr.rec.read_field(cam, i, store.back().data()));
            }
        REQUIRE(store.size() >= 6);
        std::vector<const uint8_t*> fields;
        for (const auto& f : store) fields.push_back(f.data());
        CHECK(check_identical(fields, scenario) > 20);
    }
}
#endif
