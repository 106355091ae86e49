// Precision mode's patch capture: every captured byte equals the field's sample at its coordinates, the patch covers
// the blob's box plus the 2-px halo (clipped to the field, whole UYVY pairs), enabled classes only, too-large blobs
// flagged and not sent; on generated fields and on a rig recording.
#include "field_gen.hpp"
#if __has_include("eyesim/rig/recording.hpp")
#include "rig_fixture.hpp"
#define EYESIM_PATCH_RIG_TEST 1
#endif

#include "eyesim/fpga/patch_capture.hpp"

#include <catch2/catch.hpp>

#include <map>

using namespace eyesim::fpga;
using namespace eyesim::fpga::test;

namespace {

/// Blobs (in emission order) and patches of one field, run line by line as the firmware does.
struct Captured {
    std::vector<Blob> blobs;
    std::vector<Patch> patches;
};

Captured capture_field(Pipeline& pipe, PatchCapture& cap, const uint8_t* field, int lines, uint32_t counter) {
    Captured out;
    struct Ctx {
        Captured* out;
        PatchCapture* cap;
    } ctx{&out, &cap};
    pipe.set_sink(
        [](void* c, const Blob& b) {
            auto* x = static_cast<Ctx*>(c);
            x->cap->add_blob(b, static_cast<uint16_t>(x->out->blobs.size()));
            x->out->blobs.push_back(b);
        },
        &ctx);
    cap.set_sink([](void* c, const Patch& p) { static_cast<Captured*>(c)->patches.push_back(p); }, &out);
    REQUIRE(pipe.begin_field(counter, 0) == PipelineStatus::kOk);
    cap.begin_field(pipe.params(), counter, 0);
    for (int y = 0; y < lines; ++y) {
        const uint8_t* line = field + static_cast<size_t>(y) * kLineBytes;
        cap.push_line(line, y);  // before the pipeline: a blob completed on line y finds line y buffered
        REQUIRE(pipe.push_line(line, y) == PipelineStatus::kOk);
    }
    REQUIRE(pipe.end_field() == PipelineStatus::kOk);
    cap.end_field();
    pipe.set_sink(nullptr, nullptr);
    return out;
}

/// Checks the patches against the blobs and the field; returns the number of blobs too large for a patch.
int check_patches(const Captured& c, const uint8_t* field, int lines, uint8_t enable) {
    std::map<uint16_t, const Patch*> by_index;
    for (const Patch& p : c.patches) REQUIRE(by_index.emplace(p.blob_index, &p).second);  // one patch per blob
    int too_large = 0;
    for (size_t i = 0; i < c.blobs.size(); ++i) {
        const Blob& b = c.blobs[i];
        INFO("blob " << i << " class " << int(b.class_id) << " box (" << b.x_min << ", " << b.y_min << ")-(" << b.x_max
                     << ", " << b.y_max << ")");
        // The wanted rectangle, counted column by column: the box and 2 px either side inside the field, then the
        // UYVY pairs those columns fall in.
        int cx0 = 719, cx1 = 0;
        for (int x = int(b.x_min) - 2; x <= int(b.x_max) + 2; ++x)
            if (x >= 0 && x < 720) cx0 = std::min(cx0, x - x % 2), cx1 = std::max(cx1, x - x % 2 + 1);
        const int ry0 = std::max(0, int(b.y_min) - 2), ry1 = std::min(lines - 1, int(b.y_max) + 2);
        const bool clipped = int(b.x_min) < 2 || int(b.y_min) < 2 || int(b.x_max) > 717 || int(b.y_max) + 2 > lines - 1;
        const bool wanted = (enable >> (b.class_id - 1)) & 1;
        const bool fits = cx1 - cx0 + 1 <= 64 && ry1 - ry0 + 1 <= 32;
        too_large += wanted && !fits;
        const auto it = by_index.find(static_cast<uint16_t>(i));
        if (!wanted || !fits) {
            CHECK(it == by_index.end());
            continue;
        }
        REQUIRE(it != by_index.end());
        const Patch& p = *it->second;
        CHECK(p.class_id == b.class_id);
        CHECK(p.field_counter == b.field_counter);
        CHECK(int(p.origin_x) == cx0);
        CHECK(int(p.origin_y) == ry0);
        CHECK(int(p.width_px) == cx1 - cx0 + 1);
        CHECK(int(p.height_px) == ry1 - ry0 + 1);
        CHECK(((p.flags & eyesim::protocol::kPatchFlagClipped) != 0) == clipped);
        // Every byte against the field at its coordinates.
        int wrong = 0;
        for (int r = 0; r < p.height_px; ++r)
            for (int k = 0; k < 2 * p.width_px; ++k)
                wrong += p.samples[static_cast<size_t>(2 * r * p.width_px + k)] !=
                         field[static_cast<size_t>(p.origin_y + r) * kLineBytes + 2u * p.origin_x + static_cast<size_t>(k)];
        CHECK(wrong == 0);
    }
    return too_large;
}

}  // namespace

TEST_CASE("PATCH_ENABLE: per-class bits, reset off, four bits wide", "[fpga][patch][regs]") {
    RegisterMap r;
    CHECK(r.get(reg::kPatchEnable) == 0);
    CHECK(decode(r).patch_enable == 0);
    CHECK(r.write(reg::kPatchEnable, 0x10) == RegWriteResult::kTooWide);
    CHECK(r.write(reg::kPatchEnable, 0xB) == RegWriteResult::kOk);
    CHECK(decode(r).patch_enable == 0xB);
    CHECK(r.get(reg::kVersion) == 0x0104);  // 1.3 added PATCH_ENABLE, 1.4 BG_OFFSET
}

