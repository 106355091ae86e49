// Register map: table, write validation, reset classification of the default colours, field-boundary semantics,
// class enables and ROI windows.
#include "field_gen.hpp"

#include <catch2/catch.hpp>

#include <cstring>
#include <set>

using namespace eyesim::fpga;
using namespace eyesim::fpga::test;

TEST_CASE("register table: unique aligned addresses, reset values valid", "[fpga][regs]") {
    std::set<uint16_t> seen;
    RegisterMap r;
    for (const RegisterInfo& info : register_table()) {
        INFO(info.name);
        CHECK(info.address % 4 == 0);
        CHECK(seen.insert(info.address).second);
        CHECK((info.width_bits == 32 || (info.reset_value >> info.width_bits) == 0));
        CHECK(r.get(info.address) == info.reset_value);
        CHECK(find_register(info.address) == &info);
        if (info.writable) CHECK(r.check_write(info.address, info.reset_value) == RegWriteResult::kOk);
    }
    CHECK(r.get(reg::kId) == 0x45594650u);
}

TEST_CASE("register writes are validated: address, alignment, width, read-only, range", "[fpga][regs]") {
    RegisterMap r;
    const uint32_t gen = r.generation();
    CHECK(r.write(0x3FC, 1) == RegWriteResult::kUnknownAddress);
    CHECK(r.write(reg::kMinArea + 2, 1) == RegWriteResult::kMisaligned);
    CHECK(r.write(reg::kMinArea, 1, 2) == RegWriteResult::kBadWidth);
    CHECK(r.write(reg::kId, 0) == RegWriteResult::kReadOnly);
    CHECK(r.write(reg::kVersion, 0x0102) == RegWriteResult::kReadOnly);
    CHECK(r.write(reg::kClassEnable, 0x1F) == RegWriteResult::kTooWide);
    CHECK(r.write(reg::kEnable, 2) == RegWriteResult::kTooWide);
    CHECK(r.write(reg::kWeightMode, 3) == RegWriteResult::kOutOfRange);
    CHECK(r.write(reg::kWeightBits, 0) == RegWriteResult::kOutOfRange);
    CHECK(r.write(reg::kWeightBits, 9) == RegWriteResult::kOutOfRange);
    CHECK(r.write(reg::kMinArea, 0) == RegWriteResult::kOutOfRange);
    CHECK(r.write(reg::kMaxArea, 720u * 288u + 1) == RegWriteResult::kOutOfRange);
    CHECK(r.write(reg::kMaxAspectQ4, 15) == RegWriteResult::kOutOfRange);
    CHECK(r.write(reg::roi_x(1), (100u << 16) | 200u) == RegWriteResult::kOutOfRange);   // x0 > x1
    CHECK(r.write(reg::roi_x(1), (720u << 16) | 0u) == RegWriteResult::kOutOfRange);     // x1 > 719
    CHECK(r.write(reg::roi_y(3), (10u << 16) | 20u) == RegWriteResult::kOutOfRange);     // y0 > y1
    CHECK(r.write(reg::class_sat(2), (10u << 8) | 20u) == RegWriteResult::kOutOfRange);  // min > max
    CHECK(r.write(reg::class_hue(4), 77u) == RegWriteResult::kOutOfRange);               // zero half-width
    CHECK(r.generation() == gen);  // nothing accepted so far
    for (const RegisterInfo& info : register_table()) CHECK(r.get(info.address) == info.reset_value);
    CHECK(r.write(reg::kMinArea, 5) == RegWriteResult::kOk);
    CHECK(r.get(reg::kMinArea) == 5);
    CHECK(r.generation() != gen);
    uint32_t v = 0;
    CHECK_FALSE(r.read(0x3FC, v));
    CHECK(r.read(reg::roi_y(0), v));
    CHECK(v == (287u << 16));
    CHECK(std::string(to_string(RegWriteResult::kOutOfRange)) == "out_of_range");
    r.reset();
    CHECK(r.get(reg::kMinArea) == find_register(reg::kMinArea)->reset_value);
}

