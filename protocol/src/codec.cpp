#include "eyesim/protocol/codec.hpp"

#include "eyesim/protocol/crc32c.hpp"
#include "eyesim/protocol/schema.hpp"
#include "wire_io.hpp"

#include <type_traits>

namespace eyesim::protocol {

using namespace wire;

namespace {

bool valid_marker(const Marker& k) noexcept {
    return k.colour_class >= kMinColourClass && k.colour_class <= kMaxColourClass &&
           (k.flags & ~kMarkerFlagsDefined) == 0 && k.bbox_x0 <= k.bbox_x1 && k.bbox_y0 <= k.bbox_y1;
}

bool valid(const FieldMarkers& f) noexcept {
    if (f.camera_id >= kCameraCount || f.field_parity > 1 || (f.flags & ~kFieldFlagsDefined) != 0 ||
        f.marker_count > kMaxMarkersPerMessage)
        return false;
    for (std::size_t i = 0; i < f.marker_count; ++i)
        if (!valid_marker(f.markers[i])) return false;
    return true;
}
bool valid(const PedalState&) noexcept { return true; }
bool valid(const DeviceStatus&) noexcept { return true; }
bool valid(const Command&) noexcept { return true; }  // unknown opcodes pass: the device NACKs them
bool valid(const Reply& r) noexcept {
    if (r.status == static_cast<std::uint8_t>(ReplyStatus::Ack)) return r.reason == 0;
    if (r.status == static_cast<std::uint8_t>(ReplyStatus::Nack)) return r.reason >= 1 && r.reason <= kMaxNackReason;
    return false;
}
bool valid(const BlobPatch& b) noexcept {
    if (b.camera_id >= kCameraCount || b.field_parity > 1 || b.colour_class < kMinColourClass ||
        b.colour_class > kMaxColourClass || (b.flags & ~kPatchFlagsDefined) != 0)
        return false;
    if (b.width_px < 2 || b.width_px > kPatchMaxWidthPx || b.width_px % 2 != 0 || b.height_px < 1 ||
        b.height_px > kPatchMaxHeightPx || b.origin_x % 2 != 0)
        return false;
    if (b.origin_x + b.width_px > kPatchFieldWidthPx || b.origin_y + b.height_px > kPatchFieldHeightPx) return false;
    return b.fragment_count == patch_fragment_count(patch_bytes(b.width_px, b.height_px)) &&
           b.fragment_index < b.fragment_count;
}

std::size_t size_of(const FieldMarkers& f) noexcept {
    const std::size_t n = f.marker_count <= kMaxMarkersPerMessage ? f.marker_count : kMaxMarkersPerMessage;
    return kFieldMarkersHeaderBytes + n * kMarkerRecordBytes;
}
std::size_t size_of(const PedalState&) noexcept { return kPedalStatePayloadBytes; }
std::size_t size_of(const DeviceStatus&) noexcept { return kDeviceStatusPayloadBytes; }
std::size_t size_of(const Command&) noexcept { return kCommandPayloadBytes; }
std::size_t size_of(const Reply&) noexcept { return kReplyPayloadBytes; }
std::size_t size_of(const BlobPatch& b) noexcept { return kBlobPatchHeaderBytes + b.sample_bytes(); }

void put(std::uint8_t* p, const FieldMarkers& f) noexcept {
    put_u8(p + 0, f.camera_id);
    put_u8(p + 1, f.field_parity);
    put_u8(p + 2, f.flags);
    put_u8(p + 3, f.marker_count);
    put_u32(p + 4, f.field_counter);
    put_u64(p + 8, f.field_end_us);
    put_u16(p + 16, f.part_index);
    std::uint8_t* m = p + kFieldMarkersHeaderBytes;
    for (std::size_t i = 0; i < f.marker_count; ++i, m += kMarkerRecordBytes) {
        const Marker& k = f.markers[i];
        put_u8(m + 0, k.colour_class);
        put_u8(m + 1, k.flags);
        put_u16(m + 2, k.bbox_x0);
        put_u16(m + 4, k.bbox_y0);
        put_u16(m + 6, k.bbox_x1);
        put_u16(m + 8, k.bbox_y1);
        put_u32(m + 10, k.x_q16);
        put_u32(m + 14, k.y_q16);
        put_u32(m + 18, k.area_px);
        put_u32(m + 22, k.intensity_sum);
        put_u64(m + 26, k.complete_us);
    }
}
void put(std::uint8_t* p, const PedalState& s) noexcept {
    put_u64(p + 0, s.device_us);
    for (std::size_t i = 0; i < kPedalAxisCount; ++i) put_u16(p + 8 + 2 * i, s.axes[i]);
    put_u16(p + 14, s.buttons);
}
void put(std::uint8_t* p, const DeviceStatus& s) noexcept {
    put_u64(p + 0, s.device_us);
    put_u64(p + 8, s.uptime_us);
    for (std::size_t i = 0; i < kCameraCount; ++i) put_u32(p + 16 + 4 * i, s.fields_processed[i]);
    put_u32(p + 28, s.blobs_dropped);
    put_u32(p + 32, s.blob_table_overflows);
    put_u32(p + 36, s.queue_overflows);
    put_u64(p + 40, s.bytes_sent);
    put_u32(p + 48, s.crc_errors);
    put_u32(p + 52, s.parse_errors);
}
void put(std::uint8_t* p, const Command& c) noexcept {
    put_u32(p + 0, c.command_id);
    put_u8(p + 4, c.opcode);
    put_u32(p + 5, c.address);
    put_u32(p + 9, c.value);
    put_u64(p + 13, c.host_us);
}
void put(std::uint8_t* p, const Reply& r) noexcept {
    put_u32(p + 0, r.command_id);
    put_u8(p + 4, r.opcode);
    put_u8(p + 5, r.status);
    put_u8(p + 6, r.reason);
    put_u32(p + 7, r.value);
    put_u64(p + 11, r.host_us);
    put_u64(p + 19, r.device_us);
}
void put(std::uint8_t* p, const BlobPatch& b) noexcept {
    put_u8(p + 0, b.camera_id);
    put_u8(p + 1, b.field_parity);
    put_u8(p + 2, b.colour_class);
    put_u8(p + 3, b.flags);
    put_u32(p + 4, b.field_counter);
    put_u16(p + 8, b.blob_index);
    put_u16(p + 10, b.origin_x);
    put_u16(p + 12, b.origin_y);
    put_u16(p + 14, b.width_px);
    put_u16(p + 16, b.height_px);
    put_u8(p + 18, b.fragment_index);
    put_u8(p + 19, b.fragment_count);
    const std::size_t n = b.sample_bytes();
    for (std::size_t i = 0; i < n; ++i) p[kBlobPatchHeaderBytes + i] = b.samples[i];
}

void get(const std::uint8_t* p, FieldMarkers& f) noexcept {
    f.camera_id = get_u8(p + 0);
    f.field_parity = get_u8(p + 1);
    f.flags = get_u8(p + 2);
    f.marker_count = get_u8(p + 3);
    f.field_counter = get_u32(p + 4);
    f.field_end_us = get_u64(p + 8);
    f.part_index = get_u16(p + 16);
    const std::uint8_t* m = p + kFieldMarkersHeaderBytes;
    for (std::size_t i = 0; i < f.marker_count; ++i, m += kMarkerRecordBytes) {
        Marker& k = f.markers[i];
        k.colour_class = get_u8(m + 0);
        k.flags = get_u8(m + 1);
        k.bbox_x0 = get_u16(m + 2);
        k.bbox_y0 = get_u16(m + 4);
        k.bbox_x1 = get_u16(m + 6);
        k.bbox_y1 = get_u16(m + 8);
        k.x_q16 = get_u32(m + 10);
        k.y_q16 = get_u32(m + 14);
        k.area_px = get_u32(m + 18);
        k.intensity_sum = get_u32(m + 22);
        k.complete_us = get_u64(m + 26);
    }
    for (std::size_t i = f.marker_count; i < kMaxMarkersPerMessage; ++i) f.markers[i] = Marker{};
}
void get(const std::uint8_t* p, PedalState& s) noexcept {
    s.device_us = get_u64(p + 0);
    for (std::size_t i = 0; i < kPedalAxisCount; ++i) s.axes[i] = get_u16(p + 8 + 2 * i);
    s.buttons = get_u16(p + 14);
}
void get(const std::uint8_t* p, DeviceStatus& s) noexcept {
    s.device_us = get_u64(p + 0);
    s.uptime_us = get_u64(p + 8);
    for (std::size_t i = 0; i < kCameraCount; ++i) s.fields_processed[i] = get_u32(p + 16 + 4 * i);
    s.blobs_dropped = get_u32(p + 28);
    s.blob_table_overflows = get_u32(p + 32);
    s.queue_overflows = get_u32(p + 36);
    s.bytes_sent = get_u64(p + 40);
    s.crc_errors = get_u32(p + 48);
    s.parse_errors = get_u32(p + 52);
}
void get(const std::uint8_t* p, Command& c) noexcept {
    c.command_id = get_u32(p + 0);
    c.opcode = get_u8(p + 4);
    c.address = get_u32(p + 5);
    c.value = get_u32(p + 9);
    c.host_us = get_u64(p + 13);
}
void get(const std::uint8_t* p, Reply& r) noexcept {
    r.command_id = get_u32(p + 0);
    r.opcode = get_u8(p + 4);
    r.status = get_u8(p + 5);
    r.reason = get_u8(p + 6);
    r.value = get_u32(p + 7);
    r.host_us = get_u64(p + 11);
    r.device_us = get_u64(p + 19);
}
void get(const std::uint8_t* p, BlobPatch& b) noexcept {
    b.camera_id = get_u8(p + 0);
    b.field_parity = get_u8(p + 1);
    b.colour_class = get_u8(p + 2);
    b.flags = get_u8(p + 3);
    b.field_counter = get_u32(p + 4);
    b.blob_index = get_u16(p + 8);
    b.origin_x = get_u16(p + 10);
    b.origin_y = get_u16(p + 12);
    b.width_px = get_u16(p + 14);
    b.height_px = get_u16(p + 16);
    b.fragment_index = get_u8(p + 18);
    b.fragment_count = get_u8(p + 19);
    // Called only once the length is known to match sample_bytes() (decode_as).
    const std::size_t n = b.sample_bytes();
    for (std::size_t i = 0; i < n; ++i) b.samples[i] = p[kBlobPatchHeaderBytes + i];
}

template <class T>
DecodeError decode_as(MessageType type, std::span<const std::uint8_t> payload, Message& out) noexcept {
    // Emplace only the alternative; the FieldMarkers marker array is filled by get().
    T* held = std::get_if<T>(&out);
    T& m = held ? *held : out.emplace<T>();
    if (!valid_payload_length(type, payload.size())) return DecodeError::BadLength;
    if constexpr (std::is_same_v<T, FieldMarkers>) {
        // The length is a valid FieldMarkers length; a marker_count that disagrees with it is a payload error.
        if (payload.size() != kFieldMarkersHeaderBytes + payload[3] * kMarkerRecordBytes) return DecodeError::BadPayload;
    }
    if constexpr (std::is_same_v<T, BlobPatch>) {
        // The samples the header announces must be exactly the bytes after it, and the header must be in range
        // before sample_bytes() is trusted.
        BlobPatch h;
        h.width_px = get_u16(payload.data() + 14);
        h.height_px = get_u16(payload.data() + 16);
        h.fragment_index = get_u8(payload.data() + 18);
        if (payload.size() != kBlobPatchHeaderBytes + h.sample_bytes()) return DecodeError::BadPayload;
    }
    get(payload.data(), m);
    return valid(m) ? DecodeError::None : DecodeError::BadPayload;
}

}  // namespace

const char* decode_error_name(DecodeError e) noexcept {
    switch (e) {
        case DecodeError::None: return "none";
        case DecodeError::TooShort: return "too_short";
        case DecodeError::BadSync: return "bad_sync";
        case DecodeError::BadVersion: return "bad_version";
        case DecodeError::UnknownType: return "unknown_type";
        case DecodeError::BadLength: return "bad_length";
        case DecodeError::BadCrc: return "bad_crc";
        case DecodeError::BadPayload: return "bad_payload";
    }
    return "unknown";
}

bool valid_payload_length(MessageType type, std::size_t n) noexcept {
    switch (type) {
        case MessageType::FieldMarkers:
            return n >= kFieldMarkersHeaderBytes && n <= kMaxPayloadBytes &&
                   (n - kFieldMarkersHeaderBytes) % kMarkerRecordBytes == 0 &&
                   (n - kFieldMarkersHeaderBytes) / kMarkerRecordBytes <= kMaxMarkersPerMessage;
        case MessageType::PedalState: return n == kPedalStatePayloadBytes;
        case MessageType::DeviceStatus: return n == kDeviceStatusPayloadBytes;
        case MessageType::Command: return n == kCommandPayloadBytes;
        case MessageType::Reply: return n == kReplyPayloadBytes;
        case MessageType::BlobPatch:
            return n >= kBlobPatchHeaderBytes + 4 && n <= kBlobPatchHeaderBytes + kPatchFragmentBytes &&
                   (n - kBlobPatchHeaderBytes) % 4 == 0;
    }
    return false;
}

bool valid_message(const Message& m) noexcept {
    return std::visit([](const auto& v) { return valid(v); }, m);
}

std::size_t payload_size(const Message& m) noexcept {
    return std::visit([](const auto& v) { return size_of(v); }, m);
}

std::size_t encode_payload(const Message& m, std::span<std::uint8_t> out) noexcept {
    return std::visit(
        [&](const auto& v) -> std::size_t {
            const std::size_t n = size_of(v);
            if (!valid(v) || out.size() < n) return 0;
            put(out.data(), v);
            return n;
        },
        m);
}

DecodeError decode_payload(MessageType type, std::span<const std::uint8_t> payload, Message& out) noexcept {
    switch (type) {
        case MessageType::FieldMarkers: return decode_as<FieldMarkers>(type, payload, out);
        case MessageType::PedalState: return decode_as<PedalState>(type, payload, out);
        case MessageType::DeviceStatus: return decode_as<DeviceStatus>(type, payload, out);
        case MessageType::Command: return decode_as<Command>(type, payload, out);
        case MessageType::Reply: return decode_as<Reply>(type, payload, out);
        case MessageType::BlobPatch: return decode_as<BlobPatch>(type, payload, out);
    }
    return DecodeError::UnknownType;
}

std::uint32_t frame_crc(std::span<const std::uint8_t> covered, std::uint32_t schema) noexcept {
    std::uint8_t s[4];
    put_u32(s, schema);
    return crc32c_finish(crc32c_update(crc32c_update(kCrc32cInit, covered), s));
}

namespace {
void put_header(std::uint8_t* p, std::uint8_t version, std::uint8_t type, std::uint16_t seq, std::size_t n) noexcept {
    p[0] = kSync0;
    p[1] = kSync1;
    p[2] = version;
    p[3] = type;
    put_u16(p + 4, seq);
    put_u16(p + 6, static_cast<std::uint16_t>(n));
}
void put_crc(std::uint8_t* p, std::size_t n, std::uint32_t schema) noexcept {
    put_u32(p + kFrameHeaderBytes + n, frame_crc({p + 2, kFrameHeaderBytes - 2 + n}, schema));
}
}  // namespace

std::size_t encode_frame(const Message& m, std::uint16_t sequence, std::span<std::uint8_t> out) noexcept {
    const std::size_t n = payload_size(m);
    if (out.size() < frame_size(n)) return 0;
    if (encode_payload(m, out.subspan(kFrameHeaderBytes, n)) != n) return 0;
    const MessageType type = message_type(m);
    put_header(out.data(), kProtocolVersion, static_cast<std::uint8_t>(type), sequence, n);
    put_crc(out.data(), n, schema_hash(type));
    return frame_size(n);
}

std::size_t encode_frame_raw(std::uint8_t type, std::uint16_t sequence, std::span<const std::uint8_t> payload,
                             std::span<std::uint8_t> out, std::uint32_t schema, std::uint8_t version) noexcept {
    const std::size_t n = payload.size();
    if (n > 0xFFFF || out.size() < frame_size(n)) return 0;
    put_header(out.data(), version, type, sequence, n);
    for (std::size_t i = 0; i < n; ++i) out[kFrameHeaderBytes + i] = payload[i];
    put_crc(out.data(), n, schema);
    return frame_size(n);
}

DecodeError decode_frame(std::span<const std::uint8_t> bytes, DecodedFrame& out, std::size_t& consumed) noexcept {
    consumed = 0;
    if (bytes.size() < kFrameHeaderBytes) return DecodeError::TooShort;
    const std::uint8_t* p = bytes.data();
    if (p[0] != kSync0 || p[1] != kSync1) return DecodeError::BadSync;
    if (p[2] != kProtocolVersion) return DecodeError::BadVersion;
    if (p[3] < 1 || p[3] > kMessageTypeCount) return DecodeError::UnknownType;
    const auto type = static_cast<MessageType>(p[3]);
    const std::size_t n = get_u16(p + 6);
    if (n > kMaxPayloadBytes || !valid_payload_length(type, n)) return DecodeError::BadLength;
    if (bytes.size() < frame_size(n)) return DecodeError::TooShort;
    if (get_u32(p + kFrameHeaderBytes + n) != frame_crc({p + 2, kFrameHeaderBytes - 2 + n}, schema_hash(type)))
        return DecodeError::BadCrc;
    out.header = FrameHeader{p[2], type, get_u16(p + 4), static_cast<std::uint16_t>(n)};
    const DecodeError e = decode_payload(type, {p + kFrameHeaderBytes, n}, out.message);
    if (e == DecodeError::None) consumed = frame_size(n);
    return e;
}

}  // namespace eyesim::protocol
