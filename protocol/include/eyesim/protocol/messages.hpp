#pragma once
/// \file
/// The eyesim wire messages (protocol version 1) as plain C++ structs, with every capacity as a named constant.
/// docs/protocol.md is the normative byte layout; these structs hold the decoded values (host byte order).
/// No heap anywhere: a `Message` is a std::variant of fixed-size structs.

#include <array>
#include <cstddef>
#include <cstdint>
#include <variant>

namespace eyesim::protocol {

// ---------------------------------------------------------------------------------------------------------------
// Sizes (see frame.hpp for the framing; all multi-byte wire fields are little-endian).
// ---------------------------------------------------------------------------------------------------------------

/// Protocol version carried in every frame header.
inline constexpr std::uint8_t kProtocolVersion = 1;

/// Largest frame on the wire, header + payload + CRC: one USB 2.0 high-speed bulk packet (512 bytes), so a frame
/// never spans two bulk packets and a short packet ends every transfer that carries one frame.
inline constexpr std::size_t kMaxFrameBytes = 512;
/// Frame header bytes: sync (2), version (1), type (1), sequence (2), payload length (2).
inline constexpr std::size_t kFrameHeaderBytes = 8;
/// Frame trailer bytes: CRC-32C (4).
inline constexpr std::size_t kFrameCrcBytes = 4;
/// Largest payload: kMaxFrameBytes - header - CRC = 500 bytes.
inline constexpr std::size_t kMaxPayloadBytes = kMaxFrameBytes - kFrameHeaderBytes - kFrameCrcBytes;

/// Bytes of the fixed part of a FieldMarkers payload (before the marker records).
inline constexpr std::size_t kFieldMarkersHeaderBytes = 18;
/// Bytes of one marker record in a FieldMarkers payload.
inline constexpr std::size_t kMarkerRecordBytes = 34;
/// Markers that fit in one FieldMarkers message (14): derived from the frame limit. A field with more blobs is
/// sent as several messages ("parts"), all but the last with kFieldFlagMoreFollows.
inline constexpr std::size_t kMaxMarkersPerMessage =
    (kMaxPayloadBytes - kFieldMarkersHeaderBytes) / kMarkerRecordBytes;
static_assert(kMaxMarkersPerMessage == 14);

/// Cameras per device (camera ids 0..kCameraCount-1).
inline constexpr std::size_t kCameraCount = 3;
/// Pedal axes carried in PedalState.
inline constexpr std::size_t kPedalAxisCount = 3;

/// Fixed-point scale of marker coordinates: x_q16 / kCoordScale = pixels (resolution 1/65536 px ≈ 1.5e-5 px).
inline constexpr std::uint32_t kCoordScale = 65536;

// ---------------------------------------------------------------------------------------------------------------
// Message types
// ---------------------------------------------------------------------------------------------------------------

/// Wire message type (frame header byte 3).
enum class MessageType : std::uint8_t {
    FieldMarkers = 1,  ///< device → host: marker centroids of one camera field (or part of one)
    PedalState = 2,    ///< device → host: foot pedal axes and buttons
    DeviceStatus = 3,  ///< device → host: health counters
    Command = 4,       ///< host → device: register access, streaming control, ping
    Reply = 5,         ///< device → host: answer to one Command
    BlobPatch = 6,     ///< device → host: one fragment of a blob's pixels (box + halo), precision mode
};
/// Number of message types (type codes 1..kMessageTypeCount).
inline constexpr std::size_t kMessageTypeCount = 6;

// ---------------------------------------------------------------------------------------------------------------
// FieldMarkers
// ---------------------------------------------------------------------------------------------------------------

/// FieldMarkers.flags: more messages (parts) of this same field follow; clear on the field's last part.
inline constexpr std::uint8_t kFieldFlagMoreFollows = 0x01;
/// FieldMarkers.flags: low-latency mode, each part was sent as soon as its blobs completed (field may be open).
inline constexpr std::uint8_t kFieldFlagLowLatency = 0x02;
/// FieldMarkers.flags: blobs of this field were dropped on the device (blob table or queue full).
inline constexpr std::uint8_t kFieldFlagBlobsDropped = 0x04;
/// FieldMarkers.flags: every defined bit; the others must be zero.
inline constexpr std::uint8_t kFieldFlagsDefined = 0x07;

/// Marker.flags: the blob touches the field border (centroid biased, blob may be cut).
inline constexpr std::uint8_t kMarkerFlagTouchesBorder = 0x01;
/// Marker.flags: the blob was formed by merging two or more provisional labels (U- or V-shaped blob).
inline constexpr std::uint8_t kMarkerFlagMerged = 0x02;
/// Marker.flags: the blob touches the edge of the region of interest and is clipped by it.
inline constexpr std::uint8_t kMarkerFlagClippedByRoi = 0x04;
/// Marker.flags: an accumulator (area, intensity sum or moments) saturated; the centroid is unreliable.
inline constexpr std::uint8_t kMarkerFlagSaturated = 0x08;
/// Marker.flags: every defined bit; the others must be zero.
inline constexpr std::uint8_t kMarkerFlagsDefined = 0x0F;

/// Smallest and largest marker colour class (1 red, 2 green, 3 blue, 4 yellow with the reset register map).
inline constexpr std::uint8_t kMinColourClass = 1;
/// Largest marker colour class.
inline constexpr std::uint8_t kMaxColourClass = 4;

/// One blob (marker image) found in a camera field. Coordinates are field pixels: x = column 0..719, y = field
/// row 0..287 (not frame row); the centre of pixel (column i, row j) is at (i, j) exactly, so a centroid is the
/// intensity-weighted mean of integer pixel positions and is never negative.
struct Marker {
    std::uint8_t colour_class = 0;     ///< colour class 1..4
    std::uint8_t flags = 0;            ///< kMarkerFlag* bits
    std::uint16_t bbox_x0 = 0;         ///< bounding box, first column (inclusive), px
    std::uint16_t bbox_y0 = 0;         ///< bounding box, first field row (inclusive), px
    std::uint16_t bbox_x1 = 0;         ///< bounding box, last column (inclusive), px
    std::uint16_t bbox_y1 = 0;         ///< bounding box, last field row (inclusive), px
    std::uint32_t x_q16 = 0;           ///< centroid x in 1/65536 px (x_px = x_q16 / 65536)
    std::uint32_t y_q16 = 0;           ///< centroid y in 1/65536 px (field rows)
    std::uint32_t area_px = 0;         ///< number of pixels in the blob
    std::uint32_t intensity_sum = 0;   ///< sum of the per-pixel weights the centroid was computed with
    std::uint64_t complete_us = 0;     ///< device time the blob was complete (its last pixel seen), µs

