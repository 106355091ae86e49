#pragma once
/// \file
/// One completed marker blob as the pipeline emits it.
///
/// Coordinates are field pixels: x right (0..719), y down in active field lines (0..287); pixel centres are at
/// integer coordinates. Moments are exact integer sums over the blob's pixels of weight w (see RegisterMap,
/// WEIGHT_MODE / WEIGHT_BITS; w ≤ 255) with the widths the hardware accumulators have (documented in
/// docs/fpga-pipeline.md; enough for one blob covering a whole 720×512 field): Σw 27 bits, Σwx 37, Σwy 36,
/// Σwx² 46, Σwy² 45, Σwxy 45. The centroid is the divider's
/// output: round(Σwx · 2^16 / Σw), i.e. fixed point with scale 1/65536 px (kCentroidFracBits), the scale of the
/// wire protocol's marker coordinates. With BG_OFFSET and band samples, x is corrected for the band's mean
/// residual r̄ = band_sum_r / band_count: cx = (Σwx − r̄·pos_sum_x) / (Σw − r̄·pos_count).

#include <cstdint>

namespace eyesim::fpga {

/// Fractional bits of Blob::cx_q16 / cy_q16 (scale 1/65536 px).
inline constexpr int kCentroidFracBits = 16;
/// Accumulator widths in bits (hardware; the model checks them in tests).
inline constexpr int kSumWBits = 27, kSumWxBits = 37, kSumWyBits = 36, kSumWxxBits = 46, kSumWyyBits = 45,
                     kSumWxyBits = 45;

/// Bits of Blob::flags.
enum BlobFlag : uint8_t {
    kBlobTouchesLeft = 1u << 0,    ///< has a pixel in column 0
    kBlobTouchesRight = 1u << 1,   ///< has a pixel in column 719
    kBlobTouchesTop = 1u << 2,     ///< has a pixel in line 0
    kBlobTouchesBottom = 1u << 3,  ///< has a pixel in line 287 or in the last line of a field ended early
    kBlobIncomplete = 1u << 4,     ///< touched a run dropped for lack of a blob-table slot: moments are partial
    kBlobZeroWeight = 1u << 5,     ///< Σw = 0: the centroid is the bounding-box centre
    kBlobMerged = 1u << 6,         ///< formed by merging two or more provisional labels (U/W shapes)
    kBlobClippedByRoi = 1u << 7,   ///< touches an inner edge of an enabled ROI window (may be cut)
};

/// A completed blob. Trivially copyable, fixed size.
struct Blob {
    uint32_t field_counter = 0;     ///< field the blob belongs to (from begin_field)
    uint16_t index = 0;             ///< emission order within the field, from 0
    uint8_t camera = 0;             ///< camera id from PipelineConfig
    uint8_t class_id = 0;           ///< colour class 1..4
    uint8_t flags = 0;              ///< BlobFlag bits
    uint8_t parity = 0;             ///< field parity from begin_field (0 top, 1 bottom)
    uint32_t area_px = 0;           ///< pixel count (binary)
    uint16_t x_min = 0, x_max = 0;  ///< bounding box, inclusive columns
    uint16_t y_min = 0, y_max = 0;  ///< bounding box, inclusive active field lines
    uint64_t sum_w = 0;             ///< Σw
    uint64_t sum_wx = 0;            ///< Σw·x
    uint64_t sum_wy = 0;            ///< Σw·y
    uint64_t sum_wxx = 0;           ///< Σw·x²
    uint64_t sum_wyy = 0;           ///< Σw·y²
    uint64_t sum_wxy = 0;           ///< Σw·x·y
    uint32_t pos_count = 0;         ///< pixels (blob and ring) with w > 0
    uint64_t pos_sum_x = 0;         ///< Σx over those pixels
    int32_t band_sum_r = 0;         ///< BG_OFFSET: Σ background residual (projection) of the beside-band samples
    uint32_t band_count = 0;        ///< BG_OFFSET: number of beside-band samples (0: no correction)
    uint32_t cx_q16 = 0;            ///< centroid x · 65536 (round half up)
    uint32_t cy_q16 = 0;            ///< centroid y · 65536 (round half up)
    uint32_t last_pixel_cycle = 0;  ///< cycle of the blob's last pixel on the wire (see timing.hpp)
    uint32_t emit_cycle = 0;        ///< cycle at which the blob leaves the pipeline
    uint32_t latency_cycles = 0;    ///< emit_cycle - last_pixel_cycle
    double ref_sum_w = 0;           ///< floating reference Σw (0 unless PipelineConfig::float_reference)
    double ref_cx_px = 0;           ///< floating reference centroid x (unquantised weights, exact division)
    double ref_cy_px = 0;           ///< floating reference centroid y

    /// Centroid x in pixels from the fixed-point value.
    double cx_px() const { return cx_q16 / 65536.0; }
    /// Centroid y in (field) pixels from the fixed-point value.
    double cy_px() const { return cy_q16 / 65536.0; }
    /// Central second moment μ20/μ00 in px² (from the exact sums).
    double mu20_px2() const;
    /// Central second moment μ02/μ00 in px².
    double mu02_px2() const;
    /// Central second moment μ11/μ00 in px².
    double mu11_px2() const;
    /// Latency from last pixel to emission in microseconds.
    double latency_us() const;
};

}  // namespace eyesim::fpga
