#pragma once
/// \file
/// BT.601 colour conversion as BT.656 video carries it (studio swing: Y 16..235, Cb/Cr 16..240, as the rig's
/// renderer writes it), and the hue/saturation measure of the class LUT.

#include <cstdint>

namespace eyesim::fpga {

/// Studio-swing BT.601 Y'CbCr (not rounded).
struct Ycc {
    double y, cb, cr;
};

/// Converts gamma-encoded R'G'B' (0..255) to studio-swing BT.601 Y'CbCr.
constexpr Ycc rgb_to_ycc(double r, double g, double b) {
    const double y = 0.299 * r + 0.587 * g + 0.114 * b;
    return {16.0 + 219.0 / 255.0 * y, 128.0 + 224.0 / 255.0 * (b - y) / 1.772,
            128.0 + 224.0 / 255.0 * (r - y) / 1.402};
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
