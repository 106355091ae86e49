#include "eyesim/fpga/colour.hpp"

#include <cmath>

namespace eyesim::fpga {

uint8_t chroma_hue(double cb, double cr) {
    double h = std::atan2(cr - 128.0, cb - 128.0) / 6.283185307179586 * 256.0;
    if (h < 0) h += 256.0;
    return static_cast<uint8_t>(static_cast<int>(std::lround(h)) & 0xFF);
}

double chroma_sat(double cb, double cr) { return std::hypot(cb - 128.0, cr - 128.0); }

}  // namespace eyesim::fpga
