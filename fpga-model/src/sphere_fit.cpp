#include "eyesim/fpga/sphere_fit.hpp"

#include <algorithm>
#include <cmath>

namespace eyesim::fpga {

MarkerColour MarkerColour::from_rgb(double r, double g, double b) {
    const double l = 0.299 * r + 0.587 * g + 0.114 * b;
    return {219.0 / 255.0 * l, 224.0 / 255.0 * (b - l) / 1.772, 224.0 / 255.0 * (r - l) / 1.402};
}

namespace {

constexpr int kMaxPar = 18;
// Parameters: centre (frame x, frame v), radius (frame px), amplitude; background per channel Y, Cb, Cr as
// level + x slope + v slope about the patch reference; outline: normal angle, offset, and the level beyond it.
enum : int { kX0, kV0, kR, kA, kB0, kPhi = 13, kD, kB2 };
constexpr double kOffset[3] = {16.0, 128.0, 128.0};

using Vec = std::array<double, kMaxPar>;
using Mat = std::array<double, kMaxPar * kMaxPar>;

// Solves (A + λ·diag A)·x = g for the first n unknowns by Cholesky; false when not positive definite.
bool solve_damped(const Mat& a, const Vec& g, int n, double lambda, Vec& x) {
    Mat l{};
    for (int i = 0; i < n; ++i)
        for (int j = 0; j <= i; ++j) {
            double s = a[i * kMaxPar + j] + (i == j ? lambda * a[i * kMaxPar + i] + 1e-9 : 0.0);
            for (int k = 0; k < j; ++k) s -= l[i * kMaxPar + k] * l[j * kMaxPar + k];
            if (i == j) {
                if (!(s > 0)) return false;
                l[i * kMaxPar + i] = std::sqrt(s);
            } else {
                l[i * kMaxPar + j] = s / l[j * kMaxPar + j];
            }
        }
    Vec y{};
    for (int i = 0; i < n; ++i) {
        double s = g[i];
        for (int k = 0; k < i; ++k) s -= l[i * kMaxPar + k] * y[k];
        y[i] = s / l[i * kMaxPar + i];
    }
    x.fill(0.0);
    for (int i = n - 1; i >= 0; --i) {
        double s = y[i];
        for (int k = i + 1; k < n; ++k) s -= l[k * kMaxPar + i] * x[k];
        x[i] = s / l[i * kMaxPar + i];
    }
    return true;
}

struct Patch {
    int x0 = 0, x1 = 0, j0 = 0, j1 = 0, parity = 0;
    int cols = 0, lines = 0;  // model columns (x0 - 1 .. x1 + 1) and lines
    double xc = 0, vc = 0;    // reference point of the background slopes (frame px)
    bool outline = false;
    MarkerColour colour;
};

class Fitter {
public:
    Fitter(const SphereFitConfig& cfg, const Patch& p, SphereFitWorkspace& w) : cfg_(cfg), p_(p), w_(w) {}

    // Coverage and coverage × shading of the sphere per model pixel.
    void render(double x0, double v0, double r, double* cov, double* shade) const {
        const int ss = cfg_.supersample;
        const double h = 1.0 / ss, rr = std::max(r, 0.25), inv_r2 = 1.0 / (rr * rr);
        for (int j = 0; j < p_.lines; ++j) {
            const double v = 2.0 * (p_.j0 + j) + p_.parity;
            for (int i = 0; i < p_.cols; ++i) {
                const int k = j * p_.cols + i;
                const double dx = (p_.x0 - 1 + i) - x0, dv = v - v0;
                double c = 0, s = 0;
                if (dx * dx + dv * dv < (rr + 0.75) * (rr + 0.75)) {
                    for (int sy = 0; sy < ss; ++sy) {
                        const double yy = dv - 0.5 + (sy + 0.5) * h;
                        for (int sx = 0; sx < ss; ++sx) {
                            const double xx = dx - 0.5 + (sx + 0.5) * h;
                            const double d2 = xx * xx + yy * yy;
                            // Straight-edge coverage of the sub-cell: a ramp one sub-cell wide keeps the model smooth.
                            const double rad = std::sqrt(d2);
                            const double cs = std::clamp((rr - rad) / h + 0.5, 0.0, 1.0);
                            if (cs <= 0) continue;
                            c += cs;
                            s += cs * (cfg_.shade_ambient + cfg_.shade_diffuse * std::sqrt(std::max(0.0, 1.0 - d2 * inv_r2)));
                        }
                    }
                    c *= h * h;
                    s *= h * h;
                }
                cov[k] = c;
                shade[k] = s;
            }
        }
    }

