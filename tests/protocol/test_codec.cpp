#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/crc32c.hpp"
#include "eyesim/protocol/schema.hpp"
#include "test_util.hpp"

#include <catch2/catch.hpp>

#include <algorithm>

using namespace eyesim::protocol;
using namespace eyesim::protocol::test;

namespace {

void round_trip(const Message& m, std::uint16_t seq) {
    const Bytes f = frame_of(m, seq);
    REQUIRE(f.size() == frame_size(payload_size(m)));
    REQUIRE(f.size() <= kMaxFrameBytes);
    DecodedFrame out;
    out.message = Reply{};  // decoding must replace whatever the variant held
    std::size_t used = 0;
    REQUIRE(decode_frame(f, out, used) == DecodeError::None);
    CHECK(used == f.size());
    CHECK(out.header.sequence == seq);
    CHECK(out.header.version == kProtocolVersion);
    CHECK(out.header.type == message_type(m));
    CHECK(out.header.payload_bytes == payload_size(m));
    CHECK(out.message == m);
}

}  // namespace

TEST_CASE("every message type round-trips with random values", "[protocol][codec]") {
    std::mt19937_64 rng(1234);
    for (int i = 0; i < 500; ++i) {
        round_trip(random_field_markers(rng), static_cast<std::uint16_t>(rng()));
        round_trip(random_pedal(rng), static_cast<std::uint16_t>(rng()));
        round_trip(random_status(rng), static_cast<std::uint16_t>(rng()));
        round_trip(random_command(rng), static_cast<std::uint16_t>(rng()));
        round_trip(random_reply(rng), static_cast<std::uint16_t>(rng()));
        round_trip(random_blob_patch(rng), static_cast<std::uint16_t>(rng()));
    }
}

TEST_CASE("extreme values round-trip", "[protocol][codec]") {
    FieldMarkers full;
    full.camera_id = 2;
    full.field_parity = 1;
    full.flags = kFieldFlagsDefined;
    full.marker_count = kMaxMarkersPerMessage;
    full.field_counter = 0xFFFFFFFF;
    full.field_end_us = ~0ull;
    full.part_index = 0xFFFF;
    for (auto& k : full.markers)
        k = Marker{kMaxColourClass, kMarkerFlagsDefined, 0xFFFF, 0xFFFF, 0xFFFF, 0xFFFF, ~0u, ~0u, ~0u, ~0u, ~0ull};
    round_trip(full, 0xFFFF);
    CHECK(frame_size(payload_size(full)) == 506);  // the largest frame fits one 512-byte USB 2.0 bulk packet
    FieldMarkers empty;
    round_trip(empty, 0);
    CHECK(frame_size(payload_size(empty)) == 30);
    round_trip(PedalState{~0ull, {0xFFFF, 0xFFFF, 0xFFFF}, 0xFFFF}, 1);
    round_trip(Command{~0u, 255, ~0u, ~0u, ~0ull}, 2);  // unknown opcode survives: the device NACKs it
    round_trip(Reply{~0u, 255, 1, kMaxNackReason, ~0u, ~0ull, ~0ull}, 3);
}

TEST_CASE("a frame built by hand from the spec tables equals the encoder's", "[protocol][codec]") {
    // PedalState: device_us=0x0102030405060708, axes 0x1122 0x3344 0x5566, buttons 0x8001, sequence 0xBEEF.
    Bytes f = {0xE7, 0x5A, 0x01, 0x02, 0xEF, 0xBE, 0x10, 0x00,                   // header
               0x08, 0x07, 0x06, 0x05, 0x04, 0x03, 0x02, 0x01,                   // device_us
               0x22, 0x11, 0x44, 0x33, 0x66, 0x55, 0x01, 0x80};                  // axes, buttons
    // CRC over bytes 2.. then the schema hash, computed with the bitwise definition.
    Bytes covered(f.begin() + 2, f.end());
    const std::uint32_t h = schema_hash(MessageType::PedalState);
    for (int i = 0; i < 4; ++i) covered.push_back(static_cast<std::uint8_t>(h >> (8 * i)));
    std::uint32_t reg = 0xFFFFFFFFu;
    for (auto b : covered)
        for (int k = 0; k < 8; ++k, b >>= 1) reg = ((reg ^ b) & 1u) ? (reg >> 1) ^ 0x82F63B78u : reg >> 1;
    reg = ~reg;
    for (int i = 0; i < 4; ++i) f.push_back(static_cast<std::uint8_t>(reg >> (8 * i)));
    const PedalState p{0x0102030405060708ull, {0x1122, 0x3344, 0x5566}, 0x8001};
    CHECK(frame_of(p, 0xBEEF) == f);
}

