// Streaming emission, the cycle/latency model and storage that does not grow with field height.
#include "field_gen.hpp"

#include <catch2/catch.hpp>

using namespace eyesim::fpga;
using namespace eyesim::fpga::test;

TEST_CASE("a blob leaves during the line after its last line, not at field end", "[fpga][timing]") {
    std::vector<Marker> ms;
    for (int i = 0; i < 12; ++i) ms.push_back({1 + i % 4, 30.0 + 55 * i, 12.0 + 22 * i, 5.0, 2.5});
    const Field f = render_markers(ms, 1.0, 2);
    Pipeline p{RegisterMap{}};
    REQUIRE(p.begin_field(3, 0) == PipelineStatus::kOk);
    int seen = 0;
    for (int y = 0; y < 288; ++y) {
        REQUIRE(p.push_line(f.line(y), y) == PipelineStatus::kOk);
        Blob b;
        while (p.pop_blob(b)) {
            ++seen;
            CHECK(b.y_max + 1 == y);  // known complete on the first line without a continuing run
            CHECK(b.field_counter == 3);
            // Decided once the scan of line y passed x_last+1, then the divider.
            const uint32_t x_last = b.last_pixel_cycle - pixel_cycle(0, b.y_max);
            CHECK(b.last_pixel_cycle == pixel_cycle(x_last, b.y_max));
            CHECK(b.x_max >= x_last);
            CHECK(b.emit_cycle ==
                  pixel_cycle(std::min<uint32_t>(x_last + 2, 720), static_cast<uint32_t>(y)) + kPipelineDepthClocks +
                      kDividerLatencyClocks);
            CHECK(b.latency_cycles <= kClocksPerLine + 2 + kPipelineDepthClocks + kDividerLatencyClocks);
            CHECK(b.latency_us() < 100.0);  // DESIGN target: ≤ 100 µs after the last pixel
        }
    }
    REQUIRE(p.end_field() == PipelineStatus::kOk);
    CHECK(seen == 12);
    CHECK(p.pending_blobs() == 0);
}

TEST_CASE("last blob latency after the last active line; serial emission", "[fpga][timing]") {
    cv::Mat1b l(288, 720, uint8_t{0});
    for (int i = 0; i < 10; ++i) cv::rectangle(l, cv::Rect(10 + 60 * i, 280, 6, 8), 1 + i % 4, cv::FILLED);
    Pipeline p{RegisterMap{}};
    const auto blobs = run_field(p, field_from_labels(l));
    REQUIRE(blobs.size() == 10);
    std::vector<uint32_t> cycles;
    for (const Blob& b : blobs) {
        CHECK((b.flags & kBlobTouchesBottom) != 0);
        cycles.push_back(b.emit_cycle);
    }
    std::sort(cycles.begin(), cycles.end());
    for (size_t i = 1; i < cycles.size(); ++i) CHECK(cycles[i] - cycles[i - 1] == kEmitIntervalClocks);
    const FieldStats& s = p.field_stats();
    CHECK(s.last_active_line_end_cycle == active_line_end_cycle(287));
    CHECK(s.last_emit_cycle == cycles.back());
    // Ten blobs decided together at the end of line 287, emitted one per kEmitIntervalClocks.
    CHECK(s.last_blob_latency_cycles == kPipelineDepthClocks + kDividerLatencyClocks + 9 * kEmitIntervalClocks);
    CHECK(cycles_to_us(s.last_blob_latency_cycles) < 10.0);
}

TEST_CASE("skipped lines are background and complete open blobs", "[fpga][timing]") {
    cv::Mat1b l(288, 720, uint8_t{0});
    cv::rectangle(l, cv::Rect(100, 0, 20, 288), 1, cv::FILLED);  // a full-height bar
    const Field f = field_from_labels(l);
    Pipeline p{RegisterMap{}};
    std::vector<Blob> blobs;
    p.set_sink([](void* c, const Blob& b) { static_cast<std::vector<Blob>*>(c)->push_back(b); }, &blobs);
    p.begin_field(0, 0);
    for (int y = 0; y < 288; ++y)
        if (y % 50 != 49) p.push_line(f.line(y), y);  // drop every 50th line
    p.end_field();
    CHECK(blobs.size() == 6);
    for (const Blob& b : blobs) CHECK(b.area_px == 20u * (b.y_max - b.y_min + 1u));
}