    friend bool operator==(const Marker&, const Marker&) = default;
};

/// Markers of one camera field, or one part of them (see kFieldFlagMoreFollows).
struct FieldMarkers {
    std::uint8_t camera_id = 0;       ///< camera 0..2
    std::uint8_t field_parity = 0;    ///< 0 top field, 1 bottom field
    std::uint8_t flags = 0;           ///< kFieldFlag* bits
    std::uint8_t marker_count = 0;    ///< valid entries in `markers`, 0..kMaxMarkersPerMessage
    std::uint32_t field_counter = 0;  ///< per-camera field number since stream start (wraps at 2^32)
    std::uint64_t field_end_us = 0;   ///< device time of the field's end (last active pixel), µs; 0 when the
                                      ///< field had not ended when this part was sent (low-latency parts)
    std::uint16_t part_index = 0;     ///< 0 for the field's first message, +1 for each further part
    std::array<Marker, kMaxMarkersPerMessage> markers{};  ///< the first marker_count entries are valid

    /// Equality over the header and the first marker_count markers (unused slots are ignored).
    friend bool operator==(const FieldMarkers& a, const FieldMarkers& b) noexcept {
        if (a.camera_id != b.camera_id || a.field_parity != b.field_parity || a.flags != b.flags ||
            a.marker_count != b.marker_count || a.field_counter != b.field_counter ||
            a.field_end_us != b.field_end_us || a.part_index != b.part_index)
            return false;
        for (std::size_t i = 0; i < a.marker_count && i < kMaxMarkersPerMessage; ++i)
            if (!(a.markers[i] == b.markers[i])) return false;
        return true;
    }
};

// ---------------------------------------------------------------------------------------------------------------
// PedalState
// ---------------------------------------------------------------------------------------------------------------

/// Foot pedal state, sent on change and at a steady rate.
struct PedalState {
    std::uint64_t device_us = 0;                          ///< device time of the sample, µs
    std::array<std::uint16_t, kPedalAxisCount> axes{};    ///< axes normalised 0 (released) .. 65535 (full travel)
    std::uint16_t buttons = 0;                            ///< button bitmask, bit i = button i pressed

    friend bool operator==(const PedalState&, const PedalState&) = default;
};

// ---------------------------------------------------------------------------------------------------------------
// DeviceStatus
// ---------------------------------------------------------------------------------------------------------------

/// Device health counters (all monotonic since power-up, wrapping at their width). No temperature.
struct DeviceStatus {
    std::uint64_t device_us = 0;                                    ///< device time of this report, µs
    std::uint64_t uptime_us = 0;                                    ///< time since power-up, µs
    std::array<std::uint32_t, kCameraCount> fields_processed{};     ///< fields processed, per camera
    std::uint32_t blobs_dropped = 0;          ///< blobs found but not sent (any reason)
    std::uint32_t blob_table_overflows = 0;   ///< times a camera's blob table was full
    std::uint32_t queue_overflows = 0;        ///< packets dropped because the transmit queue was full
    std::uint64_t bytes_sent = 0;             ///< bytes handed to the transport
    std::uint32_t crc_errors = 0;             ///< received command frames that failed the CRC
    std::uint32_t parse_errors = 0;           ///< other framing/payload errors in received command bytes

