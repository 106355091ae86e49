#pragma once
// Shared helpers of the protocol tests: random messages and frame streams.

#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/messages.hpp"

#include <cstdint>
#include <random>
#include <vector>

namespace eyesim::protocol::test {

using Bytes = std::vector<std::uint8_t>;

template <class T>
T uniform(std::mt19937_64& rng, T lo, T hi) {
    return static_cast<T>(std::uniform_int_distribution<std::uint64_t>(lo, hi)(rng));
}

inline Marker random_marker(std::mt19937_64& rng) {
    Marker k;
    k.colour_class = uniform<std::uint8_t>(rng, kMinColourClass, kMaxColourClass);
    k.flags = uniform<std::uint8_t>(rng, 0, kMarkerFlagsDefined);
    k.bbox_x0 = uniform<std::uint16_t>(rng, 0, 0xFFFF);
    k.bbox_x1 = uniform<std::uint16_t>(rng, k.bbox_x0, 0xFFFF);
    k.bbox_y0 = uniform<std::uint16_t>(rng, 0, 0xFFFF);
    k.bbox_y1 = uniform<std::uint16_t>(rng, k.bbox_y0, 0xFFFF);
    k.x_q16 = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    k.y_q16 = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    k.area_px = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    k.intensity_sum = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    k.complete_us = rng();
    return k;
}

inline FieldMarkers random_field_markers(std::mt19937_64& rng) {
    FieldMarkers f;
    f.camera_id = uniform<std::uint8_t>(rng, 0, kCameraCount - 1);
    f.field_parity = uniform<std::uint8_t>(rng, 0, 1);
    f.flags = uniform<std::uint8_t>(rng, 0, kFieldFlagsDefined);
    f.marker_count = uniform<std::uint8_t>(rng, 0, kMaxMarkersPerMessage);
    f.field_counter = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    f.field_end_us = rng();
    f.part_index = uniform<std::uint16_t>(rng, 0, 0xFFFF);
    for (std::size_t i = 0; i < f.marker_count; ++i) f.markers[i] = random_marker(rng);
    return f;
}

inline PedalState random_pedal(std::mt19937_64& rng) {
    PedalState p;
    p.device_us = rng();
    for (auto& a : p.axes) a = uniform<std::uint16_t>(rng, 0, 0xFFFF);
    p.buttons = uniform<std::uint16_t>(rng, 0, 0xFFFF);
    return p;
}

inline DeviceStatus random_status(std::mt19937_64& rng) {
    DeviceStatus s;
    s.device_us = rng();
    s.uptime_us = rng();
    for (auto& c : s.fields_processed) c = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    s.blobs_dropped = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    s.blob_table_overflows = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    s.queue_overflows = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    s.bytes_sent = rng();
    s.crc_errors = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    s.parse_errors = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    return s;
}

inline Command random_command(std::mt19937_64& rng) {
    return Command{uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF), uniform<std::uint8_t>(rng, 0, 255),
                   uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF), uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF), rng()};
}

inline Reply random_reply(std::mt19937_64& rng) {
    Reply r;
    r.command_id = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    r.opcode = uniform<std::uint8_t>(rng, 0, 255);
    r.status = uniform<std::uint8_t>(rng, 0, 1);
    r.reason = r.status == 0 ? 0 : uniform<std::uint8_t>(rng, 1, kMaxNackReason);
    r.value = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    r.host_us = rng();
    r.device_us = rng();
    return r;
}

/// A random valid BlobPatch fragment: any patch size and place in the field, any fragment of it.
inline BlobPatch random_blob_patch(std::mt19937_64& rng) {
    BlobPatch b;
    b.camera_id = uniform<std::uint8_t>(rng, 0, kCameraCount - 1);
    b.field_parity = uniform<std::uint8_t>(rng, 0, 1);
    b.colour_class = uniform<std::uint8_t>(rng, kMinColourClass, kMaxColourClass);
    b.flags = uniform<std::uint8_t>(rng, 0, kPatchFlagsDefined);
    b.field_counter = uniform<std::uint32_t>(rng, 0, 0xFFFFFFFF);
    b.blob_index = uniform<std::uint16_t>(rng, 0, 0xFFFF);
    b.width_px = static_cast<std::uint16_t>(2 * uniform<int>(rng, 1, kPatchMaxWidthPx / 2));
    b.height_px = uniform<std::uint16_t>(rng, 1, kPatchMaxHeightPx);
    b.origin_x = static_cast<std::uint16_t>(2 * uniform<int>(rng, 0, (kPatchFieldWidthPx - b.width_px) / 2));
    b.origin_y = uniform<std::uint16_t>(rng, 0, static_cast<std::uint16_t>(kPatchFieldHeightPx - b.height_px));
    b.fragment_count = static_cast<std::uint8_t>(patch_fragment_count(patch_bytes(b.width_px, b.height_px)));
    b.fragment_index = uniform<std::uint8_t>(rng, 0, static_cast<std::uint8_t>(b.fragment_count - 1));
    for (auto& v : b.samples) v = uniform<std::uint8_t>(rng, 0, 255);
    return b;
}

/// A random valid message of a random type (FieldMarkers more often, as in a real stream).
inline Message random_message(std::mt19937_64& rng) {
    switch (uniform<int>(rng, 0, 7)) {
        case 0: return random_pedal(rng);
        case 1: return random_status(rng);
        case 2: return random_command(rng);
        case 3: return random_reply(rng);
        default: return random_field_markers(rng);
    }
}

/// Encodes `m` as a frame.
inline Bytes frame_of(const Message& m, std::uint16_t seq) {
    Bytes b(kMaxFrameBytes);
    b.resize(encode_frame(m, seq, b));
    return b;
}

}  // namespace eyesim::protocol::test
