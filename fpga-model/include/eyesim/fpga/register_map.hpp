#pragma once
/// \file
/// The FPGA pipeline's register map: addresses, widths, reset values and validation of writes.
///
/// All registers are 32-bit words at 4-byte aligned byte addresses; each holds `width_bits` significant bits
/// (bits above must be zero). Writes are validated (address known, aligned, writable, value fits the width,
/// value in range) and return a `RegWriteResult`; a rejected write changes nothing. A running `Pipeline` samples
/// the map at `begin_field`, so a write takes effect at the next field boundary, never inside a field.
///
/// Colour classes 1..4 are defined by a hue wedge, a saturation (chroma radius) band and a luma band in the
/// Cb/Cr plane of BT.601 studio-swing YCbCr (as BT.656 carries it): hue = atan2(Cr-128, Cb-128) in 1/256 turns. The reset values classify exactly the
/// four default marker colours: 1 red (220,40,40), 2 green (40,200,60), 3 blue (40,80,220), 4 yellow (230,210,40).

#include <array>
#include <cstddef>
#include <cstdint>

namespace eyesim::fpga {

/// Number of marker colour classes (class ids 1..kNumClasses; 0 is background).
inline constexpr int kNumClasses = 4;
/// Number of region-of-interest windows.
inline constexpr int kNumRoiWindows = 4;

/// Register byte addresses.
namespace reg {
inline constexpr uint16_t kId = 0x000;            ///< RO 32: 0x45594650 ("EYFP")
inline constexpr uint16_t kVersion = 0x004;       ///< RO 16: register map version 0x0104
inline constexpr uint16_t kEnable = 0x008;        ///< RW 1: pipeline enable (0: fields produce no blobs)
inline constexpr uint16_t kClassEnable = 0x00C;   ///< RW 4: bit c-1 enables class c
inline constexpr uint16_t kWeightMode = 0x010;    ///< RW 2: 0 binary, 1 chroma projection − bg, 2 luma − bg
inline constexpr uint16_t kWeightBg = 0x014;      ///< RW 32: level subtracted from the projection
                                                  ///<       (or luma), per class: byte c−1 for class c
inline constexpr uint16_t kWeightBits = 0x018;    ///< RW 4: weight width 1..8 bits (LSBs dropped)
inline constexpr uint16_t kMinArea = 0x01C;       ///< RW 18: minimum blob area in field pixels
inline constexpr uint16_t kMaxArea = 0x020;       ///< RW 18: maximum blob area in field pixels (≤ 207360)
inline constexpr uint16_t kMinFillQ8 = 0x024;     ///< RW 8: min area/(bbox area), Q0.8; 0 disables
inline constexpr uint16_t kMaxAspectQ4 = 0x028;   ///< RW 8: max long/short bbox side, Q4.4; 0 disables
inline constexpr uint16_t kRoiEnable = 0x02C;     ///< RW 4: bit i enables ROI window i; 0 = whole field
inline constexpr uint16_t kFastPath = 0x030;      ///< RW 1: skip provably-background spans (bit-exact)
inline constexpr uint16_t kEdgeRing = 0x034;      ///< RW 1: add the weights of the 1-px ring of background
                                                  ///<      pixels around each blob to its moments
                                                  ///<      (weighted modes only)
inline constexpr uint16_t kBgTrack = 0x038;       ///< RW 3: 0 off; n = 1..7: the chroma weight subtracts a
                                                  ///<      background chroma tracked per 8-px cell over
                                                  ///<      lines with gain 2^-n (weight mode 1 only)
inline constexpr uint16_t kPatchEnable = 0x03C;   ///< RW 4: bit c-1: send class c blobs' pixel patches
                                                  ///<      (box + 2-px halo; precision mode); 0 off
inline constexpr uint16_t kBgOffset = 0x060;      ///< RW 1: chroma weight (mode 1): each blob's x centroid is
                                                  ///<      corrected for the mean background residual of the
                                                  ///<      chroma samples 3..7 columns beside its runs
/// ROI window i, X: bits [9:0] x0, [25:16] x1 (inclusive, x0 ≤ x1 ≤ 719).
constexpr uint16_t roi_x(int i) { return static_cast<uint16_t>(0x040 + 8 * i); }
/// ROI window i, Y: bits [8:0] y0, [24:16] y1 (inclusive active field lines, y0 ≤ y1 ≤ 511).
constexpr uint16_t roi_y(int i) { return static_cast<uint16_t>(0x044 + 8 * i); }
/// Class c (1..4) hue: bits [7:0] centre, [15:8] half-width, both in 1/256 turn.
constexpr uint16_t class_hue(int c) { return static_cast<uint16_t>(0x080 + 0x10 * (c - 1)); }
/// Class c saturation band: bits [7:0] min, [15:8] max chroma radius (min ≤ max).
constexpr uint16_t class_sat(int c) { return static_cast<uint16_t>(0x084 + 0x10 * (c - 1)); }
/// Class c luma band: bits [7:0] Y min, [15:8] Y max (min ≤ max).
constexpr uint16_t class_luma(int c) { return static_cast<uint16_t>(0x088 + 0x10 * (c - 1)); }
}  // namespace reg

/// Outcome of a register write.
enum class RegWriteResult : uint8_t {
    kOk = 0,          ///< written
    kUnknownAddress,  ///< no register at that address
    kMisaligned,      ///< address not a multiple of 4
    kBadWidth,        ///< access width other than 4 bytes
    kReadOnly,        ///< register is read-only
    kTooWide,         ///< value has bits set above the register width
    kOutOfRange,      ///< value fits the width but violates the register's range (e.g. min > max)
};

/// Short name of a write result ("ok", "unknown_address", ...), for logs and protocol replies.
const char* to_string(RegWriteResult r);

/// Static description of one register.
struct RegisterInfo {
    uint16_t address;      ///< byte address
    uint8_t width_bits;    ///< significant bits
    bool writable;         ///< false: read-only
    uint32_t reset_value;  ///< value after reset()
    const char* name;      ///< upper-case name as in docs/fpga-pipeline.md
};

/// Number of registers in the map.
inline constexpr int kNumRegisters = 17 + 2 * kNumRoiWindows + 3 * kNumClasses;

/// The register table (address order), for documentation, host tools and tests.
const std::array<RegisterInfo, kNumRegisters>& register_table();

/// Description of the register at `address`, or nullptr.
const RegisterInfo* find_register(uint16_t address);

/// The register file itself: a plain value type (no heap), copyable as a snapshot.
class RegisterMap {
public:
    /// Constructs with every register at its reset value.
    RegisterMap();