TEST_CASE("the encoder refuses messages outside the documented ranges", "[protocol][codec]") {
    std::mt19937_64 rng(3);
    Bytes out(kMaxFrameBytes);
    auto refuses = [&](const Message& m) { return encode_frame(m, 0, out) == 0 && !valid_message(m); };
    FieldMarkers f = random_field_markers(rng);
    f.marker_count = 1;
    f.markers[0] = random_marker(rng);
    REQUIRE(encode_frame(f, 0, out) > 0);
    FieldMarkers bad = f;
    bad.camera_id = 3;
    CHECK(refuses(bad));
    bad = f;
    bad.field_parity = 2;
    CHECK(refuses(bad));
    bad = f;
    bad.flags = 0x08;
    CHECK(refuses(bad));
    bad = f;
    bad.marker_count = kMaxMarkersPerMessage + 1;
    CHECK(refuses(bad));
    bad = f;
    bad.markers[0].colour_class = 0;
    CHECK(refuses(bad));
    bad.markers[0].colour_class = 5;
    CHECK(refuses(bad));
    bad = f;
    bad.markers[0].flags = 0x10;
    CHECK(refuses(bad));
    bad = f;
    bad.markers[0].bbox_x0 = 10;
    bad.markers[0].bbox_x1 = 9;
    CHECK(refuses(bad));
    bad = f;
    bad.markers[0].bbox_y0 = 10;
    bad.markers[0].bbox_y1 = 9;
    CHECK(refuses(bad));
    CHECK(refuses(Reply{1, 1, 2, 0, 0, 0, 0}));   // status 2 undefined
    CHECK(refuses(Reply{1, 1, 0, 3, 0, 0, 0}));   // ack with a reason
    CHECK(refuses(Reply{1, 1, 1, 0, 0, 0, 0}));   // nack without a reason
    CHECK(refuses(Reply{1, 1, 1, kMaxNackReason + 1, 0, 0, 0}));
    // Too small an output buffer.
    Bytes small(frame_size(payload_size(f)) - 1);
    CHECK(encode_frame(f, 0, small) == 0);
}

TEST_CASE("the decoder reports each kind of bad frame", "[protocol][codec]") {
    std::mt19937_64 rng(8);
    const Bytes good = frame_of(random_pedal(rng), 9);
    DecodedFrame out;
    std::size_t used = 99;
    CHECK(decode_frame(std::span(good).first(7), out, used) == DecodeError::TooShort);
    CHECK(used == 0);
    CHECK(decode_frame(std::span(good).first(good.size() - 1), out, used) == DecodeError::TooShort);
    Bytes b = good;
    b[1] = 0x5B;
    CHECK(decode_frame(b, out, used) == DecodeError::BadSync);
    b = good;
    b[2] = 2;
    CHECK(decode_frame(b, out, used) == DecodeError::BadVersion);
    b = good;
    b[3] = 7;
    CHECK(decode_frame(b, out, used) == DecodeError::UnknownType);
    b = good;
    b[3] = 3;  // DeviceStatus with a PedalState length
    CHECK(decode_frame(b, out, used) == DecodeError::BadLength);
    b = good;
    b[6] = 0xF5;  // 501: over kMaxPayloadBytes
    b[7] = 0x01;
    CHECK(decode_frame(b, out, used) == DecodeError::BadLength);
    b = good;
    b[10] ^= 0x01;
    CHECK(decode_frame(b, out, used) == DecodeError::BadCrc);
    // Payload out of range under a good CRC: FieldMarkers with camera_id 3.
    FieldMarkers f;
    Bytes payload(kFieldMarkersHeaderBytes);
    REQUIRE(encode_payload(f, payload) == kFieldMarkersHeaderBytes);
    payload[0] = 3;
    Bytes frame(kMaxFrameBytes);
    frame.resize(encode_frame_raw(1, 0, payload, frame, schema_hash(MessageType::FieldMarkers)));
    CHECK(decode_frame(frame, out, used) == DecodeError::BadPayload);
    // marker_count disagreeing with a valid length: a payload error under a good CRC.
    payload[0] = 0;
    payload[3] = 1;
    frame.assign(kMaxFrameBytes, 0);
    frame.resize(encode_frame_raw(1, 0, payload, frame, schema_hash(MessageType::FieldMarkers)));
    CHECK(decode_frame(frame, out, used) == DecodeError::BadPayload);
    CHECK(decode_payload(MessageType::FieldMarkers, payload, out.message) == DecodeError::BadPayload);
    CHECK(decode_payload(MessageType::FieldMarkers, std::span(payload).first(17), out.message) ==
          DecodeError::BadLength);
    CHECK(decode_payload(MessageType::PedalState, std::span(payload).first(15), out.message) ==
          DecodeError::BadLength);
    CHECK(std::string(decode_error_name(DecodeError::BadCrc)) == "bad_crc");
}

TEST_CASE("payload lengths accepted per type", "[protocol][codec]") {
    for (std::size_t n = 0; n <= 0xFFFF; ++n) {
        const bool fm = n >= 18 && n <= 494 && (n - 18) % 34 == 0;
        REQUIRE(valid_payload_length(MessageType::FieldMarkers, n) == fm);
        REQUIRE(valid_payload_length(MessageType::PedalState, n) == (n == 16));
        REQUIRE(valid_payload_length(MessageType::DeviceStatus, n) == (n == 56));
        REQUIRE(valid_payload_length(MessageType::Command, n) == (n == 21));
        REQUIRE(valid_payload_length(MessageType::Reply, n) == (n == 27));
        const bool bp = n >= 24 && n <= 492 && (n - 20) % 4 == 0;
        REQUIRE(valid_payload_length(MessageType::BlobPatch, n) == bp);
    }
}

