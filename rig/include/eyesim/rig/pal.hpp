#pragma once
/// \file
/// PAL / BT.656 geometry and timing constants, and the field timing model of one camera.
///
/// Timing model (all times in µs on the recording clock, t = 0 at the recording start):
/// - field i of a camera starts (vertical sync, CCD charge transfer) at `field_time_offset_us + i * 20000`;
/// - its exposure is the interval [start - exposure_us, start] (electronic shutter; exposure ends at transfer);
/// - active line y (0..287) is delivered during [line_start_us(y), line_start_us(y) + 52]; line_start_us(y) =
///   start + (22 + y) * 64 + 10.5 (+ 32 for a bottom field: the half-line offset of interlace);
/// - the field is complete (its last active pixel left the decoder) at `end_us` = line_start_us(287) + 52.

#include <cstdint>

namespace eyesim::rig {

inline constexpr int kFrameWidth = 720;   ///< PAL active frame width, pixels
inline constexpr int kFrameHeight = 576;  ///< PAL active frame height, lines
inline constexpr int kFieldWidth = 720;   ///< one field: every other frame line
inline constexpr int kFieldHeight = 288;  ///< lines per field
inline constexpr int kFieldBytes = kFieldWidth * kFieldHeight * 2;  ///< one UYVY field: 414,720 bytes

inline constexpr double kFieldPeriodUs = 20000.0;    ///< 50 fields/s
inline constexpr double kFieldRateHz = 50.0;         ///< fields per second per camera
inline constexpr double kLinePeriodUs = 64.0;        ///< PAL line period
inline constexpr double kActiveLineUs = 52.0;        ///< active part of a line
inline constexpr double kActiveLineStartUs = 10.5;   ///< from line start (H sync) to the first active pixel
inline constexpr int kFirstActiveLine = 22;          ///< lines of vertical blanking before active line 0
inline constexpr double kBottomFieldDelayUs = 32.0;  ///< half-line offset of the bottom field
inline constexpr double kPixelPeriodUs = 1.0 / 13.5;  ///< BT.656 luma sample period (13.5 MHz)

/// Timing of one field of one camera (see the file comment for the model).
struct FieldTiming {
    int64_t index = 0;              ///< field index in the camera's stream (0 = first field of the recording)
    int parity = 0;                 ///< 0 = top field (frame rows 0,2,4,...), 1 = bottom (rows 1,3,5,...)
    double start_us = 0.0;          ///< vertical sync of this field = end of its exposure
    double exposure_start_us = 0.0; ///< shutter opens
    double exposure_end_us = 0.0;   ///< shutter closes (= start_us)
    double exposure_mid_us = 0.0;   ///< middle of the exposure: the truth time of this field
    double end_us = 0.0;            ///< last active pixel delivered

    /// Time the first active pixel of field line y (0..287) is delivered.
    double line_start_us(int y) const noexcept {
        return start_us + (kFirstActiveLine + y) * kLinePeriodUs + kActiveLineStartUs +
               (parity ? kBottomFieldDelayUs : 0.0);
    }
    /// Time the last active pixel of field line y is delivered.
    double line_end_us(int y) const noexcept { return line_start_us(y) + kActiveLineUs; }
};

/// Timing of field `index` for a camera with the given clock offset, exposure and first-field parity.
FieldTiming field_timing(int64_t index, double field_time_offset_us, double exposure_us, int first_field_parity);

}  // namespace eyesim::rig