    /// Restores all reset values.
    void reset();

    /// Validates and applies a write of `access_bytes` (must be 4) at `address`.
    RegWriteResult write(uint16_t address, uint32_t value, uint8_t access_bytes = 4);

    /// Validates a write without applying it.
    RegWriteResult check_write(uint16_t address, uint32_t value, uint8_t access_bytes = 4) const;

    /// Reads a register; false when the address is unknown or misaligned.
    bool read(uint16_t address, uint32_t& value) const;

    /// Reads a register known to exist (0 for unknown addresses).
    uint32_t get(uint16_t address) const;

    /// Incremented on every accepted write (lets a pipeline skip recompiling an unchanged LUT).
    uint32_t generation() const { return generation_; }

private:
    std::array<uint32_t, kNumRegisters> values_{};
    uint32_t generation_ = 0;
};

/// Decoded view of the registers the datapath uses (computed at field start).
struct PipelineParams {
    bool enable = true;                                  ///< pipeline enable
    uint8_t class_enable = 0xF;                          ///< bit c-1 enables class c
    uint8_t weight_mode = 1;                             ///< 0 binary, 1 chroma projection, 2 luma
    std::array<uint8_t, kNumClasses + 1> weight_bg{};    ///< background level per class (index = class)
    uint8_t weight_bits = 8;                             ///< 1..8
    uint32_t min_area_px = 0;                            ///< area filter (inclusive)
    uint32_t max_area_px = 0;                            ///< area filter (inclusive)
    uint8_t min_fill_q8 = 0;                             ///< shape filter: fill ratio
    uint8_t max_aspect_q4 = 0;                           ///< shape filter: bbox aspect
    uint8_t roi_enable = 0;                              ///< enabled ROI windows
    bool fast_path = true;                               ///< background skipping
    bool edge_ring = true;                               ///< ring pixels add to the moments
    uint8_t bg_track_shift = 0;                          ///< background tracking gain 2^-n; 0 off
    uint8_t patch_enable = 0;                            ///< bit c-1: capture class c blobs' patches
    bool bg_offset = false;                              ///< BG_OFFSET: beside-band offset correction of x
    std::array<uint16_t, kNumRoiWindows> roi_x0{}, roi_x1{}, roi_y0{}, roi_y1{};  ///< inclusive bounds
    std::array<uint8_t, kNumClasses> hue_centre{}, hue_half_width{};               ///< 1/256 turn
    std::array<uint8_t, kNumClasses> sat_min{}, sat_max{};                         ///< chroma radius
    std::array<uint8_t, kNumClasses> luma_min{}, luma_max{};                       ///< Y band
};

/// Decodes a register map into datapath parameters.
PipelineParams decode(const RegisterMap& map);

}  // namespace eyesim::fpga
