// Blob → protocol marker conversion, split into FieldMarkers parts, and a codec round trip.
#include "field_gen.hpp"

#include "eyesim/fpga/wire.hpp"
#include "eyesim/protocol/codec.hpp"

#include <catch2/catch.hpp>

using namespace eyesim::fpga;
using namespace eyesim::fpga::test;

TEST_CASE("blobs become FieldMarkers parts that survive the codec", "[fpga][wire]") {
    // 31 markers in a grid, one touching the border.
    std::vector<Marker> ms;
    for (int i = 0; i < 31; ++i) ms.push_back({1 + i % 4, 20.0 + 22.0 * i, 30.0 + 7.0 * (i % 5), 5.0, 2.5});
    ms.push_back({2, 2.0, 150.0, 5.0, 2.5});
    const Field f = render_markers(ms, 1.0, 5);
    RegisterMap regs;
    Pipeline p(regs, PipelineConfig{2, kMaxBlobSlots, false});
    const std::vector<Blob> blobs = run_field(p, f, 77);
    REQUIRE(blobs.size() == 32);

    const uint64_t start_us = 1'000'000;
    const FieldInfo info = field_info(p.field_stats(), 2, 1, start_us);
    std::array<eyesim::protocol::FieldMarkers, 4> msgs{};
    REQUIRE(field_markers_messages(32) == 3);
    REQUIRE(to_field_markers(blobs.data(), blobs.size(), info, msgs.data(), 2) == 0);  // too little room
    REQUIRE(to_field_markers(blobs.data(), blobs.size(), info, msgs.data(), msgs.size()) == 3);
    CHECK(msgs[0].marker_count == 14);
    CHECK(msgs[1].marker_count == 14);
    CHECK(msgs[2].marker_count == 4);
    CHECK((msgs[0].flags & eyesim::protocol::kFieldFlagMoreFollows) != 0);
    CHECK((msgs[2].flags & eyesim::protocol::kFieldFlagMoreFollows) == 0);
    int border = 0;
    for (size_t m = 0; m < 3; ++m) {
        CHECK(msgs[m].part_index == m);
        CHECK(msgs[m].camera_id == 2);
        CHECK(msgs[m].field_parity == 1);
        CHECK(msgs[m].field_counter == 77);
        // Field end: after the last active pixel of line 287, (22+287)·864+144+720 = 267840 clocks = 19840 µs.
        CHECK(msgs[m].field_end_us == start_us + 19840);
        for (size_t k = 0; k < msgs[m].marker_count; ++k) {
            const Blob& b = blobs[m * 14 + k];
            const auto& mk = msgs[m].markers[k];
            CHECK(mk.colour_class == b.class_id);
            CHECK(mk.x_q16 / 65536.0 == Approx(b.cx_px()).margin(1e-12));
            CHECK(mk.y_q16 / 65536.0 == Approx(b.cy_px()).margin(1e-12));
            CHECK(mk.area_px == b.area_px);
            CHECK(mk.intensity_sum == b.sum_w);
            CHECK(mk.complete_us == start_us + b.last_pixel_cycle * 1000000ull / 13500000ull);
            CHECK(mk.complete_us <= msgs[m].field_end_us);
            border += (mk.flags & eyesim::protocol::kMarkerFlagTouchesBorder) != 0;
        }
        // Round trip through the wire encoding.
        std::array<uint8_t, eyesim::protocol::kMaxFrameBytes> buf{};
        const size_t len = eyesim::protocol::encode_frame(eyesim::protocol::Message{msgs[m]}, 5, buf);
        REQUIRE(len > 0);
        eyesim::protocol::DecodedFrame fr;
        size_t used = 0;
        REQUIRE(eyesim::protocol::decode_frame(std::span<const uint8_t>(buf.data(), len), fr, used) ==
                eyesim::protocol::DecodeError::None);
        REQUIRE(used == len);
        REQUIRE(std::get<eyesim::protocol::FieldMarkers>(fr.message) == msgs[m]);
    }
    CHECK(border == 1);

    // An empty field is still announced with one message.
    std::array<eyesim::protocol::FieldMarkers, 1> one{};
    REQUIRE(to_field_markers(nullptr, 0, info, one.data(), 1) == 1);
    CHECK(one[0].marker_count == 0);
    CHECK(one[0].flags == 0);
}
