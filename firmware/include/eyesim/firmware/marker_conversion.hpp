#pragma once
/// \file
/// Blob (FPGA pipeline output) → protocol Marker, as the firmware puts it on the wire.

#include "eyesim/fpga/blob.hpp"
#include "eyesim/protocol/messages.hpp"

#include <cstdint>

namespace eyesim::firmware {

/// Converts a completed blob of the field that started at device time `field_start_us`.
protocol::Marker to_marker(const fpga::Blob& blob, std::uint64_t field_start_us) noexcept;

}  // namespace eyesim::firmware