TEST_CASE("patch_rect: halo, clipping and whole pixel pairs", "[fpga][patch]") {
    PatchRect r = patch_rect(100, 50, 107, 55);  // even start: 98..109
    CHECK((r.x0 == 98 && r.x1 == 109 && r.y0 == 48 && r.y1 == 57 && !r.clipped));
    r = patch_rect(101, 50, 107, 55);  // 99..109 → 98..109
    CHECK((r.x0 == 98 && r.x1 == 109));
    r = patch_rect(100, 50, 108, 55);  // 98..110 → 98..111
    CHECK((r.x0 == 98 && r.x1 == 111));
    r = patch_rect(1, 0, 5, 3);
    CHECK((r.x0 == 0 && r.y0 == 0 && r.clipped));
    r = patch_rect(715, 284, 719, 287);
    CHECK((r.x1 == 719 && r.y1 == 287 && r.clipped));
}

TEST_CASE("patch capture on generated fields: every byte equals the field, enabled classes only", "[fpga][patch]") {
    std::mt19937 rng(31);
    std::uniform_real_distribution<double> ux(-2, 722), uy(-2, 290), ur(3, 8);
    std::uniform_int_distribution<int> uc(1, 4);
    RegisterMap regs;
    REQUIRE(regs.write(reg::kPatchEnable, 0xB) == RegWriteResult::kOk);  // classes 1, 2, 4; not 3
    Pipeline pipe(&regs);
    PatchCapture cap(1);
    int patches = 0, blobs = 0, too_large = 0, clipped = 0;
    for (uint32_t f = 0; f < 6; ++f) {
        std::vector<Marker> ms;
        for (int i = 0; i < 25; ++i) {
            Marker m;
            m.cls = uc(rng);
            m.cx = ux(rng);  // some across the field's edges
            m.cy = uy(rng);
            m.rx = ur(rng);
            m.ry = m.rx / 2;
            ms.push_back(m);
        }
        // Too large for the 32 line buffers or the 64-px width: flagged, no patch.
        ms.push_back({1, 360, 144, 40, 6});
        ms.push_back({2, 200, 100, 5, 16});
        const Field field = render_markers(ms, 1.0, 100 + f, 288, 2);
        const Captured c = capture_field(pipe, cap, field.bytes.data(), 288, f);
        too_large += check_patches(c, field.bytes.data(), 288, 0xB);
        blobs += static_cast<int>(c.blobs.size());
        patches += static_cast<int>(c.patches.size());
        for (const Patch& p : c.patches) clipped += (p.flags & eyesim::protocol::kPatchFlagClipped) != 0;
        CHECK(cap.pending() == 0);
    }
    CHECK(patches > 60);
    CHECK(clipped > 0);
    CHECK(too_large >= 12);
    CHECK(cap.stats().too_large == static_cast<uint64_t>(too_large));
    CHECK(cap.stats().captured == static_cast<uint64_t>(patches));
    CHECK(cap.stats().dropped == 0);
    CHECK(cap.stats().captured + cap.stats().disabled + cap.stats().too_large == static_cast<uint64_t>(blobs));
}

TEST_CASE("patch capture: a field that ends early cuts the pending patches at its last line", "[fpga][patch]") {
    RegisterMap regs;
    REQUIRE(regs.write(reg::kPatchEnable, 0xF) == RegWriteResult::kOk);
    Pipeline pipe(&regs);
    PatchCapture cap;
    const Field field = render_markers({{2, 300, 96, 6, 3}}, 0.5, 9, 288, 2);
    const Captured c = capture_field(pipe, cap, field.bytes.data(), 100, 0);  // ends inside the marker's lower halo
    REQUIRE(c.blobs.size() == 1);
    REQUIRE(c.patches.size() == 1);
    CHECK(check_patches(c, field.bytes.data(), 100, 0xF) == 0);
    CHECK(c.patches[0].origin_y + c.patches[0].height_px == 100);
}

#ifdef EYESIM_PATCH_RIG_TEST
TEST_CASE("patch capture on a rig recording: every byte equals the recorded field", "[fpga][patch][rig]") {
    RigRecording rr("eyesim_fpga_patch_test", "static", 0.1, 1.0);  // 5 fields × 3 cameras
    std::vector<uint8_t> field(static_cast<size_t>(eyesim::rig::kFieldBytes));
    int patches = 0, blobs = 0;
    for (int cam = 0; cam < rr.rec.camera_count(); ++cam) {
        RegisterMap regs;
        REQUIRE(regs.write(reg::kPatchEnable, 0xF) == RegWriteResult::kOk);
        Pipeline pipe(&regs);
        PatchCapture cap(static_cast<uint8_t>(cam));
        for (int64_t i = 0; i < 5; ++i) {
            REQUIRE(rr.rec.read_field(cam, i, field.data()));
            const Captured c = capture_field(pipe, cap, field.data(), 288, static_cast<uint32_t>(i));
            CHECK(check_patches(c, field.data(), 288, 0xF) == 0);  // the rig's markers all fit
            blobs += static_cast<int>(c.blobs.size());
            patches += static_cast<int>(c.patches.size());
            for (const Patch& p : c.patches) CHECK(p.camera == cam);
        }
        CHECK(cap.stats().dropped == 0);
    }
    CHECK(blobs > 20);
    CHECK(patches == blobs);
}
#endif
