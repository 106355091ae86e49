// Cramér–Rao bound on the centre of a rig eye marker (yellow shaded sphere on the eye white) from one field's
// 4:2:2 samples, beside the noise of a linear chroma centroid over the same samples: how far any estimator from
// chroma alone, and one from luma and chroma, can go at the rig's noise (σ on Y, Cb, Cr; luma shot noise
// 0.02 DN²/DN; rounding). The background is known exactly here, so these are lower bounds.
//
// Usage: crb_sphere [sigma_dn]
#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <vector>

namespace {

constexpr int kW = 40, kLines = 20, kSs = 12;
constexpr double kMarker[3] = {230, 210, 40}, kEye[3] = {236, 234, 226};
constexpr double kAmbient = 0.35, kDiffuse = 0.65;

struct Params {
    double x0, v0, r, a;  // centre (frame px), radius (frame px), amplitude
};

// Y per pixel, then Cb and Cr per pair ([1 2 1] co-sited), offset-free.
std::vector<double> render(const Params& p, int parity, bool with_luma) {
    std::vector<double> y(kW * kLines), cb(kW * kLines), cr(kW * kLines), out;
    for (int j = 0; j < kLines; ++j)
        for (int x = 0; x < kW; ++x) {
            const double v = 2.0 * j + parity;
            double in = 0, c = 0;
            for (int sy = 0; sy < kSs; ++sy)
                for (int sx = 0; sx < kSs; ++sx) {
                    const double xx = x - 0.5 + (sx + 0.5) / kSs - p.x0, vv = v - 0.5 + (sy + 0.5) / kSs - p.v0;
                    const double q = 1.0 - (xx * xx + vv * vv) / (p.r * p.r);
                    if (q > 0) {
                        c += 1;
                        in += kAmbient + kDiffuse * std::sqrt(q);
                    }
                }
            c /= kSs * kSs;
            in /= kSs * kSs;
            double rgb[3];
            for (int k = 0; k < 3; ++k) rgb[k] = p.a * in * kMarker[k] + (1 - c) * kEye[k];
            const double l = 0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2];
            y[j * kW + x] = 16 + 219.0 / 255 * l;
            cb[j * kW + x] = 224.0 / 255 * (rgb[2] - l) / 1.772;
            cr[j * kW + x] = 224.0 / 255 * (rgb[0] - l) / 1.402;
        }
    if (with_luma) out = y;
    for (const std::vector<double>* ch : {&cb, &cr})
        for (int j = 0; j < kLines; ++j)
            for (int x = 0; x < kW; x += 2) {
                auto at = [&](int xx) { return (*ch)[j * kW + std::clamp(xx, 0, kW - 1)]; };
                out.push_back(0.25 * (at(x - 1) + 2 * at(x) + at(x + 1)));
            }
    return out;
}

// Variance of the centre x (frame px) and v (field lines) from the Fisher information of (x0, v0, r, a).
void crb(const Params& p, int parity, bool with_luma, double sigma, double& var_x, double& var_y) {
    const std::vector<double> base = render(p, parity, with_luma);
    std::vector<std::vector<double>> d(4);
    for (int q = 0; q < 4; ++q) {
        Params a = p, b = p;
        double* pa = q == 0 ? &a.x0 : q == 1 ? &a.v0 : q == 2 ? &a.r : &a.a;
        double* pb = q == 0 ? &b.x0 : q == 1 ? &b.v0 : q == 2 ? &b.r : &b.a;
        *pa += 1e-3;
        *pb -= 1e-3;
        const std::vector<double> fa = render(a, parity, with_luma), fb = render(b, parity, with_luma);
        d[static_cast<size_t>(q)].resize(fa.size());
        for (size_t i = 0; i < fa.size(); ++i) d[static_cast<size_t>(q)][i] = (fa[i] - fb[i]) / 2e-3;
    }
    const size_t n_luma = with_luma ? static_cast<size_t>(kW * kLines) : 0;
    Eigen::Matrix4d f = Eigen::Matrix4d::Zero();
    for (size_t i = 0; i < base.size(); ++i) {
        const double var = sigma * sigma + 1.0 / 12 + (i < n_luma ? 0.02 * std::max(0.0, base[i] - 16) : 0.0);
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c) f(r, c) += d[static_cast<size_t>(r)][i] * d[static_cast<size_t>(c)][i] / var;
    }
    const Eigen::Matrix4d cov = f.inverse();
    var_x = cov(0, 0);
    var_y = cov(1, 1) / 4;  // field line = 2 frame px
}

