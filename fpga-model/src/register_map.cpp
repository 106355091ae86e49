#include "eyesim/fpga/register_map.hpp"

namespace eyesim::fpga {
namespace {

constexpr uint32_t pack2(uint32_t lo, uint32_t hi, int shift) { return lo | (hi << shift); }

// Reset hue centres (1/256 turn) of the default colours in BT.601 Cb/Cr (studio or full swing alike):
// red 108.7° → 77, green 237.9° → 169, blue 337.8° → 240, yellow 164.9° → 117.
constexpr std::array<uint8_t, kNumClasses> kResetHue{77, 169, 240, 117};
constexpr uint8_t kResetHueHalfWidth = 16;  // ±22.5°: the closest pair (red, yellow) is 40 units apart
constexpr uint8_t kResetSatMin = 12, kResetSatMax = 255;  // neutral backgrounds + noise stay below 12
constexpr uint8_t kResetLumaMin = 24, kResetLumaMax = 255;

constexpr std::array<RegisterInfo, kNumRegisters> make_table() {
    std::array<RegisterInfo, kNumRegisters> t{};
    int i = 0;
    t[i++] = {reg::kId, 32, false, 0x45594650u, "ID"};
    t[i++] = {reg::kVersion, 16, false, 0x0104u, "VERSION"};
    t[i++] = {reg::kEnable, 1, true, 1u, "ENABLE"};
    t[i++] = {reg::kClassEnable, 4, true, 0xFu, "CLASS_ENABLE"};
    t[i++] = {reg::kWeightMode, 2, true, 1u, "WEIGHT_MODE"};
    // Per class, after BG_TRACK has removed the local background: a noise margin, one level higher for yellow
    // (class 4), whose markers sit on the eye's warm white (map 1.1, without tracking: 3 / 3 / 3 / 5).
    t[i++] = {reg::kWeightBg, 32, true, 0x03020202u, "WEIGHT_BG"};
    t[i++] = {reg::kWeightBits, 4, true, 8u, "WEIGHT_BITS"};
    t[i++] = {reg::kMinArea, 18, true, 2u, "MIN_AREA"};
    t[i++] = {reg::kMaxArea, 18, true, 4096u, "MAX_AREA"};
    t[i++] = {reg::kMinFillQ8, 8, true, 0u, "MIN_FILL_Q8"};
    t[i++] = {reg::kMaxAspectQ4, 8, true, 0u, "MAX_ASPECT_Q4"};
    t[i++] = {reg::kRoiEnable, 4, true, 0u, "ROI_ENABLE"};
    t[i++] = {reg::kFastPath, 1, true, 1u, "FAST_PATH"};
    t[i++] = {reg::kEdgeRing, 1, true, 1u, "EDGE_RING"};
    t[i++] = {reg::kBgTrack, 3, true, 4u, "BG_TRACK"};
    t[i++] = {reg::kPatchEnable, 4, true, 0u, "PATCH_ENABLE"};
    const char* roi_names[2 * kNumRoiWindows] = {"ROI0_X", "ROI0_Y", "ROI1_X", "ROI1_Y",
                                                 "ROI2_X", "ROI2_Y", "ROI3_X", "ROI3_Y"};
    for (int w = 0; w < kNumRoiWindows; ++w) {
        t[i++] = {reg::roi_x(w), 26, true, pack2(0, 719, 16), roi_names[2 * w]};
        t[i++] = {reg::roi_y(w), 25, true, pack2(0, 287, 16), roi_names[2 * w + 1]};
    }
    t[i++] = {reg::kBgOffset, 1, true, 0u, "BG_OFFSET"};
    const char* class_names[3 * kNumClasses] = {"CLASS1_HUE", "CLASS1_SAT", "CLASS1_LUMA", "CLASS2_HUE",
                                                "CLASS2_SAT", "CLASS2_LUMA", "CLASS3_HUE", "CLASS3_SAT",
                                                "CLASS3_LUMA", "CLASS4_HUE", "CLASS4_SAT", "CLASS4_LUMA"};
    for (int c = 1; c <= kNumClasses; ++c) {
        t[i++] = {reg::class_hue(c), 16, true, pack2(kResetHue[c - 1], kResetHueHalfWidth, 8),
                  class_names[3 * (c - 1)]};
        t[i++] = {reg::class_sat(c), 16, true, pack2(kResetSatMin, kResetSatMax, 8), class_names[3 * (c - 1) + 1]};
        t[i++] = {reg::class_luma(c), 16, true, pack2(kResetLumaMin, kResetLumaMax, 8),
                  class_names[3 * (c - 1) + 2]};
    }
    return t;
}

constexpr std::array<RegisterInfo, kNumRegisters> kTable = make_table();

int index_of(uint16_t address) {
    for (int i = 0; i < kNumRegisters; ++i)
        if (kTable[i].address == address) return i;
    return -1;
}

// Range rules beyond the width; called with a value that already fits the width.
bool in_range(uint16_t address, uint32_t v) {
    const uint32_t lo8 = v & 0xFFu, hi8 = (v >> 8) & 0xFFu;
    switch (address) {
        case reg::kWeightMode: return v <= 2;
        case reg::kWeightBits: return v >= 1 && v <= 8;
        case reg::kMinArea: return v >= 1 && v <= 720u * 288u;
        case reg::kMaxArea: return v >= 1 && v <= 720u * 288u;
        case reg::kMaxAspectQ4: return v == 0 || v >= 16;  // aspect below 1.0 would reject everything
        default: break;
    }
    for (int w = 0; w < kNumRoiWindows; ++w) {
        if (address == reg::roi_x(w)) {
            const uint32_t x0 = v & 0x3FFu, x1 = (v >> 16) & 0x3FFu;
            return (v & 0xFC00FC00u) == 0 && x0 <= x1 && x1 <= 719;
        }
        if (address == reg::roi_y(w)) {
            const uint32_t y0 = v & 0x1FFu, y1 = (v >> 16) & 0x1FFu;
            return (v & 0xFE00FE00u) == 0 && y0 <= y1;
        }
    }
    for (int c = 1; c <= kNumClasses; ++c) {
        if (address == reg::class_hue(c)) return hi8 >= 1 && hi8 <= 127;
        if (address == reg::class_sat(c) || address == reg::class_luma(c)) return lo8 <= hi8;
    }
    return true;
}

}  // namespace

const char* to_string(RegWriteResult r) {
    switch (r) {
        case RegWriteResult::kOk: return "ok";
        case RegWriteResult::kUnknownAddress: return "unknown_address";
        case RegWriteResult::kMisaligned: return "misaligned";
        case RegWriteResult::kBadWidth: return "bad_width";
        case RegWriteResult::kReadOnly: return "read_only";
        case RegWriteResult::kTooWide: return "too_wide";
        case RegWriteResult::kOutOfRange: return "out_of_range";
    }
    return "unknown";
}

const std::array<RegisterInfo, kNumRegisters>& register_table() { return kTable; }

const RegisterInfo* find_register(uint16_t address) {
    const int i = index_of(address);
    return i < 0 ? nullptr : &kTable[i];
}

RegisterMap::RegisterMap() { reset(); }

void RegisterMap::reset() {
    for (int i = 0; i < kNumRegisters; ++i) values_[i] = kTable[i].reset_value;
    ++generation_;
}

RegWriteResult RegisterMap::check_write(uint16_t address, uint32_t value, uint8_t access_bytes) const {
    if (address % 4 != 0) return RegWriteResult::kMisaligned;
    const int i = index_of(address);
    if (i < 0) return RegWriteResult::kUnknownAddress;
    if (access_bytes != 4) return RegWriteResult::kBadWidth;
    if (!kTable[i].writable) return RegWriteResult::kReadOnly;
    if (kTable[i].width_bits < 32 && (value >> kTable[i].width_bits) != 0) return RegWriteResult::kTooWide;
    if (!in_range(address, value)) return RegWriteResult::kOutOfRange;
    return RegWriteResult::kOk;
}

RegWriteResult RegisterMap::write(uint16_t address, uint32_t value, uint8_t access_bytes) {
    const RegWriteResult r = check_write(address, value, access_bytes);
    if (r == RegWriteResult::kOk) {
        values_[index_of(address)] = value;
        ++generation_;
    }
    return r;
}

bool RegisterMap::read(uint16_t address, uint32_t& value) const {
    if (address % 4 != 0) return false;
    const int i = index_of(address);
    if (i < 0) return false;
    value = values_[i];
    return true;
}

uint32_t RegisterMap::get(uint16_t address) const {
    uint32_t v = 0;
    return read(address, v) ? v : 0;
}

PipelineParams decode(const RegisterMap& m) {
    PipelineParams p;
    p.enable = m.get(reg::kEnable) != 0;
    p.class_enable = static_cast<uint8_t>(m.get(reg::kClassEnable));
    p.weight_mode = static_cast<uint8_t>(m.get(reg::kWeightMode));
    const uint32_t bg = m.get(reg::kWeightBg);
    for (int c = 1; c <= kNumClasses; ++c) p.weight_bg[c] = static_cast<uint8_t>(bg >> (8 * (c - 1)));
    p.weight_bits = static_cast<uint8_t>(m.get(reg::kWeightBits));
    p.min_area_px = m.get(reg::kMinArea);
    p.max_area_px = m.get(reg::kMaxArea);
    p.min_fill_q8 = static_cast<uint8_t>(m.get(reg::kMinFillQ8));
    p.max_aspect_q4 = static_cast<uint8_t>(m.get(reg::kMaxAspectQ4));
    p.roi_enable = static_cast<uint8_t>(m.get(reg::kRoiEnable));
    p.fast_path = m.get(reg::kFastPath) != 0;
    p.edge_ring = m.get(reg::kEdgeRing) != 0;
    p.bg_track_shift = static_cast<uint8_t>(m.get(reg::kBgTrack));
    p.patch_enable = static_cast<uint8_t>(m.get(reg::kPatchEnable));
    p.bg_offset = m.get(reg::kBgOffset) != 0;
    for (int w = 0; w < kNumRoiWindows; ++w) {
        const uint32_t x = m.get(reg::roi_x(w)), y = m.get(reg::roi_y(w));
        p.roi_x0[w] = static_cast<uint16_t>(x & 0x3FFu);
        p.roi_x1[w] = static_cast<uint16_t>((x >> 16) & 0x3FFu);
        p.roi_y0[w] = static_cast<uint16_t>(y & 0x1FFu);
        p.roi_y1[w] = static_cast<uint16_t>((y >> 16) & 0x1FFu);
    }
    for (int c = 1; c <= kNumClasses; ++c) {
        const uint32_t h = m.get(reg::class_hue(c)), s = m.get(reg::class_sat(c)), l = m.get(reg::class_luma(c));
        p.hue_centre[c - 1] = static_cast<uint8_t>(h & 0xFF);
        p.hue_half_width[c - 1] = static_cast<uint8_t>(h >> 8);
        p.sat_min[c - 1] = static_cast<uint8_t>(s & 0xFF);
        p.sat_max[c - 1] = static_cast<uint8_t>(s >> 8);
        p.luma_min[c - 1] = static_cast<uint8_t>(l & 0xFF);
        p.luma_max[c - 1] = static_cast<uint8_t>(l >> 8);
    }
    return p;
}

}  // namespace eyesim::fpga
