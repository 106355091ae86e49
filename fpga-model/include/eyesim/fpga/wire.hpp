#pragma once
/// \file
/// Conversion of pipeline blobs into wire-protocol markers and FieldMarkers messages, shared by the firmware and
/// `eyesim fpga` so both produce identical packets. No heap, no exceptions.
///
/// Device time: the caller gives the device time of cycle 0 of the field (start of its vertical blanking, see
/// timing.hpp); a cycle c of that field is at field_start_us + floor(c / 13.5) µs.
/// - Marker::complete_us = time of the blob's last pixel (Blob::last_pixel_cycle).
/// - FieldMarkers::field_end_us = time just after the last active pixel of line 287.
/// Flags: any border bit → kMarkerFlagTouchesBorder; kBlobMerged → kMarkerFlagMerged; kBlobClippedByRoi →
/// kMarkerFlagClippedByRoi; kBlobIncomplete (part of the blob was dropped for lack of a table slot, so its
/// moments are partial) → kMarkerFlagSaturated, the protocol's "centroid unreliable" bit.

#include "eyesim/fpga/blob.hpp"
#include "eyesim/fpga/field_stats.hpp"
#include "eyesim/protocol/messages.hpp"

#include <cstddef>
#include <cstdint>

namespace eyesim::fpga {

/// Device time in µs of pixel-clock cycle `cycle` of a field that started at `field_start_us`.
uint64_t device_time_us(uint64_t field_start_us, uint32_t cycle);

/// Device time in µs of the end of a field that started at `field_start_us`, as FieldMarkers::field_end_us carries
/// it: the end of its last active line.
uint64_t field_end_us(uint64_t field_start_us);

/// The wire marker of one blob.
protocol::Marker to_marker(const Blob& blob, uint64_t field_start_us);

/// What a field's messages carry besides the markers.
struct FieldInfo {
    uint8_t camera = 0;            ///< camera id 0..2
    uint8_t parity = 0;            ///< 0 top, 1 bottom
    uint32_t field_counter = 0;    ///< per-camera field number
    uint64_t field_start_us = 0;   ///< device time of cycle 0 of the field
    bool blobs_dropped = false;    ///< set kFieldFlagBlobsDropped (table overflow or full output ring)
};

/// FieldInfo from a finished field's stats (blobs_dropped from table overflows and dropped blobs).
FieldInfo field_info(const FieldStats& stats, uint8_t camera, uint8_t parity, uint64_t field_start_us);

/// Upper bound on the messages `to_field_markers` writes for `n` blobs (at least 1: an empty field is announced).
constexpr size_t field_markers_messages(size_t n) {
    return n == 0 ? 1 : (n + protocol::kMaxMarkersPerMessage - 1) / protocol::kMaxMarkersPerMessage;
}

/// Writes the FieldMarkers messages of one complete field: parts of up to 14 markers in blob order, part_index
/// 0, 1, ..., kFieldFlagMoreFollows on all but the last, field_end_us on every part. Returns the number of
/// messages written, or 0 when `max_out` < field_markers_messages(n).
size_t to_field_markers(const Blob* blobs, size_t n, const FieldInfo& info, protocol::FieldMarkers* out,
                        size_t max_out);

}  // namespace eyesim::fpga
