#pragma once
/// \file
/// Encoder and single-frame decoder. No heap, no exceptions: every function reports failure by its return value.

#include "eyesim/protocol/frame.hpp"
#include "eyesim/protocol/messages.hpp"

#include <cstddef>
#include <cstdint>
#include <span>

namespace eyesim::protocol {

/// Why a payload or frame did not decode.
enum class DecodeError : std::uint8_t {
    None = 0,         ///< decoded
    TooShort,         ///< fewer bytes than the header or the header's length announce
    BadSync,          ///< the first two bytes are not 0xE7 0x5A
    BadVersion,       ///< version byte is not kProtocolVersion
    UnknownType,      ///< message type not 1..kMessageTypeCount
    BadLength,        ///< payload length over kMaxPayloadBytes or not valid for the type
    BadCrc,           ///< CRC mismatch (corruption, or a peer with another schema)
    BadPayload,       ///< CRC good but a field is out of its documented range
};

/// Name of a DecodeError ("none", "too_short", ...).
const char* decode_error_name(DecodeError e) noexcept;

/// Checks a message against its documented ranges (camera id, parity, colour class, flags, bbox order, counts).
bool valid_message(const Message& m) noexcept;

/// Payload size of a message on the wire (FieldMarkers depends on marker_count; capped at the maximum).
std::size_t payload_size(const Message& m) noexcept;

/// Serialises the payload of `m` into `out`; returns bytes written, or 0 when `out` is too small or `m` is not
/// valid_message().
std::size_t encode_payload(const Message& m, std::span<std::uint8_t> out) noexcept;

/// Decodes a payload of type `type` into `out`; checks the length and every field's range.
DecodeError decode_payload(MessageType type, std::span<const std::uint8_t> payload, Message& out) noexcept;

/// Encodes `m` as one complete frame with sequence number `sequence`; returns the frame size, or 0 when `out`
/// is too small or `m` is invalid.
std::size_t encode_frame(const Message& m, std::uint16_t sequence, std::span<std::uint8_t> out) noexcept;

/// Frames arbitrary payload bytes with a correct CRC for `type` (no payload check): for tests, fuzzing and
/// tools. `schema` is the hash mixed into the CRC (normally schema_hash(type)). Returns 0 when it does not fit.
std::size_t encode_frame_raw(std::uint8_t type, std::uint16_t sequence, std::span<const std::uint8_t> payload,
                             std::span<std::uint8_t> out, std::uint32_t schema,
                             std::uint8_t version = kProtocolVersion) noexcept;

/// The CRC a frame must carry: CRC-32C over `covered` (bytes 2..8+N of the frame) then the LE schema hash.
std::uint32_t frame_crc(std::span<const std::uint8_t> covered, std::uint32_t schema) noexcept;

/// Decodes exactly one frame starting at bytes[0]. On success `consumed` is the frame size.
DecodeError decode_frame(std::span<const std::uint8_t> bytes, DecodedFrame& out, std::size_t& consumed) noexcept;

}  // namespace eyesim::protocol
