#pragma once
// Test fields: grey background with anti-aliased discs in the four default marker colours, as BT.601
// studio-swing UYVY (what the rig's recordings hold). Positions move from field to field and differ per camera.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

namespace eyesim::test {

inline constexpr int kW = 720;
inline constexpr int kH = 288;
inline constexpr std::size_t kFieldBytes = std::size_t{kW} * kH * 2;

struct Disc {
    double x, y, r;  // field pixels
    int colour;      // 0 red, 1 green, 2 blue, 3 yellow
};

inline void rgb_to_studio(double r, double g, double b, double& y, double& cb, double& cr) {
    const double yf = 0.299 * r + 0.587 * g + 0.114 * b;
    y = 16.0 + 219.0 * yf / 255.0;
    cb = 128.0 + 224.0 * (b - yf) / (1.772 * 255.0);
    cr = 128.0 + 224.0 * (r - yf) / (1.402 * 255.0);
}

/// Renders discs over a grey background into one UYVY field (4×4 supersampled coverage).
inline void render_field(const std::vector<Disc>& discs, std::uint8_t* uyvy) {
    static constexpr std::array<std::array<double, 3>, 4> kColours{
        {{220, 40, 40}, {40, 200, 60}, {40, 80, 220}, {230, 210, 40}}};
    std::vector<std::array<double, 3>> rgb(std::size_t{kW} * kH, {90.0, 90.0, 90.0});
    for (const Disc& d : discs) {
        const int x0 = std::max(0, static_cast<int>(d.x - d.r - 1)), x1 = std::min(kW - 1, static_cast<int>(d.x + d.r + 1));
        const int y0 = std::max(0, static_cast<int>(d.y - d.r - 1)), y1 = std::min(kH - 1, static_cast<int>(d.y + d.r + 1));
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                int inside = 0;
                for (int sy = 0; sy < 4; ++sy)
                    for (int sx = 0; sx < 4; ++sx) {
                        const double px = x - 0.375 + 0.25 * sx - d.x, py = y - 0.375 + 0.25 * sy - d.y;
                        inside += px * px + py * py <= d.r * d.r;
                    }
                const double a = inside / 16.0;
                auto& p = rgb[static_cast<std::size_t>(y) * kW + x];
                for (int k = 0; k < 3; ++k) p[k] = (1 - a) * p[k] + a * kColours[d.colour][k];
            }
    }
    auto byte = [](double v) { return static_cast<std::uint8_t>(std::clamp(std::lround(v), 0L, 255L)); };
    for (int y = 0; y < kH; ++y)
        for (int x = 0; x < kW; x += 2) {
            double ya, cba, cra, yb, cbb, crb;
            const auto& p = rgb[static_cast<std::size_t>(y) * kW + x];
            const auto& q = rgb[static_cast<std::size_t>(y) * kW + x + 1];
            rgb_to_studio(p[0], p[1], p[2], ya, cba, cra);
            rgb_to_studio(q[0], q[1], q[2], yb, cbb, crb);
            std::uint8_t* o = uyvy + (static_cast<std::size_t>(y) * kW + x) * 2;
            o[0] = byte(0.5 * (cba + cbb));
            o[1] = byte(ya);
            o[2] = byte(0.5 * (cra + crb));
            o[3] = byte(yb);
        }
}

/// The discs of field `k` of camera `cam`: `n` ≤ 32 markers on slowly moving paths.
inline std::vector<Disc> scene(int cam, int k, int n = 8) {
    std::vector<Disc> d;
    for (int i = 0; i < n; ++i) {
        const double phase = 0.37 * i + 0.9 * cam + 0.05 * k;
        const int col = i % 8, row = i / 8;  // a grid keeps discs apart; rows at y = 30, 90, 150, 210 (+ motion)
        d.push_back({50.0 + 85.0 * col + 6.0 * std::sin(phase), 30.0 + 60.0 * row + 5.0 * std::cos(1.3 * phase),
                     2.5 + 0.4 * (i % 4), (i + cam) % 4});
    }
    return d;
}

/// `fields` fields of camera `cam`, concatenated.
inline std::vector<std::uint8_t> make_stream(int cam, int fields, int markers = 8) {
    std::vector<std::uint8_t> out(kFieldBytes * static_cast<std::size_t>(fields));
    for (int k = 0; k < fields; ++k) render_field(scene(cam, k, markers), out.data() + kFieldBytes * k);
    return out;
}

}  // namespace eyesim::test