TEST_CASE("reset values classify exactly the four default colours as classes 1..4", "[fpga][regs]") {
    RegisterMap r;
    Pipeline p(r);
    for (int c = 1; c <= 4; ++c) {
        for (double gain : {1.0, 0.75, 0.5}) {  // lit and shaded
            const auto& rgb = kColours[static_cast<size_t>(c)];
            const Ycc y = rgb_to_ycc(gain * rgb[0], gain * rgb[1], gain * rgb[2]);
            INFO("class " << c << " gain " << gain);
            CHECK(p.classify(to_byte(y.y), to_byte(y.cb), to_byte(y.cr)) == c);
        }
    }
    // Neutral and other colours are background, among them the rig's white eye (236, 234, 226) and a bluish grey.
    // (Low-saturation reds such as skin, sat ≈ 17, would need a higher SAT_MIN than the reset 12.)
    const std::vector<std::array<double, 3>> others{{0, 0, 0},       {255, 255, 255}, {128, 128, 128},
                                                    {60, 60, 60},    {200, 40, 200},  {40, 200, 200},
                                                    {230, 120, 40},  {100, 100, 110}, {236, 234, 226}};
    for (const auto& o : others) {
        const Ycc y = rgb_to_ycc(o[0], o[1], o[2]);
        INFO(o[0] << "," << o[1] << "," << o[2]);
        CHECK(p.classify(to_byte(y.y), to_byte(y.cb), to_byte(y.cr)) == 0);
    }
    // Every LUT cell holds a class 0..4, and each class owns cells.
    std::array<int, 5> count{};
    for (int cb = 0; cb < 256; cb += 4)
        for (int cr = 0; cr < 256; cr += 4) ++count[p.lut_class(static_cast<uint8_t>(cb), static_cast<uint8_t>(cr))];
    for (int c = 1; c <= 4; ++c) CHECK(count[static_cast<size_t>(c)] > 20);
    CHECK(p.fast_path_half_width() >= 6);  // box half-width ≈ SAT_MIN/√2 less the LUT cell size
}

TEST_CASE("register writes take effect at the next field boundary", "[fpga][regs]") {
    std::vector<Marker> ms;
    for (int i = 0; i < 8; ++i) ms.push_back({1 + i % 4, 40.0 + 80 * i, 40.0 + 25 * i, 6.0, 3.0});
    const Field f = render_markers(ms, 1.0, 3);
    RegisterMap regs;
    Pipeline p(&regs);  // live map
    auto count_class1 = [&](uint32_t counter, bool write_mid_field) {
        std::vector<Blob> blobs;
        p.set_sink([](void* c, const Blob& b) { static_cast<std::vector<Blob>*>(c)->push_back(b); }, &blobs);
        REQUIRE(p.begin_field(counter, 0) == PipelineStatus::kOk);
        for (int y = 0; y < 288; ++y) {
            if (write_mid_field && y == 10) REQUIRE(regs.write(reg::kClassEnable, 0xE) == RegWriteResult::kOk);
            REQUIRE(p.push_line(f.line(y), y) == PipelineStatus::kOk);
        }
        REQUIRE(p.end_field() == PipelineStatus::kOk);
        return std::count_if(blobs.begin(), blobs.end(), [](const Blob& b) { return b.class_id == 1; });
    };
    CHECK(count_class1(0, true) == 2);   // written before any class-1 marker, yet this field keeps class 1
    CHECK(count_class1(1, false) == 0);  // next field: disabled
    REQUIRE(regs.write(reg::kClassEnable, 0xF) == RegWriteResult::kOk);
    CHECK(count_class1(2, false) == 2);

    // A snapshot pipeline ignores later writes to the caller's map until set_registers.
    RegisterMap mine;
    Pipeline snap(mine);
    mine.write(reg::kEnable, 0);
    CHECK(run_field(snap, f).size() == 8);
    snap.set_registers(mine);
    CHECK(run_field(snap, f).empty());
}