TEST_CASE("storage does not grow with field height", "[fpga][storage]") {
    // The same stripe pattern in fields of 64, 288 and 512 lines: every high-water mark and the storage in bits
    // are identical.
    auto make = [](int h) {
        cv::Mat1b l(h, 720, uint8_t{0});
        for (int y = 0; y < h; y += 8)
            for (int x = 0; x < 720; x += 8) cv::rectangle(l, cv::Rect(x, y, 4 + (x / 8) % 3, 4), 1 + (x / 8) % 4, -1);
        return field_from_labels(l);
    };
    RegisterMap r;
    r.write(reg::kMinArea, 1);
    std::vector<uint64_t> bits;
    std::vector<uint32_t> occupancy, runs, blobs;
    for (int h : {64, 288, 512}) {
        Pipeline p(r);
        const Field f = make(h);
        REQUIRE(p.process_field(f.bytes.data(), h, 0, 0) == PipelineStatus::kOk);
        bits.push_back(p.storage_bits().total());
        occupancy.push_back(p.field_stats().max_table_occupancy);
        runs.push_back(p.field_stats().max_runs_per_line);
        blobs.push_back(p.field_stats().blobs_emitted + p.field_stats().dropped_blobs);
        Blob b;
        while (p.pop_blob(b)) {
        }
    }
    CHECK(bits[0] == bits[1]);
    CHECK(bits[1] == bits[2]);
    CHECK(occupancy[0] == occupancy[2]);
    CHECK(runs[0] == runs[2]);
    CHECK(occupancy[0] == 90);  // one row of 90 blobs alive at a time
    CHECK(blobs[2] == 64u * 90u);  // 8× the blobs of the short field, same tables
    // The figures documented in docs/fpga-pipeline.md.
    Pipeline p(r);
    const StorageBits s = p.storage_bits();
    CHECK(s.chroma_lut == 4096u * 3u);
    CHECK(s.run_buffers == 2u * 720u * (10u + 10u + 3u + 9u));
    CHECK(s.line_buffer == 720u * 16u + 4u * 720u + 90u * (2u * 12u + 1u) + 720u);
    CHECK(s.total() < 400'000u);
}

TEST_CASE("random bytes: no crash, bounded tables, invariants hold in every register mode", "[fpga][robust]") {
    std::mt19937 rng(77);
    std::uniform_int_distribution<int> byte(0, 255);
    Field f(288);
    for (uint8_t& b : f.bytes) b = static_cast<uint8_t>(byte(rng));
    for (int capacity : {4, 64, kMaxBlobSlots}) {
        for (uint32_t mode = 0; mode <= 2; ++mode) {
            RegisterMap r;
            r.write(reg::kMinArea, 1);
            r.write(reg::kWeightMode, mode);
            r.write(reg::kRoiEnable, capacity == 64 ? 0x3u : 0u);
            r.write(reg::roi_x(0), (400u << 16) | 10u);
            r.write(reg::roi_x(1), (719u << 16) | 300u);
            r.write(reg::roi_y(1), (287u << 16) | 100u);
            PipelineConfig cfg;
            cfg.blob_table_capacity = capacity;
            Pipeline p(r, cfg);
            for (int rep = 0; rep < 2; ++rep) {  // the table must be empty again after a field
                const std::vector<Blob> blobs = run_field(p, f, static_cast<uint32_t>(rep));
                const FieldStats& s = p.field_stats();
                CHECK(s.max_table_occupancy <= static_cast<uint32_t>(capacity));
                CHECK(s.max_runs_per_line <= 720u);
                uint64_t area = 0;
                for (const Blob& b : blobs) {
                    area += b.area_px;
                    CHECK(b.class_id >= 1);
                    CHECK(b.class_id <= 4);
                    CHECK(b.area_px <= (b.x_max - b.x_min + 1u) * (b.y_max - b.y_min + 1u));
                    CHECK(b.cx_px() >= b.x_min - 2.0);
                    CHECK(b.cx_px() <= b.x_max + 2.0);
                    CHECK(b.cy_px() >= b.y_min - 1.0);
                    CHECK(b.cy_px() <= b.y_max + 1.0);
                    CHECK(b.emit_cycle > b.last_pixel_cycle);
                }
                CHECK(area <= 720u * 288u);
                if (capacity < kMaxBlobSlots) CHECK(s.table_overflows > 0);
                CHECK(s.blobs_emitted == blobs.size());
            }
        }
    }
}
