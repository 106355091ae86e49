#pragma once
/// \file
/// JSON rendering of decoded frames and parser counters, one object per line, every key named as in
/// docs/protocol.md. Writes into a caller's buffer (no heap) so tools and tests share one rendering.

#include "eyesim/protocol/frame.hpp"
#include "eyesim/protocol/stream_parser.hpp"

#include <cstddef>
#include <cstdint>
#include <span>

namespace eyesim::protocol {

/// Buffer size that always holds format_json() of any frame.
inline constexpr std::size_t kMaxJsonBytes = 8192;

/// Renders `f` as one JSON object (no newline): "type", "version", "sequence", "payload_bytes", then
/// "host_rx_us" when `host_rx_us` is given, then the message's fields (FieldMarkers: "markers" array; each marker
/// also gets the derived "x_px"/"y_px" = q16 / 65536 rounded to 6 decimals). Returns the length, 0 if it does
/// not fit (output is NUL-terminated when it fits).
std::size_t format_json(const DecodedFrame& f, std::span<char> out, const std::uint64_t* host_rx_us = nullptr) noexcept;

/// Renders the parser counters as one JSON object with the ParserStats member names as keys.
std::size_t format_stats_json(const ParserStats& s, std::span<char> out) noexcept;

}  // namespace eyesim::protocol
