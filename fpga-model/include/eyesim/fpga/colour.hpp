#pragma once
/// \file
/// BT.601 colour conversion as the model and its test renderers use it (full-range 8-bit YCbCr, as the
/// register map's class definitions assume), and the hue/saturation measure of the class LUT.

#include <cstdint>

namespace eyesim::fpga {

/// Full-range BT.601 YCbCr of an sRGB-encoded colour (components 0..255, not rounded).
struct Ycc {
    double y, cb, cr;
};

/// Converts gamma-encoded R'G'B' (0..255) to full-range BT.601 Y'CbCr (0..255).
constexpr Ycc rgb_to_ycc(double r, double g, double b) {
    return {0.299 * r + 0.587 * g + 0.114 * b, 128.0 - 0.168736 * r - 0.331264 * g + 0.5 * b,
            128.0 + 0.5 * r - 0.418688 * g - 0.081312 * b};
}

/// Clamps and rounds to a byte.
constexpr uint8_t to_byte(double v) {
    return static_cast<uint8_t>(v <= 0.0 ? 0 : v >= 255.0 ? 255 : static_cast<int>(v + 0.5));
}

/// Hue of a Cb/Cr pair in 1/256 turns (0..255): atan2(Cr-128, Cb-128).
uint8_t chroma_hue(double cb, double cr);

/// Saturation (chroma radius) of a Cb/Cr pair: hypot(Cb-128, Cr-128).
double chroma_sat(double cb, double cr);

}  // namespace eyesim::fpga