TEST_CASE("per-class enables and area/shape filters", "[fpga][regs]") {
    std::vector<Marker> ms{{1, 100, 50, 6, 3}, {2, 200, 50, 6, 3}, {3, 300, 50, 6, 3}, {4, 400, 50, 6, 3},
                           {1, 500, 50, 1.2, 0.8}, {2, 600, 150, 40, 2}};
    const Field f = render_markers(ms, 0.0, 1);
    RegisterMap r;
    r.write(reg::kMaxArea, 720u * 288u);
    r.write(reg::kMinArea, 1);
    {
        Pipeline p(r);
        CHECK(run_field(p, f).size() == 6);
    }
    r.write(reg::kClassEnable, 0x5);  // classes 1 and 3
    {
        Pipeline p(r);
        const auto b = run_field(p, f);
        CHECK(b.size() == 3);
        for (const Blob& x : b) CHECK((x.class_id == 1 || x.class_id == 3));
    }
    r.write(reg::kClassEnable, 0xF);
    r.write(reg::kMinArea, 8);  // drops the tiny marker
    r.write(reg::kMaxAspectQ4, 6 * 16);  // drops the 80×4 bar (aspect 20) but keeps 12×6 ellipses
    r.write(reg::kMinFillQ8, 128);  // ellipse fill ≈ π/4 passes
    Pipeline p(r);
    const auto b = run_field(p, f);
    CHECK(b.size() == 4);
    CHECK(p.field_stats().blobs_filtered == 2);
}

TEST_CASE("WEIGHT_BG holds one background level per class (byte c-1 for class c)", "[fpga][regs]") {
    RegisterMap r;
    CHECK(decode(r).weight_bg == std::array<uint8_t, kNumClasses + 1>{0, 2, 2, 2, 3});  // reset 0x03020202
    REQUIRE(r.write(reg::kWeightBg, 0x04030201u) == RegWriteResult::kOk);
    CHECK(decode(r).weight_bg == std::array<uint8_t, kNumClasses + 1>{0, 1, 2, 3, 4});
    // A level reaches only its own class: raise one byte at a time and compare every blob's Σw with level 0.
    const std::vector<Marker> ms{{1, 100, 50, 5, 2.5}, {2, 200, 50, 5, 2.5}, {3, 300, 50, 5, 2.5},
                                 {4, 400, 50, 5, 2.5}};
    const Field f = render_markers(ms, 0.0, 1, 288, 8, {14, 14, 18});
    auto sums = [&](uint32_t bg) {
        RegisterMap m;
        m.write(reg::kWeightBg, bg);
        Pipeline p(m);
        std::array<uint64_t, kNumClasses + 1> sw{};
        for (const Blob& b : run_field(p, f)) sw[b.class_id] = b.sum_w;
        return sw;
    };
    const auto base = sums(0);
    for (int c = 1; c <= kNumClasses; ++c) REQUIRE(base[c] > 0);
    for (int c = 1; c <= kNumClasses; ++c) {
        const auto raised = sums(10u << (8 * (c - 1)));
        INFO("level 10 for class " << c);
        for (int k = 1; k <= kNumClasses; ++k) {
            if (k == c)
                CHECK(raised[k] < base[k]);
            else
                CHECK(raised[k] == base[k]);
        }
    }
}

TEST_CASE("ROI windows: only pixels inside enabled windows count, clipped blobs flagged", "[fpga][regs][exact]") {
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> ux(5, 715), uy(3, 285);
    std::vector<Marker> ms;
    for (int i = 0; i < 60; ++i) ms.push_back({1 + i % 4, ux(rng), uy(rng), 6.0, 3.0});
    const Field f = render_markers(ms, 1.5, 9);
    RegisterMap r;
    r.write(reg::kMinArea, 1);
    r.write(reg::roi_x(0), (300u << 16) | 100u);
    r.write(reg::roi_y(0), (150u << 16) | 20u);
    r.write(reg::roi_x(2), (719u << 16) | 250u);  // overlaps window 0 in x
    r.write(reg::roi_y(2), (287u << 16) | 120u);
    r.write(reg::kRoiEnable, 0x5);
    Pipeline p(r);
    const std::vector<Blob> got = run_field(p, f);
    const cv::Mat1b cls = classify_field(p, f);
    const std::vector<RefBlob> want = reference_blobs(p, f, cls);
    REQUIRE(got.size() == want.size());
    REQUIRE(got.size() > 10);
    int clipped = 0;
    for (size_t i = 0; i < got.size(); ++i) {
        CHECK(got[i].area_px == static_cast<uint32_t>(want[i].area));
        CHECK(got[i].x_min == want[i].x0);
        CHECK(got[i].y_max == want[i].y1);
        if (!want[i].ring_shared) CHECK(got[i].sum_wx == want[i].swx);
        clipped += (got[i].flags & kBlobClippedByRoi) != 0;
    }
    CHECK(clipped > 0);
    // Fewer pixels examined than the whole field: the two windows cover 201×131 + 470×168 px.
    Pipeline full{RegisterMap{}};
    run_field(full, f);
    CHECK(p.field_stats().runs < full.field_stats().runs);
}

