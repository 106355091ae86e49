#pragma once
// A next-step centroid estimator measured beside the pipeline in the benchmarks, computed offline from the
// field and a model blob (it is not part of the pipeline): luma weighted against a local background level.
// Background = mean luma of the band 2–3 columns and 2 lines out from the blob's box; weights = luma − background
// over the box grown by one column and one line (luma is not spread by the chroma filter, so one pixel of ring
// holds the anti-aliased edge). Signed, so it also works for markers darker than their surroundings.

#include "eyesim/fpga/blob.hpp"

#include <cmath>
#include <cstdint>

namespace eyesim::fpga::bench {

struct LumaEstimate {
    double x_px = 0, y_px = 0;  ///< centroid
    double sum_w = 0;           ///< Σ(luma − background), signed
};

/// UYVY field of 720 × height. False near the field border or when the weights cancel.
inline bool luma_centroid(const uint8_t* uyvy, int height, const Blob& b, LumaEstimate& out) {
    const int x0 = b.x_min, x1 = b.x_max, y0 = b.y_min, y1 = b.y_max;
    if (x0 < 4 || x1 > 715 || y0 < 3 || y1 > height - 4) return false;
    auto luma = [&](int x, int y) { return double(uyvy[static_cast<size_t>(y) * 1440 + 2 * static_cast<size_t>(x) + 1]); };
    double sb = 0;
    int nb = 0;
    for (int y = y0 - 2; y <= y1 + 2; ++y)
        for (int x = x0 - 3; x <= x1 + 3; ++x)
            if (!(x >= x0 - 1 && x <= x1 + 1 && y >= y0 - 1 && y <= y1 + 1)) sb += luma(x, y), ++nb;
    const double bg = sb / nb;
    double sw = 0, swx = 0, swy = 0;
    for (int y = y0 - 1; y <= y1 + 1; ++y)
        for (int x = x0 - 1; x <= x1 + 1; ++x) {
            const double w = luma(x, y) - bg;
            sw += w, swx += w * x, swy += w * y;
        }
    if (std::fabs(sw) < 1e-9) return false;
    out = {swx / sw, swy / sw, sw};
    return true;
}

/// Inverse-variance mix of the model's chroma centroid and the luma estimate: each one's noise scales as
/// 1 / (its weight sum); chroma counts twice (one sample per pixel pair, spread over three pixels).
inline void mix_centroids(const Blob& b, const LumaEstimate& l, double& x_px, double& y_px) {
    const double wl = l.sum_w * l.sum_w, wc = 2.0 * double(b.sum_w) * double(b.sum_w);
    x_px = (wl * l.x_px + wc * b.cx_px()) / (wl + wc);
    y_px = (wl * l.y_px + wc * b.cy_px()) / (wl + wc);
}

}  // namespace eyesim::fpga::bench