    friend bool operator==(const DeviceStatus&, const DeviceStatus&) = default;
};

// ---------------------------------------------------------------------------------------------------------------
// Command / Reply
// ---------------------------------------------------------------------------------------------------------------

/// Command opcodes. The decoder passes unknown opcodes through so the device can NACK them (kBadOpcode).
enum class Opcode : std::uint8_t {
    RegisterWrite = 1,   ///< write `value` to register `address`
    RegisterRead = 2,    ///< read register `address`; the Reply carries the value
    StreamStart = 3,     ///< start sending FieldMarkers / PedalState / DeviceStatus
    StreamStop = 4,      ///< stop streaming
    Ping = 5,            ///< host_us is echoed in the Reply with the device time (pong)
    SetLowLatency = 6,   ///< value 1: send each blob as soon as it completes; 0: one message train per field
};

/// A host → device request.
struct Command {
    std::uint32_t command_id = 0;  ///< chosen by the host, echoed in the Reply
    std::uint8_t opcode = 0;       ///< an Opcode value (raw, so unknown opcodes survive decoding)
    std::uint32_t address = 0;     ///< register address (RegisterWrite/Read), else 0
    std::uint32_t value = 0;       ///< register value (RegisterWrite), 0/1 (SetLowLatency), else 0
    std::uint64_t host_us = 0;     ///< host time when sent, µs (Ping; any command may set it)

    friend bool operator==(const Command&, const Command&) = default;
};

/// Reply status.
enum class ReplyStatus : std::uint8_t {
    Ack = 0,   ///< done
    Nack = 1,  ///< refused; see NackReason
};

/// Why a command was refused.
enum class NackReason : std::uint8_t {
    None = 0,           ///< (Ack)
    BadOpcode = 1,      ///< unknown opcode
    BadAddress = 2,     ///< no register at that address
    BadRange = 3,       ///< value outside the register's width or range
    ReadOnly = 4,       ///< write to a read-only register
    Busy = 5,           ///< cannot be done now (e.g. register locked while streaming)
    Malformed = 6,      ///< fields inconsistent for this opcode
};
/// Largest defined NackReason value.
inline constexpr std::uint8_t kMaxNackReason = 6;

/// A device → host answer to exactly one Command.
struct Reply {
    std::uint32_t command_id = 0;  ///< the Command's command_id
    std::uint8_t opcode = 0;       ///< the Command's opcode (echoed, raw)
    std::uint8_t status = 0;       ///< a ReplyStatus value
    std::uint8_t reason = 0;       ///< a NackReason value (0 with Ack)
    std::uint32_t value = 0;       ///< register value (RegisterRead; RegisterWrite: value now in the register)
    std::uint64_t host_us = 0;     ///< the Command's host_us, echoed (pong)
    std::uint64_t device_us = 0;   ///< device time when the command was executed, µs