TEST_CASE("pipeline call order is checked", "[fpga][regs]") {
    Pipeline p{RegisterMap{}};
    std::vector<uint8_t> line(kLineBytes, 128);
    CHECK(p.push_line(line.data(), 0) == PipelineStatus::kNotInField);
    CHECK(p.end_field() == PipelineStatus::kNotInField);
    CHECK(p.begin_field(0, 0) == PipelineStatus::kOk);
    CHECK(p.begin_field(0, 0) == PipelineStatus::kAlreadyInField);
    CHECK(p.push_line(nullptr, 0) == PipelineStatus::kNullLine);
    CHECK(p.push_line(line.data(), -1) == PipelineStatus::kLineOutOfRange);
    CHECK(p.push_line(line.data(), kMaxFieldLines) == PipelineStatus::kLineOutOfRange);
    CHECK(p.push_line(line.data(), 5) == PipelineStatus::kOk);
    CHECK(p.push_line(line.data(), 5) == PipelineStatus::kLineOutOfOrder);
    CHECK(p.push_line(line.data(), 4) == PipelineStatus::kLineOutOfOrder);
    CHECK(p.end_field() == PipelineStatus::kOk);
    CHECK_FALSE(p.in_field());
}

namespace {
// Noise-free yellow markers (8 px wide, 4 lines tall) at random subpixel positions, the left half of the field on
// a warm white (the eye's), the right half on a cool grey-blue: RMS centroid error against the coverage centroid.
double tinted_background_rms(const RegisterMap& regs) {
    std::mt19937 rng(21);
    std::uniform_real_distribution<double> phase(0, 1);
    std::vector<Marker> left, right;
    for (int i = 0; i < 24; ++i) {  // a 4 × 6 grid in each half, random subpixel phase
        left.push_back({4, 40 + 80 * (i % 4) + phase(rng), 24 + 44 * (i / 4) + phase(rng), 4.0, 2.0});
        right.push_back({4, 400 + 80 * (i % 4) + phase(rng), 24 + 44 * (i / 4) + phase(rng), 4.0, 2.0});
    }
    std::vector<std::array<double, 2>> tl, tr;
    const Field fl = render_markers(left, 0.0, 1, 288, 8, {236, 234, 226}, &tl);
    const Field fr = render_markers(right, 0.0, 1, 288, 8, {170, 175, 190}, &tr);
    Field f = fl;
    for (int y = 0; y < 288; ++y)
        std::memcpy(f.line(y) + 720, fr.line(y) + 720, 720);  // pixels 360..719 from the right field
    std::vector<std::array<double, 2>> truth = tl;
    truth.insert(truth.end(), tr.begin(), tr.end());
    std::vector<Marker> all = left;
    all.insert(all.end(), right.begin(), right.end());
    Pipeline p(regs);
    const std::vector<Blob> got = run_field(p, f);
    double se = 0;
    int n = 0;
    for (size_t i = 0; i < all.size(); ++i) {
        double best = 1e9;
        for (const Blob& b : got) {
            const double dx = b.cx_px() - truth[i][0], dy = b.cy_px() - truth[i][1];
            best = std::min(best, dx * dx + dy * dy);
        }
        if (best < 1.0) {
            se += best;
            ++n;
        }
    }
    REQUIRE(n == static_cast<int>(all.size()));
    return std::sqrt(se / n);
}
}  // namespace

