#pragma once
/// \file
/// PAL / BT.656 timing model of one camera's pixel stream, in 13.5 MHz pixel clocks.
///
/// A field starts (cycle 0) at the first line of its vertical blanking. Field line `L` (0..312) starts at cycle
/// `L * kClocksPerLine`. Active field line `y` (0..287) is field line `kFirstActiveLine + y`; inside a line the
/// 144 clocks of horizontal blanking (EAV, blanking, SAV) come first, then the 720 active pixels, so active pixel
/// (x, y) is on the wire at cycle `(kFirstActiveLine + y) * 864 + 144 + x`. Both fields use the same offsets (the
/// half-line offset of the second field is not modelled). A field lasts 270000 clocks = 20 ms (312.5 lines).

#include <cstdint>

namespace eyesim::fpga {

/// Pixel clock of BT.601/BT.656 4:2:2 video.
inline constexpr uint32_t kPixelClockHz = 13'500'000;
/// Clocks per PAL line including horizontal blanking (64 µs).
inline constexpr uint32_t kClocksPerLine = 864;
/// Active pixels per line.
inline constexpr uint32_t kActivePixelsPerLine = 720;
/// Horizontal blanking clocks before the first active pixel of a line.
inline constexpr uint32_t kHorizontalBlankingClocks = kClocksPerLine - kActivePixelsPerLine;
/// Field line index of active line 0 (22 lines of vertical blanking precede it).
inline constexpr uint32_t kFirstActiveLine = 22;
/// Active lines of a PAL field.
inline constexpr uint32_t kActiveLinesPerField = 288;
/// Clocks per PAL field (312.5 lines, 20 ms).
inline constexpr uint32_t kClocksPerField = 270'000;
/// Field period in microseconds (50 fields/s).
inline constexpr uint32_t kFieldPeriodUs = 20'000;

/// Cycle (from field start) at which active pixel (x, y) is on the wire.
constexpr uint32_t pixel_cycle(uint32_t x, uint32_t y) {
    return (kFirstActiveLine + y) * kClocksPerLine + kHorizontalBlankingClocks + x;
}

/// Cycle just after the last active pixel of active line y.
constexpr uint32_t active_line_end_cycle(uint32_t y) { return pixel_cycle(kActivePixelsPerLine, y); }

/// Pixel clocks → microseconds.
constexpr double cycles_to_us(uint32_t cycles) { return cycles * (1e6 / kPixelClockHz); }

/// Pixel clocks → nanoseconds, rounded down (integer device time).
constexpr uint64_t cycles_to_ns(uint64_t cycles) { return cycles * 1'000'000'000ull / kPixelClockHz; }

static_assert(pixel_cycle(719, 287) < kClocksPerField, "active video fits in a field");

}  // namespace eyesim::fpga