// Noise of a linear centroid of the chroma projection on the marker's hue (exact background, no clamp) over the
// marker and a ring of `ring` px beside it and one line above and below.
void linear_chroma(const Params& p, int parity, double sigma, double ring, double& var_x) {
    double ux = 0, uy = 0;
    {
        const double lm = 0.299 * kMarker[0] + 0.587 * kMarker[1] + 0.114 * kMarker[2];
        const double le = 0.299 * kEye[0] + 0.587 * kEye[1] + 0.114 * kEye[2];
        ux = ((kMarker[2] - lm) - (kEye[2] - le)) / 1.772;
        uy = ((kMarker[0] - lm) - (kEye[0] - le)) / 1.402;
        const double n = std::hypot(ux, uy);
        ux /= n;
        uy /= n;
    }
    const std::vector<double> s = render(p, parity, false), bg = render({p.x0, p.v0, 1e-9, 0}, parity, false);
    const int pairs = kW / 2, chroma = pairs * kLines;
    auto proj = [&](int j, int k) {
        const size_t i = static_cast<size_t>(j * pairs + k);
        return (s[i] - bg[i]) * ux + (s[i + chroma] - bg[i + chroma]) * uy;
    };
    std::vector<double> w(kW * kLines);
    std::vector<bool> in(kW * kLines);
    double sw = 0, sx = 0;
    for (int j = 0; j < kLines; ++j)
        for (int x = 0; x < kW; ++x) {
            const int k = x / 2;
            const double wx = (x & 1) && k + 1 < pairs ? 0.5 * (proj(j, k) + proj(j, k + 1)) : proj(j, k);
            const bool inside = std::fabs(x - p.x0) <= p.r + ring && std::fabs(2.0 * j + parity - p.v0) <= p.r + 1.0;
            in[static_cast<size_t>(j * kW + x)] = inside;
            if (inside) {
                sw += wx;
                sx += wx * x;
            }
        }
    const double cx = sx / sw, var_sample = sigma * sigma + 1.0 / 12;
    var_x = 0;
    for (int j = 0; j < kLines; ++j)
        for (int k = 0; k < pairs; ++k) {
            double g = 0;  // d(centroid)/d(sample) through the pixels that use this sample
            for (int x = 2 * k - 1; x <= 2 * k + 1; ++x) {
                if (x < 0 || x >= kW || !in[static_cast<size_t>(j * kW + x)]) continue;
                g += (x == 2 * k ? 1.0 : 0.5) * (x - cx) / sw;
            }
            var_x += g * g * var_sample;  // the projection of Cb, Cr noise on a unit hue vector has variance σ²
        }
}

}  // namespace

int main(int argc, char** argv) {
    const double sigma = argc > 1 ? std::atof(argv[1]) : 1.0;
    std::mt19937 rng(1);
    std::uniform_real_distribution<double> u(0, 1);
    std::printf("sigma %.2f DN; RMS over 20 sub-pixel phases and both parities; px (x) and field lines (y)\n\n", sigma);
    std::printf("| diameter px | bound Y+Cb+Cr x / y | bound Cb+Cr only x / y | linear chroma centroid x |\n");
    std::printf("|---:|---:|---:|---:|\n");
    for (double r : {3.0, 4.0, 4.5, 5.0}) {
        double fx = 0, fy = 0, cx = 0, cy = 0, lx = 0;
        const int trials = 20;
        for (int t = 0; t < trials; ++t) {
            const Params p{20 + u(rng), 20 + 2 * u(rng), r, 1.0};
            double vx, vy;
            crb(p, t & 1, true, sigma, vx, vy);
            fx += vx;
            fy += vy;
            crb(p, t & 1, false, sigma, vx, vy);
            cx += vx;
            cy += vy;
            linear_chroma(p, t & 1, sigma, 2.5, vx);
            lx += vx;
        }
        std::printf("| %.0f | %.4f / %.4f | %.4f / %.4f | %.4f |\n", 2 * r, std::sqrt(fx / trials), std::sqrt(fy / trials),
                    std::sqrt(cx / trials), std::sqrt(cy / trials), std::sqrt(lx / trials));
    }
    return 0;
}