    friend bool operator==(const Reply&, const Reply&) = default;
};

// ---------------------------------------------------------------------------------------------------------------
// BlobPatch
// ---------------------------------------------------------------------------------------------------------------

/// Bytes of the fixed part of a BlobPatch payload (before the samples).
inline constexpr std::size_t kBlobPatchHeaderBytes = 20;
/// Sample bytes in one BlobPatch fragment at most: 118 UYVY pixel pairs (whole pairs only), so the largest
/// BlobPatch frame is 504 bytes, within the largest FieldMarkers frame (506).
inline constexpr std::size_t kPatchFragmentBytes = 472;
static_assert(kFrameHeaderBytes + kBlobPatchHeaderBytes + kPatchFragmentBytes + kFrameCrcBytes == 504 &&
              kPatchFragmentBytes % 4 == 0);
/// Widest patch, px (even: whole UYVY pairs).
inline constexpr std::uint16_t kPatchMaxWidthPx = 64;
/// Tallest patch, field rows (the device's patch line buffers hold this many lines).
inline constexpr std::uint16_t kPatchMaxHeightPx = 32;
/// Largest patch in sample bytes (2 per pixel: UYVY).
inline constexpr std::size_t kPatchMaxBytes = 2u * kPatchMaxWidthPx * kPatchMaxHeightPx;
/// Fragments of the largest patch (9).
inline constexpr std::size_t kPatchMaxFragments = (kPatchMaxBytes + kPatchFragmentBytes - 1) / kPatchFragmentBytes;
/// Field width and height, px, that bound a patch (PAL field: 720 × 288).
inline constexpr std::uint16_t kPatchFieldWidthPx = 720, kPatchFieldHeightPx = 288;

/// BlobPatch.flags: the box plus halo reached the field's edge and was clipped to it.
inline constexpr std::uint8_t kPatchFlagClipped = 0x01;
/// BlobPatch.flags: every defined bit; the others must be zero.
inline constexpr std::uint8_t kPatchFlagsDefined = 0x01;

/// Sample bytes of a width × height patch.
constexpr std::size_t patch_bytes(std::uint16_t width_px, std::uint16_t height_px) noexcept {
    return std::size_t{2} * width_px * height_px;
}
/// Fragments a patch of `bytes` sample bytes is sent in (at least 1).
constexpr std::size_t patch_fragment_count(std::size_t bytes) noexcept {
    return bytes == 0 ? 1 : (bytes + kPatchFragmentBytes - 1) / kPatchFragmentBytes;
}

/// One fragment of a blob's patch: the field's UYVY samples (Cb Y Cr Y per pixel pair, as BT.656 carries them)
/// of the rectangle [origin_x, origin_x + width_px) × [origin_y, origin_y + height_px), row by row. Fragment i
/// carries sample bytes [i · kPatchFragmentBytes, min(total, (i + 1) · kPatchFragmentBytes)) of the patch.
struct BlobPatch {
    std::uint8_t camera_id = 0;       ///< camera 0..2
    std::uint8_t field_parity = 0;    ///< 0 top field, 1 bottom field
    std::uint8_t colour_class = 0;    ///< the blob's colour class 1..4
    std::uint8_t flags = 0;           ///< kPatchFlag* bits
    std::uint32_t field_counter = 0;  ///< the field's FieldMarkers field_counter
    std::uint16_t blob_index = 0;     ///< position of the blob's Marker in the field's FieldMarkers, counted
                                      ///< over its parts in order from 0
    std::uint16_t origin_x = 0;       ///< first column, px (even)
    std::uint16_t origin_y = 0;       ///< first field row, px
    std::uint16_t width_px = 0;       ///< columns (even, 2..kPatchMaxWidthPx)
    std::uint16_t height_px = 0;      ///< field rows (1..kPatchMaxHeightPx)
    std::uint8_t fragment_index = 0;  ///< 0..fragment_count-1
    std::uint8_t fragment_count = 0;  ///< patch_fragment_count(patch_bytes(width_px, height_px))
    std::array<std::uint8_t, kPatchFragmentBytes> samples{};  ///< the first sample_bytes() entries are valid

    /// Sample bytes this fragment carries (0 when the header is inconsistent).
    constexpr std::size_t sample_bytes() const noexcept {
        const std::size_t total = patch_bytes(width_px, height_px);
        const std::size_t first = static_cast<std::size_t>(fragment_index) * kPatchFragmentBytes;
        if (first >= total) return 0;
        return total - first < kPatchFragmentBytes ? total - first : kPatchFragmentBytes;
    }

    /// Equality over the header and the valid samples.
    friend bool operator==(const BlobPatch& a, const BlobPatch& b) noexcept {
        if (a.camera_id != b.camera_id || a.field_parity != b.field_parity || a.colour_class != b.colour_class ||
            a.flags != b.flags || a.field_counter != b.field_counter || a.blob_index != b.blob_index ||
            a.origin_x != b.origin_x || a.origin_y != b.origin_y || a.width_px != b.width_px ||
            a.height_px != b.height_px || a.fragment_index != b.fragment_index ||
            a.fragment_count != b.fragment_count)
            return false;
        const std::size_t n = a.sample_bytes();
        for (std::size_t i = 0; i < n; ++i)
            if (a.samples[i] != b.samples[i]) return false;
        return true;
    }
};

// ---------------------------------------------------------------------------------------------------------------
// Message
// ---------------------------------------------------------------------------------------------------------------

/// Any one message. The variant index + 1 is the wire MessageType value.
using Message = std::variant<FieldMarkers, PedalState, DeviceStatus, Command, Reply, BlobPatch>;

/// The wire type of a message.
constexpr MessageType message_type(const Message& m) noexcept {
    return static_cast<MessageType>(m.index() + 1);
}

/// Human/JSON name of a message type ("FieldMarkers", ...), or "Unknown".
constexpr const char* message_type_name(MessageType t) noexcept {
    switch (t) {
        case MessageType::FieldMarkers: return "FieldMarkers";
        case MessageType::PedalState: return "PedalState";
        case MessageType::DeviceStatus: return "DeviceStatus";
        case MessageType::Command: return "Command";
        case MessageType::Reply: return "Reply";
        case MessageType::BlobPatch: return "BlobPatch";
    }
    return "Unknown";
}

}  // namespace eyesim::protocol