TEST_CASE("BlobPatch: fragments of every patch size reassemble the patch, and out-of-range headers are refused",
          "[protocol][codec]") {
    std::mt19937_64 rng(2020);
    for (std::uint16_t w = 2; w <= kPatchMaxWidthPx; w += 2) {
        for (std::uint16_t h = 1; h <= kPatchMaxHeightPx; ++h) {
            const std::size_t total = patch_bytes(w, h);
            Bytes patch(total);
            for (auto& v : patch) v = uniform<std::uint8_t>(rng, 0, 255);
            const std::size_t count = patch_fragment_count(total);
            // Independent count: whole 472-byte fragments plus one for any remainder.
            REQUIRE(count == total / 472 + (total % 472 != 0));
            Bytes joined;
            for (std::size_t i = 0; i < count; ++i) {
                BlobPatch b;
                b.camera_id = 2;
                b.colour_class = 3;
                b.width_px = w;
                b.height_px = h;
                b.origin_x = static_cast<std::uint16_t>(720 - w);
                b.origin_y = static_cast<std::uint16_t>(288 - h);
                b.fragment_count = static_cast<std::uint8_t>(count);
                b.fragment_index = static_cast<std::uint8_t>(i);
                const std::size_t first = i * 472, n = std::min<std::size_t>(472, total - first);
                REQUIRE(b.sample_bytes() == n);
                std::copy(patch.begin() + static_cast<std::ptrdiff_t>(first),
                          patch.begin() + static_cast<std::ptrdiff_t>(first + n), b.samples.begin());
                const Bytes f = frame_of(b, static_cast<std::uint16_t>(i));
                REQUIRE(f.size() == 12 + 20 + n);
                REQUIRE(f.size() <= 506);
                DecodedFrame out;
                std::size_t used = 0;
                REQUIRE(decode_frame(f, out, used) == DecodeError::None);
                const auto& got = std::get<BlobPatch>(out.message);
                REQUIRE(got == b);
                joined.insert(joined.end(), got.samples.begin(), got.samples.begin() + static_cast<std::ptrdiff_t>(n));
            }
            REQUIRE(joined == patch);
        }
    }
    // Each header field out of its range, on an otherwise valid fragment.
    BlobPatch ok;
    ok.colour_class = 1;
    ok.width_px = 10;
    ok.height_px = 7;
    ok.origin_x = 100;
    ok.origin_y = 50;
    ok.fragment_count = 1;
    CHECK(valid_message(ok));
    auto refused = [&](auto change) {
        BlobPatch b = ok;
        change(b);
        Bytes out(kMaxFrameBytes);
        return !valid_message(b) && encode_frame(b, 0, out) == 0;
    };
    CHECK(refused([](BlobPatch& b) { b.camera_id = 3; }));
    CHECK(refused([](BlobPatch& b) { b.field_parity = 2; }));
    CHECK(refused([](BlobPatch& b) { b.colour_class = 0; }));
    CHECK(refused([](BlobPatch& b) { b.colour_class = 5; }));
    CHECK(refused([](BlobPatch& b) { b.flags = 0x02; }));
    CHECK(refused([](BlobPatch& b) { b.width_px = 11; }));
    CHECK(refused([](BlobPatch& b) { b.width_px = 0; }));
    CHECK(refused([](BlobPatch& b) { b.width_px = kPatchMaxWidthPx + 2; }));
    CHECK(refused([](BlobPatch& b) { b.height_px = 0; }));
    CHECK(refused([](BlobPatch& b) { b.height_px = kPatchMaxHeightPx + 1; }));
    CHECK(refused([](BlobPatch& b) { b.origin_x = 101; }));
    CHECK(refused([](BlobPatch& b) { b.origin_x = 712; }));
    CHECK(refused([](BlobPatch& b) { b.origin_y = 282; }));
    CHECK(refused([](BlobPatch& b) { b.fragment_count = 2; }));
    CHECK(refused([](BlobPatch& b) { b.fragment_index = 1; }));
    // Under a good CRC: a length that disagrees with the header's size is a payload error, not a length error.
    Bytes payload(kMaxPayloadBytes);
    payload.resize(encode_payload(ok, payload));
    REQUIRE(payload.size() == 20 + 140);
    payload.resize(payload.size() - 4);
    Bytes frame(kMaxFrameBytes);
    frame.resize(encode_frame_raw(6, 0, payload, frame, schema_hash(MessageType::BlobPatch)));
    DecodedFrame out;
    std::size_t used = 0;
    CHECK(decode_frame(frame, out, used) == DecodeError::BadPayload);
}