    // Background of channel ch at model pixel (i, j), its level inside the outline and the outline weight.
    void background(const Vec& t, int ch, int i, int j, double& bg, double& inside, double& we, double& dwe_dphi,
                    bool& ramp) const {
        const double x = (p_.x0 - 1 + i) - p_.xc, v = 2.0 * (p_.j0 + j) + p_.parity - p_.vc;
        inside = t[kB0 + 3 * ch] + t[kB0 + 3 * ch + 1] * x + t[kB0 + 3 * ch + 2] * v;
        we = 1.0;
        dwe_dphi = 0.0;
        ramp = false;
        bg = inside;
        if (!p_.outline) return;
        const double cp = std::cos(t[kPhi]), sp = std::sin(t[kPhi]);
        const double dist = cp * x + sp * v - t[kD];
        we = std::clamp(0.5 - dist, 0.0, 1.0);
        ramp = we > 0.0 && we < 1.0;
        dwe_dphi = ramp ? -(-sp * x + cp * v) : 0.0;
        bg = we * inside + (1.0 - we) * t[kB2 + ch];
    }

    double pixel_value(const Vec& t, const double* cov, const double* shade, int ch, int i, int j) const {
        const int k = j * p_.cols + i;
        double bg, inside, we, dphi;
        bool ramp;
        background(t, ch, i, j, bg, inside, we, dphi, ramp);
        const double m = ch == 0 ? p_.colour.y_dn : ch == 1 ? p_.colour.cb_dn : p_.colour.cr_dn;
        return kOffset[ch] + t[kA] * shade[k] * m + (1.0 - cov[k]) * (bg - kOffset[ch]);
    }

    // Adds the derivative row of the model pixel (ch, i, j) times `scale` to `row`.
    void pixel_row(const Vec& t, int ch, int i, int j, double scale, Vec& row) const {
        const int k = j * p_.cols + i, n = p_.lines * p_.cols;
        double bg, inside, we, dphi;
        bool ramp;
        background(t, ch, i, j, bg, inside, we, dphi, ramp);
        const double m = ch == 0 ? p_.colour.y_dn : ch == 1 ? p_.colour.cb_dn : p_.colour.cr_dn;
        const double cov = w_.cov[k], open = 1.0 - cov, under = bg - kOffset[ch];
        for (int q = 0; q < 3; ++q) row[q] += scale * (t[kA] * m * w_.dshade[q * n + k] - w_.dcov[q * n + k] * under);
        row[kA] += scale * w_.shade[k] * m;
        const double x = (p_.x0 - 1 + i) - p_.xc, v = 2.0 * (p_.j0 + j) + p_.parity - p_.vc;
        row[kB0 + 3 * ch] += scale * open * we;
        row[kB0 + 3 * ch + 1] += scale * open * we * x;
        row[kB0 + 3 * ch + 2] += scale * open * we * v;
        if (p_.outline) {
            const double step = open * (inside - t[kB2 + ch]);
            row[kPhi] += scale * step * dphi;
            row[kD] += scale * (ramp ? step : 0.0);
            row[kB2 + ch] += scale * open * (1.0 - we);
        }
    }

    // Σ (r/σ)² at t (renders into the workspace's trial arrays).
    double cost(const Vec& t) {
        double* cov = w_.trial.data();
        double* shade = cov + SphereFitWorkspace::kPx;
        render(t[kX0], t[kV0], t[kR], cov, shade);
        return residuals(t, cov, shade, nullptr, nullptr);
    }