TEST_CASE("BG_TRACK: a tinted background that changes across the field does not bias the centroids", "[fpga][regs]") {
    // Without tracking no single level fits both halves: level 0 leaves the tint in every edge and ring pixel,
    // map 1.1's reset level (5 for yellow) cuts into the marker's own edge weights.
    RegisterMap off, off_map11, on;
    for (RegisterMap* r : {&off, &on}) REQUIRE(r->write(reg::kWeightBg, 0) == RegWriteResult::kOk);
    REQUIRE(off_map11.write(reg::kWeightBg, 0x05030303u) == RegWriteResult::kOk);
    for (RegisterMap* r : {&off, &off_map11}) REQUIRE(r->write(reg::kBgTrack, 0) == RegWriteResult::kOk);
    REQUIRE(on.write(reg::kBgTrack, 4) == RegWriteResult::kOk);
    const double e_off = tinted_background_rms(off), e_map11 = tinted_background_rms(off_map11);
    const double e_on = tinted_background_rms(on);
    INFO("rms: no tracking, level 0: " << e_off << "; level 5: " << e_map11 << "; tracked, level 0: " << e_on);
    CHECK(e_off > 0.02);
    CHECK(e_map11 > 0.01);
    CHECK(e_on < 0.3 * e_off);
    CHECK(e_on < 0.6 * e_map11);
    CHECK(e_on < 0.008);
}

namespace {
// Markers of every class (8 px wide, 4 lines tall) at random subpixel positions just below steps of the background
// tint (warm white and cool grey-blue alternating every 32 lines; each marker's top 3–4 lines under a step), so the
// tracked background under each marker still carries the tint above the step. Noise-free. RMS x and y errors
// against the coverage centroid, and the blobs.
struct StepErrors {
    double x_rms = 0, y_rms = 0;
    std::vector<Blob> blobs;
};
StepErrors step_background_errors(const RegisterMap& regs) {
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> phase(0, 1);
    std::vector<Marker> ms;
    for (int row = 0; row < 8; ++row)
        for (int i = 0; i < 8; ++i)
            ms.push_back({1 + (row + i) % 4, 40 + 85 * i + phase(rng), 32 * row + 6 + phase(rng), 4.0, 2.0});
    std::vector<std::array<double, 2>> truth, t_cool;
    const Field warm = render_markers(ms, 0.0, 1, 288, 8, {236, 234, 226}, &truth);
    const Field cool = render_markers(ms, 0.0, 1, 288, 8, {170, 175, 190}, &t_cool);
    Field f = warm;
    for (int y = 0; y < 288; ++y)
        if ((y / 32) % 2 == 1) std::memcpy(f.line(y), cool.line(y), kLineBytes);
    StepErrors e;
    Pipeline p(regs);
    e.blobs = run_field(p, f);
    int n = 0;
    for (size_t i = 0; i < ms.size(); ++i) {
        const Blob* best = nullptr;
        for (const Blob& b : e.blobs)
            if (b.class_id == ms[i].cls && std::hypot(b.cx_px() - truth[i][0], b.cy_px() - truth[i][1]) < 1.0) best = &b;
        if (best == nullptr) continue;
        e.x_rms += std::pow(best->cx_px() - truth[i][0], 2);
        e.y_rms += std::pow(best->cy_px() - truth[i][1], 2);
        ++n;
    }
    REQUIRE(n == static_cast<int>(ms.size()));
    e.x_rms = std::sqrt(e.x_rms / n);
    e.y_rms = std::sqrt(e.y_rms / n);
    return e;
}
}  // namespace

TEST_CASE("BG_OFFSET: the band beside a marker corrects x where the tracked background is stale", "[fpga][regs]") {
    RegisterMap off, on;
    CHECK(off.get(reg::kBgOffset) == 0);  // reset: off
    CHECK(on.write(reg::kBgOffset, 2) == RegWriteResult::kTooWide);
    REQUIRE(on.write(reg::kBgOffset, 1) == RegWriteResult::kOk);
    CHECK(decode(on).bg_offset);
    const StepErrors a = step_background_errors(off), b = step_background_errors(on);
    INFO("x rms off " << a.x_rms << " on " << b.x_rms << "; y rms off " << a.y_rms << " on " << b.y_rms);
    CHECK(a.x_rms > 0.01);
    CHECK(b.x_rms < 0.65 * a.x_rms);
    // y and every moment are untouched: only the x divider's operands change.
    REQUIRE(a.blobs.size() == b.blobs.size());
    for (size_t i = 0; i < a.blobs.size(); ++i) {
        CHECK(a.blobs[i].cy_q16 == b.blobs[i].cy_q16);
        CHECK(a.blobs[i].sum_wx == b.blobs[i].sum_wx);
        CHECK(b.blobs[i].band_count > 0);
        CHECK(a.blobs[i].band_count == 0);
    }
}
