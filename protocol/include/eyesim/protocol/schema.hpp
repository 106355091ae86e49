#pragma once
/// \file
/// Canonical schema strings and schema hashes (MAVLink CRC_EXTRA style). Each message type's schema string lists
/// its wire fields in order as `name:type`; its CRC-32C is the schema hash, which every frame mixes into its CRC
/// (see frame.hpp). A peer built from a different layout computes another hash, so its frames fail the CRC.

#include "eyesim/protocol/crc32c.hpp"
#include "eyesim/protocol/messages.hpp"

#include <array>
#include <cstddef>
#include <cstdint>
#include <string_view>

namespace eyesim::protocol {

/// Schema string of FieldMarkers: the fixed part, then the repeated Marker record.
inline constexpr std::string_view kFieldMarkersSchema =
    "FieldMarkers{camera_id:u8,field_parity:u8,flags:u8,marker_count:u8,field_counter:u32,field_end_us:u64,"
    "part_index:u16,markers:Marker[marker_count<=14]}"
    "Marker{colour_class:u8,flags:u8,bbox_x0:u16,bbox_y0:u16,bbox_x1:u16,bbox_y1:u16,x_q16:u32,y_q16:u32,"
    "area_px:u32,intensity_sum:u32,complete_us:u64}";
/// Schema string of PedalState.
inline constexpr std::string_view kPedalStateSchema = "PedalState{device_us:u64,axes:u16[3],buttons:u16}";
/// Schema string of DeviceStatus.
inline constexpr std::string_view kDeviceStatusSchema =
    "DeviceStatus{device_us:u64,uptime_us:u64,fields_processed:u32[3],blobs_dropped:u32,"
    "blob_table_overflows:u32,queue_overflows:u32,bytes_sent:u64,crc_errors:u32,parse_errors:u32}";
/// Schema string of Command.
inline constexpr std::string_view kCommandSchema =
    "Command{command_id:u32,opcode:u8,address:u32,value:u32,host_us:u64}";
/// Schema string of Reply.
inline constexpr std::string_view kReplySchema =
    "Reply{command_id:u32,opcode:u8,status:u8,reason:u8,value:u32,host_us:u64,device_us:u64}";

/// Schema string of BlobPatch: the fixed part, then the fragment's UYVY sample bytes.
inline constexpr std::string_view kBlobPatchSchema =
    "BlobPatch{camera_id:u8,field_parity:u8,colour_class:u8,flags:u8,field_counter:u32,blob_index:u16,"
    "origin_x:u16,origin_y:u16,width_px:u16,height_px:u16,fragment_index:u8,fragment_count:u8,"
    "samples:u8[<=472]}";

/// Schema string of a message type ("" for an unknown type).
constexpr std::string_view schema_string(MessageType t) noexcept {
    switch (t) {
        case MessageType::FieldMarkers: return kFieldMarkersSchema;
        case MessageType::PedalState: return kPedalStateSchema;
        case MessageType::DeviceStatus: return kDeviceStatusSchema;
        case MessageType::Command: return kCommandSchema;
        case MessageType::Reply: return kReplySchema;
        case MessageType::BlobPatch: return kBlobPatchSchema;
    }
    return {};
}

namespace detail {
/// Schema hashes by type code, computed at compile time (index 0 unused).
inline constexpr std::array<std::uint32_t, kMessageTypeCount + 1> kSchemaHashes = {
    0u, crc32c(kFieldMarkersSchema), crc32c(kPedalStateSchema), crc32c(kDeviceStatusSchema), crc32c(kCommandSchema),
    crc32c(kReplySchema), crc32c(kBlobPatchSchema)};
}  // namespace detail

/// Schema hash of a message type: CRC-32C of its schema string (0 for an unknown type). A table look-up.
constexpr std::uint32_t schema_hash(MessageType t) noexcept {
    const auto i = static_cast<std::size_t>(t);
    return i >= 1 && i <= kMessageTypeCount ? detail::kSchemaHashes[i] : 0u;
}

}  // namespace eyesim::protocol