    // Σ (r/σ)²; with a and g, also accumulates JᵀWJ and JᵀWr (derivatives from the workspace's base render).
    double residuals(const Vec& t, const double* cov, const double* shade, Mat* a, Vec* g) const {
        double chi2 = 0;
        const int nx = p_.x1 - p_.x0 + 1;
        Vec row;
        auto add = [&](double r, double wgt) {
            chi2 += r * r * wgt;
            if (!a) return;
            for (int q = 0; q < np(); ++q) {
                if (row[q] == 0.0) continue;
                (*g)[q] += wgt * row[q] * r;
                for (int s = 0; s <= q; ++s) (*a)[q * kMaxPar + s] += wgt * row[q] * row[s];
            }
        };
        for (int j = 0; j < p_.lines; ++j) {
            for (int x = 0; x < nx; ++x) {
                const int i = x + 1, o = j * nx + x;
                const double r = w_.obs_y[o] - pixel_value(t, cov, shade, 0, i, j);
                if (a) {
                    row.fill(0.0);
                    pixel_row(t, 0, i, j, 1.0, row);
                }
                add(r, 1.0 / w_.var_y[o]);
            }
            const double wc = 1.0 / var_c();
            int s = 0;
            for (int x = p_.x0 + (p_.x0 & 1); x <= p_.x1; x += 2, ++s) {
                const int i = x - p_.x0 + 1, o = j * nx + s;
                for (int ch = 1; ch <= 2; ++ch) {
                    const double mod = 0.25 * (pixel_value(t, cov, shade, ch, i - 1, j) +
                                               2.0 * pixel_value(t, cov, shade, ch, i, j) +
                                               pixel_value(t, cov, shade, ch, i + 1, j));
                    const double r = (ch == 1 ? w_.obs_cb[o] : w_.obs_cr[o]) - mod;
                    if (a) {
                        row.fill(0.0);
                        pixel_row(t, ch, i - 1, j, 0.25, row);
                        pixel_row(t, ch, i, j, 0.5, row);
                        pixel_row(t, ch, i + 1, j, 0.25, row);
                    }
                    add(r, wc);
                }
            }
        }
        return chi2;
    }

    // Base render with finite-difference derivatives by centre x, centre v and radius.
    void linearise(const Vec& t) {
        const int n = p_.lines * p_.cols;
        render(t[kX0], t[kV0], t[kR], w_.cov.data(), w_.shade.data());
        constexpr double h = 1e-3;
        for (int q = 0; q < 3; ++q) {
            double* dc = w_.dcov.data() + q * n;
            double* ds = w_.dshade.data() + q * n;
            render(t[kX0] + (q == 0 ? h : 0), t[kV0] + (q == 1 ? h : 0), t[kR] + (q == 2 ? h : 0), dc, ds);
            for (int k = 0; k < n; ++k) {
                dc[k] = (dc[k] - w_.cov[k]) / h;
                ds[k] = (ds[k] - w_.shade[k]) / h;
            }
        }
    }

