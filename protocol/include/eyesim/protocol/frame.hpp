#pragma once
/// \file
/// Frame layout (little-endian everywhere):
///
///   offset 0  u8   sync0 = 0xE7
///   offset 1  u8   sync1 = 0x5A
///   offset 2  u8   version (kProtocolVersion)
///   offset 3  u8   message type (MessageType)
///   offset 4  u16  sequence number (per sender, +1 per frame, wraps)
///   offset 6  u16  payload length N
///   offset 8  N    payload
///   offset 8+N u32 CRC-32C over bytes [2, 8+N) followed by the 4 bytes of the type's schema hash (LE)
///
/// kMaxFrameBytes (512) bounds 12 + N.

#include "eyesim/protocol/messages.hpp"

#include <cstddef>
#include <cstdint>

namespace eyesim::protocol {

/// First sync byte.
inline constexpr std::uint8_t kSync0 = 0xE7;
/// Second sync byte.
inline constexpr std::uint8_t kSync1 = 0x5A;

/// Payload sizes of the fixed-size message types.
inline constexpr std::size_t kPedalStatePayloadBytes = 16;
/// DeviceStatus payload bytes.
inline constexpr std::size_t kDeviceStatusPayloadBytes = 56;
/// Command payload bytes.
inline constexpr std::size_t kCommandPayloadBytes = 21;
/// Reply payload bytes.
inline constexpr std::size_t kReplyPayloadBytes = 27;

/// The decoded frame header.
struct FrameHeader {
    std::uint8_t version = kProtocolVersion;         ///< protocol version
    MessageType type = MessageType::FieldMarkers;    ///< message type
    std::uint16_t sequence = 0;                      ///< sender's sequence number
    std::uint16_t payload_bytes = 0;                 ///< payload length N

    friend bool operator==(const FrameHeader&, const FrameHeader&) = default;
};

/// A frame decoded into its header and message.
struct DecodedFrame {
    FrameHeader header;  ///< header fields
    Message message;     ///< the message (its index matches header.type)
};

/// True when `n` is a valid payload length for `type` (FieldMarkers: 18 + 34·k with k ≤ 14; BlobPatch: 20 + 4·j,
/// 1 ≤ j ≤ 118).
bool valid_payload_length(MessageType type, std::size_t n) noexcept;

/// Total frame size for a payload of `payload_bytes`.
constexpr std::size_t frame_size(std::size_t payload_bytes) noexcept {
    return kFrameHeaderBytes + payload_bytes + kFrameCrcBytes;
}

}  // namespace eyesim::protocol