    int np() const { return p_.outline ? kMaxPar : kPhi; }
    double var_c() const { return cfg_.noise_dn * cfg_.noise_dn + 1.0 / 12.0; }
    int observations() const {
        const int nx = p_.x1 - p_.x0 + 1;
        return p_.lines * (nx + 2 * ((p_.x1 - (p_.x0 + (p_.x0 & 1))) / 2 + 1));
    }

private:
    const SphereFitConfig& cfg_;
    const Patch& p_;
    SphereFitWorkspace& w_;
};

// Intensity centroid of the fitted sphere over the field's pixels (pixel centres weighted by the coverage ×
// shading each pixel integrates — the rig's truth definition), field px.
void intensity_centroid(const SphereFitConfig& cfg, double x0, double v0, double r, int parity, double& cx,
                        double& cy) {
    constexpr int S = 16;
    const double h = 1.0 / S, inv_r2 = 1.0 / (r * r);
    double si = 0, sx = 0, sv = 0;
    const int lo_v = static_cast<int>(std::floor(v0 - r - 1)), hi_v = static_cast<int>(std::ceil(v0 + r + 1));
    const int lo_x = static_cast<int>(std::floor(x0 - r - 1)), hi_x = static_cast<int>(std::ceil(x0 + r + 1));
    for (int v = lo_v; v <= hi_v; ++v) {
        if (((v - parity) & 1) != 0) continue;
        for (int x = lo_x; x <= hi_x; ++x) {
            double in = 0;
            for (int sy = 0; sy < S; ++sy) {
                const double yy = v - 0.5 + (sy + 0.5) * h - v0;
                for (int sx2 = 0; sx2 < S; ++sx2) {
                    const double xx = x - 0.5 + (sx2 + 0.5) * h - x0;
                    const double q = 1.0 - (xx * xx + yy * yy) * inv_r2;
                    if (q > 0) in += cfg.shade_ambient + cfg.shade_diffuse * std::sqrt(q);
                }
            }
            si += in;
            sx += in * x;
            sv += in * v;
        }
    }
    cx = sx / si;
    cy = 0.5 * (sv / si - parity);
}

}  // namespace

SphereFitResult fit_sphere(const uint8_t* field, int height, const Blob& blob, const SphereFitConfig& cfg,
                           SphereFitWorkspace& w) {
    SphereFitResult res;
    constexpr int kWidth = 720, kStride = 1440;
    if (blob.class_id < 1 || blob.class_id > 4 || blob.sum_w == 0) return res;
    Patch p;
    p.x0 = std::max(1, blob.x_min - cfg.margin_px);
    p.x1 = std::min(kWidth - 2, blob.x_max + cfg.margin_px);
    p.j0 = std::max(0, blob.y_min - cfg.margin_lines);
    p.j1 = std::min(height - 1, blob.y_max + cfg.margin_lines);
    p.parity = blob.parity & 1;
    p.cols = p.x1 - p.x0 + 3;
    p.lines = p.j1 - p.j0 + 1;
    if (p.x1 - p.x0 + 1 > kFitMaxCols || p.lines > kFitMaxLines || p.x1 <= p.x0) return res;
    p.colour = cfg.colour[blob.class_id];
    const double cx0 = blob.cx_px(), cy0 = blob.cy_px();
    p.xc = cx0;
    p.vc = 2.0 * cy0 + p.parity;

    // Observations and the border's levels.
    const int nx = p.x1 - p.x0 + 1;
    const double shot = cfg.shot_gain, n2 = cfg.noise_dn * cfg.noise_dn;
    for (int j = 0; j < p.lines; ++j) {
        const uint8_t* line = field + static_cast<size_t>(p.j0 + j) * kStride;
        for (int x = 0; x < nx; ++x) {
            const double yv = line[2 * (p.x0 + x) + 1];
            w.obs_y[j * nx + x] = yv;
            w.var_y[j * nx + x] = n2 + shot * std::max(0.0, yv - 16.0) + 1.0 / 12.0;
        }
        int s = 0;
        for (int x = p.x0 + (p.x0 & 1); x <= p.x1; x += 2, ++s) {
            w.obs_cb[j * nx + s] = line[2 * x];
            w.obs_cr[j * nx + s] = line[2 * x + 2];
        }
    }
    // Border walk, clockwise: levels, and where the luma crosses its mid level (an outline through the patch).
    struct BorderPx {
        double x, v, c[3];
    };
    std::array<BorderPx, 2 * (kFitMaxCols + kFitMaxLines)> border;
    int nb = 0;
    auto push = [&](int x, int j) {
        const uint8_t* line = field + static_cast<size_t>(j) * kStride;
        border[static_cast<size_t>(nb++)] = {double(x), 2.0 * j + p.parity,
                                             {double(line[2 * x + 1]), double(line[4 * (x >> 1)]), double(line[4 * (x >> 1) + 2])}};
    };
    for (int x = p.x0; x < p.x1; ++x) push(x, p.j0);
    for (int j = p.j0; j < p.j1; ++j) push(p.x1, j);
    for (int x = p.x1; x > p.x0; --x) push(x, p.j1);
    for (int j = p.j1; j > p.j0; --j) push(p.x0, j);
    double lo = 1e9, hi = -1e9, mean[3] = {0, 0, 0};
    for (int k = 0; k < nb; ++k) {
        lo = std::min(lo, border[k].c[0]);
        hi = std::max(hi, border[k].c[0]);
        for (int c = 0; c < 3; ++c) mean[c] += border[k].c[c] / nb;
    }

    Vec t{};
    t[kX0] = cx0;
    t[kV0] = p.vc;
    t[kR] = 0.5 * (blob.x_max - blob.x_min + 1);
    t[kA] = 1.0;
    for (int c = 0; c < 3; ++c) t[kB0 + 3 * c] = mean[c];
    if (hi - lo > cfg.outline_step_dn) {
        const double mid = 0.5 * (lo + hi);
        double cross[2][2];
        int nc = 0;
        for (int k = 0; k < nb; ++k) {
            const BorderPx& a = border[k];
            const BorderPx& b = border[(k + 1) % nb];
            if ((a.c[0] - mid) * (b.c[0] - mid) < 0) {
                if (nc < 2) {
                    const double u = (mid - a.c[0]) / (b.c[0] - a.c[0]);
                    cross[nc][0] = a.x + u * (b.x - a.x);
                    cross[nc][1] = a.v + u * (b.v - a.v);
                }
                ++nc;
            }
        }
        if (nc == 2) {
            double nxv = -(cross[1][1] - cross[0][1]), nvv = cross[1][0] - cross[0][0];
            const double len = std::hypot(nxv, nvv);
            if (len > 0) {
                nxv /= len;
                nvv /= len;
                double sd = 0, sb = 0, dark[3] = {0, 0, 0}, bright[3] = {0, 0, 0};
                int nd = 0, nbr = 0;
                for (int k = 0; k < nb; ++k) {
                    const double d = nxv * (border[k].x - cross[0][0]) + nvv * (border[k].v - cross[0][1]);
                    const bool is_dark = border[k].c[0] < mid;
                    (is_dark ? sd : sb) += d;
                    ++(is_dark ? nd : nbr);
                    for (int c = 0; c < 3; ++c) (is_dark ? dark : bright)[c] += border[k].c[c];
                }
                if (nd > 0 && nbr > 0) {
                    if (sd / nd < sb / nbr) {  // normal points to the dark side
                        nxv = -nxv;
                        nvv = -nvv;
                    }
                    p.outline = true;
                    t[kPhi] = std::atan2(nvv, nxv);
                    t[kD] = nxv * (cross[0][0] - p.xc) + nvv * (cross[0][1] - p.vc);
                    for (int c = 0; c < 3; ++c) {
                        t[kB0 + 3 * c] = bright[c] / nbr;
                        t[kB2 + c] = dark[c] / nd;
                    }
                }
            }
        }
    }

    Fitter f(cfg, p, w);
    const int np = f.np();
    double chi2 = f.cost(t), lambda = 1e-3;
    int it = 0;
    for (; it < cfg.max_iterations; ++it) {
        f.linearise(t);
        Mat a{};
        Vec g{};
        f.residuals(t, w.cov.data(), w.shade.data(), &a, &g);
        for (int q = 0; q < np; ++q)
            for (int s = q + 1; s < np; ++s) a[q * kMaxPar + s] = a[s * kMaxPar + q];
        bool improved = false;
        double gain = 0;
        for (int tries = 0; tries < 8 && !improved; ++tries) {
            Vec d;
            if (solve_damped(a, g, np, lambda, d)) {
                Vec tt = t;
                for (int q = 0; q < np; ++q) tt[q] += d[q];
                const double c1 = f.cost(tt);
                if (c1 < chi2) {
                    gain = chi2 - c1;
                    t = tt;
                    chi2 = c1;
                    lambda = std::max(1e-7, lambda * 0.3);
                    improved = true;
                    break;
                }
            }
            lambda *= 10.0;
        }
        if (!improved || gain < 1e-6 * chi2) break;
        // A fit still far off after a few steps is another object in the patch: stop paying for it.
        if (it >= 3 && chi2 > 4.0 * cfg.max_reduced_chi2 * std::max(1, f.observations() - np)) break;
    }
    res.iterations = it;
    res.outline = p.outline;
    const int dof = std::max(1, f.observations() - np);
    res.reduced_chi2 = chi2 / dof;
    res.radius_px = t[kR];
    res.centre_x_px = t[kX0];
    res.centre_y_px = 0.5 * (t[kV0] - p.parity);
    const double box_r = 0.5 * (blob.x_max - blob.x_min + 1);
    const bool sane = std::isfinite(chi2) && res.reduced_chi2 <= cfg.max_reduced_chi2 && t[kR] > 0.5 &&
                      t[kR] < 2.0 * box_r + 2.0 && t[kA] > 0.2 && t[kA] < 5.0 &&
                      std::fabs(t[kX0] - cx0) < 1.5 && std::fabs(t[kV0] - p.vc) < 2.0;
    if (!sane) return res;
    intensity_centroid(cfg, t[kX0], t[kV0], t[kR], p.parity, res.cx_px, res.cy_px);
    // Both estimate the same centroid; a fit that moves far from the pipeline's has modelled something else (a
    // partly occluded marker's hidden half, a neighbour in the patch).
    res.ok = std::isfinite(res.cx_px) && std::isfinite(res.cy_px) &&
             std::hypot(res.cx_px - cx0, res.cy_px - cy0) <= cfg.max_shift_px;
    return res;
}

}  // namespace eyesim::fpga
