#include "eyesim/tracking/refine.hpp"

#include <algorithm>
#include <cmath>
#include <string_view>
#include <type_traits>
#include <utility>

namespace eyesim::tracking {

// The documented storage of one fit (docs/fpga-pipeline.md): a fixed block a device CPU can hold.
static_assert(sizeof(SphereFitWorkspace) <= 256 * 1024, "SphereFitWorkspace grew past 256 KiB");

MarkerColour MarkerColour::from_rgb(double r, double g, double b) {
    const double l = 0.299 * r + 0.587 * g + 0.114 * b;
    return {219.0 / 255.0 * l, 224.0 / 255.0 * (b - l) / 1.772, 224.0 / 255.0 * (r - l) / 1.402};
}

const char* to_string(FitRefusal r) {
    switch (r) {
        case FitRefusal::kNone: return "none";
        case FitRefusal::kInput: return "input";
        case FitRefusal::kStorage: return "storage";
        case FitRefusal::kChi2: return "chi2";
        case FitRefusal::kImplausible: return "implausible";
        case FitRefusal::kOutliers: return "outliers";
        case FitRefusal::kShift: return "shift";
        case FitRefusal::kHintOutline: return "hint_outline";
    }
    return "?";
}

SphereFitConfig sphere_fit_config_for_source(SphereFitConfig config, const char* chroma, bool lossless) {
    const std::string_view c = chroma ? chroma : "4:2:2";
    // Subsampled chroma, interpolated back, smooths the marker's colour edge over two to four pixels; lossy coding
    // adds blocking of several DN. Either misfit the model's 4:2:2 chroma far beyond the sensor's σ.
    if (c != "4:2:2" || !lossless) config.chroma_noise_dn = 8.0;
    // Lossy luma: the codec's quantisation error near the marker's edge (DCT ringing), a few DN.
    if (!lossless) config.luma_noise_floor_dn = 2.0;
    // Lossy coding moves the pipeline's chroma-only centroid itself by ≈ 0.1 px RMS, so a fit 0.15 px from it is
    // as often the right one as not: the shift test, which catches fits of something else, needs a wider gate.
    if (!lossless) config.max_shift_px = std::max(config.max_shift_px, kLossyMaxShiftPx);
    // A partly hidden marker's pipeline centroid on lossy video, or from subsampled chroma, is further off still (its
    // chroma spread across the occluder's edge; DV: 0.31 px at the 99th percentile against 0.23 for clear markers;
    // FFV1 4:1:1 slivers 2.3–2.6 px), and a hinted fit has the occluders modelled: its gate is wider again.
    const bool subsampled = c != "4:2:2";
    if (!lossless || subsampled)
        config.max_shift_hinted_px = std::max(config.max_shift_hinted_px, kLossyMaxShiftHintedPx);
    // There a sliver's pipeline centroid (a marker mostly hidden) can be a pixel off, and the pose, a field old,
    // is the better anchor for its fit; so with 4:1:1 chroma (a sample in four columns), where it was 2.3 px off
    // (FFV1 4:1:1 `sweep` seed 91). Not on the camera's own fields: their sliver centroids are within tenths, and
    // the pose's anchor refused good fits (bench_refine, sweep seeds 21–30, σ = 1: partly hidden 6–10 px markers
    // 0.0316 → 0.0358 px with it); nor with lossless 4:2:0, where it cost more than it gained (FFV1 4:2:0 seeds
    // 91–106: geometric mean 1.00 → 1.07 × raw).
    if (!lossless || c == "4:1:1")
        config.prediction_gate_visible = std::max(config.prediction_gate_visible, kLossyPredictionGateVisible);
    // And there the start placed from that centroid can lead the fit into another minimum: a refused hinted fit is
    // tried again from the pose's prediction (DVCPRO25 `sweep` seed 21, an eye marker 79 % behind the eye's outline,
    // its pipeline centroid 1.6 px off: the fit ended 3 px from the prediction and was refused as implausible).
    // So with any subsampled chroma (FFV1 4:2:0 / 4:1:1 `sweep` seeds 91–106, geometric mean × raw: 1.00 → 0.94,
    // 1.40 → 1.27).
    if (!lossless || subsampled) config.restart_from_prediction = true;
    // Chroma coarser than 4:2:2 along a direction (4:1:1: one sample in four columns; 4:2:0: one line in two)
    // leaves the pipeline's chroma-only centroid about twice as uncertain along it.
    if (c == "4:1:1") config.shift_x_scale = 2.0;
    if (c == "4:2:0") config.shift_y_scale = 2.0;
    // The same codec error, or subsampled chroma spread across the eye's outline, makes a shaft fit beside that
    // outline the better of the two (SphereFitConfig).
    if (c != "4:2:2" || !lossless) config.hint_with_outline = true;
    return config;
}

namespace {

// The taps over fine samples (field lines, or 4:2:2 chroma samples) d = −kChromaChainLines … kChromaChainLines about
// fine sample y of a chain whose coarse rows lie every two fine samples at 2k + site: each coarse row the tent of
// half-width two fine samples about its site, the reader's linear interpolation between the two rows about the fine
// sample (its weights in 1/256, as it takes them). n_fine > 0: only the fine samples 0 … n_fine − 1 and the rows
// 0 … n_fine / 2 − 1 exist, the writer repeating the edge samples and the reader the edge rows; 0: no edge.
void compose_chain(double site, int y, int n_fine, double* out) {
    constexpr int kL = kChromaChainLines;
    std::fill(out, out + 2 * kL + 1, 0.0);
    const double at = (y - site) / 2.0, row0 = std::floor(at);
    const double w1 = std::round((at - row0) * 256.0) / 256.0;
    for (int a = 0; a < 2; ++a) {
        const double wa = a == 0 ? 1.0 - w1 : w1;
        if (wa == 0.0) continue;
        double row = row0 + a;
        if (n_fine > 0) row = std::clamp(row, 0.0, static_cast<double>(n_fine / 2 - 1));
        const double centre = 2.0 * row + site;
        double tent[5], sum = 0;
        const int first = static_cast<int>(std::floor(centre)) - 1;
        for (int k = 0; k < 5; ++k) sum += tent[k] = std::max(0.0, 1.0 - std::fabs(first + k - centre) / 2.0);
        for (int k = 0; k < 5; ++k) {
            const int line = n_fine > 0 ? std::clamp(first + k, 0, n_fine - 1) : first + k;
            const int d = line - y;
            if (tent[k] > 0.0 && d >= -kL && d <= kL) out[d + kL] += wa * tent[k] / sum;
        }
    }
}

}  // namespace

void chroma_chain_420(SphereFitConfig& config, const double site_lines[2][2], int field_lines) {
    constexpr int kE = kChromaChainEdgeLines;
    const bool edges = field_lines >= 4 * kE;  // a field tall enough for its two edges' taps not to meet
    for (int p = 0; p < 2; ++p)
        for (int c = 0; c < 2; ++c) {
            // A fine sample of each phase away from the edges.
            for (int phase = 0; phase < 2; ++phase)
                compose_chain(site_lines[p][c], 8 + phase, 0, config.chroma_v_taps[p][phase][c]);
            for (int k = 0; edges && k < kE; ++k) {
                compose_chain(site_lines[p][c], k, field_lines, config.chroma_v_edge_taps[p][0][k][c]);
                compose_chain(site_lines[p][c], field_lines - 1 - k, field_lines, config.chroma_v_edge_taps[p][1][k][c]);
            }
        }
    config.chroma_chain_field_lines = edges ? field_lines : 0;
    config.chroma_chain = true;
    if (!(config.chain_chroma_noise_dn > 0)) config.chain_chroma_noise_dn = config.noise_dn;
}

const double* chroma_chain_v_taps(const SphereFitConfig& config, int parity, int y, int c, int field_lines) {
    constexpr int kE = kChromaChainEdgeLines;
    parity &= 1;
    if (field_lines > 0 && field_lines == config.chroma_chain_field_lines) {
        if (y >= 0 && y < kE) return config.chroma_v_edge_taps[parity][0][y][c];
        if (y < field_lines && y >= field_lines - kE) return config.chroma_v_edge_taps[parity][1][field_lines - 1 - y][c];
    }
    return config.chroma_v_taps[parity][y & 1][c];
}

void chroma_chain_411(SphereFitConfig& config, double site_px) {
    // In 4:2:2 samples (two luma columns each), 4:1:1 sample m lies at 2m + site_px / 2.
    for (int phase = 0; phase < 2; ++phase) compose_chain(site_px / 2.0, 8 + phase, 0, config.chroma_h_taps[phase]);
    config.chroma_chain_h = true;
    if (!(config.chain_chroma_noise_dn > 0)) config.chain_chroma_noise_dn = config.noise_dn;
}

namespace {

// Variance of one set of chain taps about their observation (in their own steps: lines or samples).
double taps_variance(const double* t) {
    double s = 0, m1 = 0, m2 = 0;
    for (int d = -kChromaChainLines; d <= kChromaChainLines; ++d) {
        s += t[d + kChromaChainLines];
        m1 += d * t[d + kChromaChainLines];
        m2 += d * d * t[d + kChromaChainLines];
    }
    return s > 0 ? m2 / s - (m1 / s) * (m1 / s) : 0.0;
}

// Variance (field lines²) of the chain's taps about the observation's line, averaged over the line phases and
// components of a field of `parity`: how far the chain spreads the marker's chroma down the lines.
double chain_variance_lines(const SphereFitConfig& cfg, int parity) {
    double var = 0;
    for (int phase = 0; phase < 2; ++phase)
        for (int c = 0; c < 2; ++c) var += taps_variance(cfg.chroma_v_taps[parity & 1][phase][c]);
    return var / 4.0;
}

// The same for the horizontal chain, in 4:2:2 samples² (a sample is two columns).
double chain_variance_samples(const SphereFitConfig& cfg) {
    return 0.5 * (taps_variance(cfg.chroma_h_taps[0]) + taps_variance(cfg.chroma_h_taps[1]));
}

// The taps of no chain: the observation's own line or sample.
constexpr double kIdentityTaps[2 * kChromaChainLines + 1] = {0, 0, 0, 1, 0, 0, 0};
static_assert(kChromaChainLines == 3);

// Whether a box of half-sizes (hx, hv) whose centre is (dx, dv) from a point lies within r of it.
bool box_within(double dx, double dv, double hx, double hv, double r) {
    const double ex = std::max(0.0, std::fabs(dx) - hx), ev = std::max(0.0, std::fabs(dv) - hv);
    return ex * ex + ev * ev <= r * r;
}

}  // namespace

bool shaft_touches(const ForeignShaft& shaft, double x_px, double v_px, double hx, double hv) {
    const double dx = x_px - shaft.x_px, dv = v_px - shaft.v_px;
    const double along = dx * shaft.ux + dv * shaft.uv, across = std::fabs(dv * shaft.ux - dx * shaft.uv);
    // The box's reach across and along the strip (its support in those directions).
    const double reach_across = hx * std::fabs(shaft.uv) + hv * std::fabs(shaft.ux);
    const double reach_along = hx * std::fabs(shaft.ux) + hv * std::fabs(shaft.uv);
    if (across > shaft.half_width_px + reach_across) return false;
    if (!shaft.from_start || along >= 0) return true;
    if (along < -(shaft.half_width_px + reach_along)) return false;
    // Beside the start: the rounded end, a disc of the half-width about the start point.
    return box_within(dx, dv, hx, hv, shaft.half_width_px);
}

namespace {

// Whether the ray of (qx, qy) from the camera at (0, 0, −l) meets the sphere about `o` (radius `r`) before the
// marker (centre 0, radius 1), or meets it where it misses the marker; all in marker radii, view frame.
bool sphere_hides(const double o[3], double r, double l, double qx, double qy) {
    // The ray (0, 0, −L) + t·(qx, qy, L).
    const double dx = qx, dy = qy, dz = l;
    const double a2 = dx * dx + dy * dy + dz * dz;
    const double ox = -o[0], oy = -o[1], oz = -l - o[2];
    const double b = ox * dx + oy * dy + oz * dz, c0 = ox * ox + oy * oy + oz * oz - r * r;
    const double disc_o = b * b - a2 * c0;
    if (disc_o < 0) return false;
    const double t_occ = (-b - std::sqrt(disc_o)) / a2;
    const double bm = -l * dz, cm = l * l - 1.0, disc_m = bm * bm - a2 * cm;
    return t_occ > 0 && (disc_m < 0 || t_occ < (-bm - std::sqrt(disc_m)) / a2);
}

}  // namespace

bool hint_covers(const MarkerHint& hint, double qx, double qy) {
    // In units of the sphere's radius about its centre, view frame (z away from the camera): the ray of q is
    // (qx, qy, z); the sphere's near surface is at z = −√(1 − q²); the shaft is every point within ρ of the axis a:
    // (1 − a_z²)·z² − 2·s·a_z·z + q² − s² − ρ² ≤ 0 with s = q·(a_x, a_y).
    const double q2 = qx * qx + qy * qy;
    if (hint.view_distance > 0) {
        if (hint.occluder_radius > 0 && sphere_hides(hint.occluder_view, hint.occluder_radius, hint.view_distance, qx, qy))
            return true;
        if (hint.occluder2_radius > 0 &&
            sphere_hides(hint.occluder2_view, hint.occluder2_radius, hint.view_distance, qx, qy))
            return true;
    }
    if (!(hint.radius_ratio > 0)) return false;
    const double ax = hint.axis_view[0], ay = hint.axis_view[1], az = hint.axis_view[2], rho = hint.radius_ratio;
    const double s = qx * ax + qy * ay, c = q2 - s * s - rho * rho, a = 1.0 - az * az;
    if (a < 1e-12) return c <= 0;  // the axis along the line of sight: a disc in front of the sphere
    const double disc = s * s * az * az - a * c;
    if (disc < 0) return false;  // the ray passes beside the shaft
    if (q2 >= 1.0) return true;
    return (s * az - std::sqrt(disc)) / a < -std::sqrt(1.0 - q2);
}

void mark_foreign_overlaps(std::span<BlobBox> boxes) {
    for (BlobBox& b : boxes) {
        b.foreign_overlap = b.foreign_touch = false;
        for (const BlobBox& o : boxes) {
            b.foreign_overlap = b.foreign_overlap || foreign_overlap(o, b);
            b.foreign_touch = b.foreign_touch || foreign_touch(o, b);
        }
    }
}

namespace {

constexpr int kMaxPar = 24;
// Two doubles in one SSE2 register (GCC / Clang vector extension): sums over two independent lanes.
typedef double V2 __attribute__((vector_size(16)));
// Parameters: centre (frame x, frame v), radius (frame px), the outline's ellipticity (e1, e2: the marker's
// outline is ρ² = (1 + e1)·dx² + 2·e2·dx·dv + (1 − e1)·dv² = r²; pixel aspect and perspective make a sphere's
// image an ellipse), amplitude; background per channel Y, Cb, Cr as level + x slope + v slope about the patch
// reference; outline: normal angle, offset, the level beyond it per channel, its curvature, and per channel the
// gain of the limb shading inside it.
enum : int { kX0, kV0, kR, kE1, kE2, kA, kB0, kPhi = 15, kD, kB2, kKappa = 20, kG };
constexpr int kShapePar = 5;  // centre, radius, ellipticity: the parameters the marker render depends on
constexpr double kOffset[3] = {16.0, 128.0, 128.0};

using Vec = std::array<double, kMaxPar>;
using Mat = std::array<double, kMaxPar * kMaxPar>;

// The unknowns' structure solve_damped_blocks() uses: parameters every channel's observations depend on (the
// marker's, the outline's geometry) and, per channel, those only its own observations depend on (its background;
// with an outline also the level beyond it and the limb's gain).
template <int NS, int NB>
struct BlockLayout {
    int shared[NS];
    int block[3][NB];
};
constexpr BlockLayout<6, 3> kLayoutMarker = {{kX0, kV0, kR, kE1, kE2, kA}, {{6, 7, 8}, {9, 10, 11}, {12, 13, 14}}};
constexpr BlockLayout<9, 5> kLayoutOutline = {{kX0, kV0, kR, kE1, kE2, kA, kPhi, kD, kKappa},
                                              {{6, 7, 8, kB2, kG}, {9, 10, 11, kB2 + 1, kG + 1}, {12, 13, 14, kB2 + 2, kG + 2}}};

// Solves (A + λ·diag A)·x = g, Levenberg–Marquardt's damped normal equations, by Cholesky. The channels' blocks do
// not couple with each other, so each is eliminated on its own (Schur complement) and only the shared parameters'
// system is factorised whole: 6 × 6 instead of 15 × 15 without an outline, 9 × 9 instead of 24 × 24 with one (the
// dense 24 × 24 factorisation was a fifth of an outline fit). The same solution to rounding (checked against it on
// 20,000 systems of two surgery recordings: 1e-6 relative); false when not positive definite (a damped block or the
// complement).
template <int NS, int NB>
bool solve_damped_blocks(const Mat& a, const Vec& g, const BlockLayout<NS, NB>& lay, double lambda, Vec& x) {
    constexpr int kS = NS, kB = NB, ns = NS, nb = NB;
    auto at = [&](int i, int j) {
        return i >= j ? a[static_cast<size_t>(i * kMaxPar + j)] : a[static_cast<size_t>(j * kMaxPar + i)];
    };
    auto diag = [&](int i) { return a[static_cast<size_t>(i * kMaxPar + i)] * (1.0 + lambda) + 1e-9; };
    // In place Cholesky of a lower triangle (row stride `st`), reciprocal pivots out.
    auto factor = [](double* m, int n, int st, double* inv_d) {
        for (int i = 0; i < n; ++i)
            for (int j = 0; j <= i; ++j) {
                double v = m[i * st + j];
                for (int k = 0; k < j; ++k) v -= m[i * st + k] * m[j * st + k];
                if (i == j) {
                    if (!(v > 0)) return false;
                    m[i * st + i] = std::sqrt(v);
                    inv_d[i] = 1.0 / m[i * st + i];
                } else {
                    m[i * st + j] = v * inv_d[j];
                }
            }
        return true;
    };
    double s[kS * kS], h[kS];  // the shared parameters' complement (lower triangle) and right-hand side
    for (int i = 0; i < ns; ++i) {
        for (int j = 0; j < i; ++j) s[i * kS + j] = at(lay.shared[i], lay.shared[j]);
        s[i * kS + i] = diag(lay.shared[i]);
        h[i] = g[static_cast<size_t>(lay.shared[i])];
    }
    double l[3][kB * kB], inv_l[3][kB], wm[3][kB][kS], wg[3][kB];  // per channel: factor, L⁻¹·A_bs, L⁻¹·g_b
    for (int c = 0; c < 3; ++c) {
        const int* blk = lay.block[c];
        double* lc = l[c];
        for (int i = 0; i < nb; ++i) {
            for (int j = 0; j < i; ++j) lc[i * kB + j] = at(blk[i], blk[j]);
            lc[i * kB + i] = diag(blk[i]);
        }
        if (!factor(lc, nb, kB, inv_l[c])) return false;
        // Forward substitution for the shared columns and the right-hand side together.
        for (int i = 0; i < nb; ++i) {
            double* wi = wm[c][i];
            double gi = g[static_cast<size_t>(blk[i])];
            for (int m = 0; m < ns; ++m) wi[m] = at(blk[i], lay.shared[m]);
            for (int k = 0; k < i; ++k) {
                const double lik = lc[i * kB + k];
                for (int m = 0; m < ns; ++m) wi[m] -= lik * wm[c][k][m];
                gi -= lik * wg[c][k];
            }
            for (int m = 0; m < ns; ++m) wi[m] *= inv_l[c][i];
            wg[c][i] = gi * inv_l[c][i];
        }
        for (int k = 0; k < nb; ++k) {
            const double* wk = wm[c][k];
            for (int i = 0; i < ns; ++i) {
                for (int j = 0; j <= i; ++j) s[i * kS + j] -= wk[i] * wk[j];
                h[i] -= wk[i] * wg[c][k];
            }
        }
    }
    double inv_d[kS];
    if (!factor(s, ns, kS, inv_d)) return false;
    double y[kS], xs[kS];
    for (int i = 0; i < ns; ++i) {
        double v = h[i];
        for (int k = 0; k < i; ++k) v -= s[i * kS + k] * y[k];
        y[i] = v * inv_d[i];
    }
    for (int i = ns - 1; i >= 0; --i) {
        double v = y[i];
        for (int k = i + 1; k < ns; ++k) v -= s[k * kS + i] * xs[k];
        xs[i] = v * inv_d[i];
    }
    x.fill(0.0);
    for (int i = 0; i < ns; ++i) x[static_cast<size_t>(lay.shared[i])] = xs[i];
    // Each channel's block: Lᵀ·x_b = L⁻¹·g_b − (L⁻¹·A_bs)·x_s.
    for (int c = 0; c < 3; ++c) {
        double r[kB], xb[kB];
        for (int k = 0; k < nb; ++k) {
            r[k] = wg[c][k];
            for (int m = 0; m < ns; ++m) r[k] -= wm[c][k][m] * xs[m];
        }
        for (int i = nb - 1; i >= 0; --i) {
            double v = r[i];
            for (int k = i + 1; k < nb; ++k) v -= l[c][k * kB + i] * xb[k];
            xb[i] = v * inv_l[c][i];
        }
        for (int i = 0; i < nb; ++i) x[static_cast<size_t>(lay.block[c][i])] = xb[i];
    }
    return true;
}

// Analytic pixel integrals of the marker model (SphereFitModel::kAnalytic). With the outline metric
// ρ(x) = √(xᵀMx), M = [[1 + e1, e2], [e2, 1 − e1]], the marker is coverage c(ρ) = [ρ < r] and shading
// q(ρ) = √(1 − ρ²/r²) inside it. Across an edge pixel ρ is nearly linear: ρ ≈ ρ_eff + g·u over the pixel box u, so
// ρ is ρ_eff plus a sum of two uniform variables (half-widths α = |g_x|/2, β = |g_v|·ap/2) and the pixel's mean of
// any h(ρ) is a second difference of h's second antiderivative over the box's four corners. ρ_eff adds the mean
// of the quadratic term (the outline's curvature within the pixel). Inside, away from the rim, q is smooth in ρ²
// (which is exactly quadratic over the pixel): its mean is taken to second order.
struct PixelIntegral {
    double cov = 0, q = 0;    // pixel means of c and q (fractions of the pixel)
    double dcov = 0, dq = 0;  // their derivatives by ρ
    double drho[5] = {};      // ∂ρ_eff by centre x, centre v, r (0), e1, e2
    bool inside = false;      // interior branch: dq_dp holds ∂E[q] by the shape parameters directly
    double dq_dp[5] = {};
};

// asin on [0, 1/√2] from a cubic Hermite table (values and slopes), within 1e-15 of std::asin there; above it
// π/2 − asin(√(1 − t²)), within 1e-13 (the error of √(1 − t²) itself). std::asin was a fifth of the render.
struct AsinTable {
    static constexpr int kN = 1024;
    static constexpr double kMax = 0.70711;  // just above 1/√2
    static constexpr double kScale = kN / kMax;
    double v[kN + 2], d[kN + 2];  // asin and h·asin′ at the nodes
    AsinTable() {
        const double h = kMax / kN;
        for (int i = 0; i <= kN + 1; ++i) {
            const double t = i * h;
            v[i] = std::asin(t);
            d[i] = h / std::sqrt(1.0 - t * t);
        }
    }
};
inline double asin_small(double u) {
    static const AsinTable tab;
    const double x = u * AsinTable::kScale;
    const int i = static_cast<int>(x);
    const double f = x - i, g = 1.0 - f;
    return (1.0 + 2.0 * f) * g * g * tab.v[i] + f * g * g * tab.d[i] + f * f * (3.0 - 2.0 * f) * tab.v[i + 1] -
           f * f * g * tab.d[i + 1];
}
// asin(t) for t in [0, 1] given s = √(1 − t²).
inline double asin_01(double t, double s) {
    constexpr double kHalfPi = 1.5707963267948966;
    return t <= 0.7071067811865476 ? asin_small(t) : kHalfPi - asin_small(s);
}

// Second antiderivatives (and first) of c and q in ρ, extended evenly to ρ < 0 (c, q even; S1, Q1 odd). kShade
// false: c's alone (q1, q2 left 0), piecewise quadratic — no square root, no arcsine.
struct Anti {
    double s1, s2, q1 = 0, q2 = 0;
};
template <bool kShade = true>
inline Anti anti(double rho, double r, double inv_r) {
    const double a = std::fabs(rho), sg = rho < 0 ? -1.0 : 1.0;
    constexpr double kQuarterPi = 0.78539816339744831;
    Anti o;
    if (a >= r) {
        o.s1 = sg * r;
        o.s2 = r * a - 0.5 * r * r;
        if constexpr (kShade) {
            o.q1 = sg * r * kQuarterPi;
            o.q2 = r * r * kQuarterPi + r * kQuarterPi * (a - r);
        }
        return o;
    }
    o.s1 = sg * a;
    o.s2 = 0.5 * a * a;
    if constexpr (kShade) {
        const double t = a * inv_r, s = std::sqrt(std::max(0.0, 1.0 - t * t)), as = asin_01(t, s);
        o.q1 = sg * 0.5 * r * (t * s + as);
        o.q2 = 0.5 * r * r * (s - s * s * s / 3.0 + t * as);
    }
    return o;
}

// How far past the outline (in ρ) a pixel's centre may lie and the pixel still reach the marker: |∇ρ| ≤ √(1 + |e|)
// ≤ 1.307 (|e1|, |e2| ≤ 0.5) times the half diagonal of the pixel, 1 × ap frame px.
inline double pixel_reach(double ap) { return 1.31 * std::sqrt(0.25 + 0.25 * ap * ap); }

// Mean of c, q and of their ρ-derivatives over the pixel whose centre is (dx, dv) from the marker's centre.
// Returns false when the pixel is wholly outside the marker. kShade false (a model without shading, whose q the
// caller multiplies by 0): q and its derivatives are left 0 and not computed — the shading's square roots and
// arcsines were most of a flat disc's render; c and its derivatives are the same to the bit.
template <bool kDeriv, bool kShade = true>
bool pixel_integral(double dx, double dv, double r, double e1, double e2, double ap, PixelIntegral& o, double reach) {
    const double mx = (1.0 + e1) * dx + e2 * dv, mv = e2 * dx + (1.0 - e1) * dv;  // M·x
    const double w = dx * mx + dv * mv;                                            // ρ²
    // Outside, tested on ρ² (no square root for the box's corners). Such a pixel fails the test below as well: ρ_eff
    // ≥ ρ (ρ is a norm: its Hessian is positive semidefinite) and α + β ≤ |∇ρ|·(the half diagonal).
    if (w > (r + reach) * (r + reach)) return false;
    const double rho = std::sqrt(w);
    const double inv_r = 1.0 / r, inv_r2 = inv_r * inv_r;
    if (rho + 0.62 * (1.0 + ap) < 0.8 * r) {
        if constexpr (!kShade) {
            o.inside = true;
            o.cov = 1.0;
            o.q = o.dcov = o.dq = 0.0;
            if constexpr (kDeriv)
                for (double& d : o.dq_dp) d = 0.0;
            return true;
        }
        // Interior: ρ² = w + 2(Mx)·u + uᵀMu over the pixel; mean and variance of that, q = ψ(ρ²) to second order.
        const double wm = w + ((1.0 + e1) + (1.0 - e1) * ap * ap) / 12.0;
        const double var = 4.0 * (mx * mx + mv * mv * ap * ap) / 12.0;
        const double psi = std::sqrt(1.0 - wm * inv_r2);
        const double d1 = -0.5 * inv_r2 / psi, d2 = -0.25 * inv_r2 * inv_r2 / (psi * psi * psi);
        o.inside = true;
        o.cov = 1.0;
        o.q = psi + 0.5 * d2 * var;
        o.dcov = o.dq = 0.0;
        if constexpr (kDeriv) {
            o.dq_dp[0] = -2.0 * mx * d1;
            o.dq_dp[1] = -2.0 * mv * d1;
            o.dq_dp[2] = wm * inv_r2 / (r * psi);
            o.dq_dp[3] = (dx * dx - dv * dv + (1.0 - ap * ap) / 12.0) * d1;
            o.dq_dp[4] = 2.0 * dx * dv * d1;
        }
        return true;
    }
    o.inside = false;
    const double inv_rho = 1.0 / std::max(rho, 1e-9);
    const double gx = mx * inv_rho, gv = mv * inv_rho;
    // Mean of the quadratic term: ½·tr(H·Σ_u), H = (M − g gᵀ)/ρ, Σ_u = diag(1, ap²)/12.
    const double hxx = ((1.0 + e1) - gx * gx) * inv_rho, hvv = ((1.0 - e1) - gv * gv) * inv_rho;
    const double re = rho + (hxx + hvv * ap * ap) / 24.0;
    double al = 0.5 * std::fabs(gx), be = 0.5 * ap * std::fabs(gv);
    if (al < be) std::swap(al, be);
    if (re - al - be >= r) return false;
    if (be > 1e-4) {
        const Anti a = anti<kShade>(re + al + be, r, inv_r), b = anti<kShade>(re + al - be, r, inv_r),
                   c = anti<kShade>(re - al + be, r, inv_r), d = anti<kShade>(re - al - be, r, inv_r);
        const double k = 1.0 / (4.0 * al * be);
        o.cov = (a.s2 - b.s2 - c.s2 + d.s2) * k;
        o.q = (a.q2 - b.q2 - c.q2 + d.q2) * k;
        o.dcov = (a.s1 - b.s1 - c.s1 + d.s1) * k;
        o.dq = (a.q1 - b.q1 - c.q1 + d.q1) * k;
    } else {
        // One uniform variable: first differences of the first antiderivatives.
        const Anti a = anti<kShade>(re + al, r, inv_r), b = anti<kShade>(re - al, r, inv_r);
        const double k = 0.5 / al;
        o.cov = (a.s1 - b.s1) * k;
        o.q = (a.q1 - b.q1) * k;
        const double hi = std::fabs(re + al), lo = std::fabs(re - al);
        auto qv = [&](double x) { return x < r ? std::sqrt(1.0 - x * x * inv_r2) : 0.0; };
        o.dcov = ((hi < r ? 1.0 : 0.0) - (lo < r ? 1.0 : 0.0)) * k;
        o.dq = kShade ? (qv(hi) - qv(lo)) * k : 0.0;
    }
    if (re + al + be <= r) {
        // Wholly inside the outline: covered, exactly (not to rounding), so that its normal-equation rows end at
        // the amplitude.
        o.cov = 1.0;
        o.dcov = 0.0;
    }
    if constexpr (kDeriv) {
        o.drho[0] = -gx;
        o.drho[1] = -gv;
        o.drho[2] = 0.0;
        o.drho[3] = 0.5 * (dx * dx - dv * dv) * inv_rho;
        o.drho[4] = dx * dv * inv_rho;
    }
    return true;
}

// Frame offsets (dx, dv) from the sphere's centre to its view frame in units of its radius, q = M·(dx, dv): the
// hint's map from the camera model (scaled to the fitted radius), or without one M = M_outline^½ / r from the
// fitted outline (the outline is then the unit circle; its rotation is lost).
struct OutlineNorm {
    double m00 = 0, m01 = 0, m10 = 0, m11 = 0, stretch = 1;  // stretch: a bound on M's largest gain
    OutlineNorm(const MarkerHint& hint, double r, double e1, double e2) {
        const double* v = hint.view_per_px;
        if (hint.radius_px > 0 && (v[0] != 0 || v[1] != 0 || v[2] != 0 || v[3] != 0)) {
            const double s = hint.radius_px / r;  // the fitted size, the camera model's shape
            m00 = s * v[0];
            m01 = s * v[1];
            m10 = s * v[2];
            m11 = s * v[3];
        } else {
            const double e = std::min(0.9, std::hypot(e1, e2)), sp = std::sqrt(1.0 + e), sm = std::sqrt(1.0 - e);
            const double al = 0.5 * (sp + sm), be = e > 1e-12 ? 0.5 * (sp - sm) / e : 0.5;
            m00 = (al + be * e1) / r;
            m01 = m10 = be * e2 / r;
            m11 = (al - be * e1) / r;
        }
        stretch = std::sqrt(m00 * m00 + m01 * m01 + m10 * m10 + m11 * m11);
    }
    void operator()(double dx, double dv, double& qx, double& qy) const {
        qx = m00 * dx + m01 * dv;
        qy = m10 * dx + m11 * dv;
    }
};

// The hint seen from a fit's centre (x0, v0): a fixed occluder (MarkerHint::occluder_fixed) keeps its place in the
// image, so about the fitted centre it is displaced by the fitted centre's offset from the predicted one.
MarkerHint hint_at(const MarkerHint& hint, const OutlineNorm& nm, double x0, double v0) {
    MarkerHint h = hint;
    const bool fixed1 = h.occluder_fixed && h.occluder_radius > 0, fixed2 = h.occluder2_fixed && h.occluder2_radius > 0;
    if (fixed1 || fixed2) {
        double qx, qy;
        nm(x0 - h.centre_x_px, v0 - h.centre_v_px, qx, qy);
        if (fixed1) {
            h.occluder_view[0] -= qx;
            h.occluder_view[1] -= qy;
        }
        if (fixed2) {
            h.occluder2_view[0] -= qx;
            h.occluder2_view[1] -= qy;
        }
    }
    return h;
}

// A fit's centroid offset from the pipeline's in units of the shift gate's reach along x and y (SphereFitConfig::
// shift_x_scale, shift_y_scale): compared with max_shift_px.
double gate_distance(const SphereFitConfig& cfg, double dx_px, double dy_px) {
    return std::hypot(dx_px / cfg.shift_x_scale, dy_px / cfg.shift_y_scale);
}

// The occluders' images are at least two pixels across (a shaft's band; the eye's rim is nearly straight at this
// scale), so samples one pixel apart cannot pass between their edges: the tests below look at box corners only.

// Whether an occluder's image touches the box of half-sides hx, hv about the offset (dx, dv) from the marker's
// centre (frame px): its four corners and its centre.
bool box_touches_occluder(const MarkerHint& hint, const OutlineNorm& nm, double dx, double dv, double hx, double hv) {
    const double px[5] = {dx - hx, dx + hx, dx - hx, dx + hx, dx}, pv[5] = {dv - hv, dv - hv, dv + hv, dv + hv, dv};
    for (int k = 0; k < 5; ++k) {
        double qx, qy;
        nm(px[k], pv[k], qx, qy);
        if (hint_covers(hint, qx, qy)) return true;
    }
    return false;
}

// Occluder cover of the boxes (half-sides 0.5 + m and hv) of the n pixels at offsets dx0 + k, k = 0 … n − 1, on the
// line at dv: state[k] bit 0: a corner covered; bit 1: every corner covered. Corners one pixel apart along the
// box's top and bottom edges (and its middle, for a box over 1.5 px tall), shared between neighbours.
constexpr int kMaxCoverCols = kFitMaxCols + 24;
void line_cover(const MarkerHint& hint, const OutlineNorm& nm, double dx0, double dv, int n, double m, double hv,
                uint8_t* state) {
    const int span = static_cast<int>(std::ceil(1.0 + 2.0 * m));  // corner steps across one widened box
    const int nc = std::min(n + span, kMaxCoverCols);
    const int rows = 2.0 * hv > 1.5 ? 3 : 2;
    const double rv[3] = {dv - hv, dv + hv, dv};
    uint8_t corner[kMaxCoverCols + 1];
    for (int i = 0; i <= nc; ++i) corner[i] = 0;
    for (int r = 0; r < rows; ++r)
        for (int i = 0; i <= nc; ++i) {
            double qx, qy;
            nm(dx0 - 0.5 - m + i, rv[r], qx, qy);
            corner[i] = static_cast<uint8_t>(corner[i] + (hint_covers(hint, qx, qy) ? 1 : 0));
        }
    for (int k = 0; k < n; ++k) {
        int any = 0, all = 1;
        for (int i = k; i <= std::min(k + span, nc); ++i) {
            any |= corner[i] != 0;
            all &= corner[i] == rows;
        }
        state[k] = static_cast<uint8_t>(any | (all << 1));
    }
}

struct Patch {
    int x0 = 0, x1 = 0, j0 = 0, j1 = 0, parity = 0;
    int cols = 0, lines = 0;  // model columns (x0 - 1 .. x1 + 1) and lines
    double xc = 0, vc = 0;    // reference point of the background slopes (frame px)
    bool outline = false;
    // The source's chroma chains are modelled (SphereFitConfig::chroma_chain, chroma_chain_h): the model's lines
    // reach kChromaChainLines (vertical) and its columns 2·kChromaChainLines (horizontal) beyond the observed ones
    // (lines core_j0 … core_j1, columns core_x0 … core_x1 of the field); what lies beyond is left out (foreign).
    bool chain = false, hchain = false;  // the vertical (4:2:0) and horizontal (4:1:1) chains
    // The field's lines when the chain's edge taps are for them (SphereFitConfig::chroma_v_edge_taps), else 0.
    int edge_height = 0;
    int core_j0 = 0, core_j1 = 0, core_x0 = 0, core_x1 = 0;
    double chroma_sigma_dn = 1.0;  // the chroma observations' σ
    MarkerColour colour;
};

// The chains' taps for a chroma observation on patch line j of channel ch (1 Cb, 2 Cr) over the lines, and for one
// at the patch's chroma sample s over the samples; offsets −kChromaChainLines … kChromaChainLines; the identity where
// the source has no such chain.
const double* chain_vtaps(const SphereFitConfig& cfg, const Patch& p, int j, int ch) {
    return p.chain ? chroma_chain_v_taps(cfg, p.parity, p.j0 + j, ch - 1, p.edge_height) : kIdentityTaps;
}
const double* chain_htaps(const SphereFitConfig& cfg, const Patch& p, int s) {
    return p.hchain ? cfg.chroma_h_taps[((p.x0 + (p.x0 & 1)) / 2 + s) & 1] : kIdentityTaps;
}

// Whether the chroma observation at patch line j, sample s (of ns a line) takes in anything `bits` marks per line
// and sample: its own, and through the chains every line and sample either channel's taps reach.
bool chain_reaches(const SphereFitConfig& cfg, const Patch& p, const uint8_t (*bits)[SphereFitWorkspace::kSamples],
                   int ns, int j, int s) {
    if (bits[j][s]) return true;
    if (!p.chain && !p.hchain) return false;
    constexpr int kL = kChromaChainLines;
    const double *t1 = chain_vtaps(cfg, p, j, 1), *t2 = chain_vtaps(cfg, p, j, 2), *th = chain_htaps(cfg, p, s);
    for (int dv = -kL; dv <= kL; ++dv) {
        if (j + dv < 0 || j + dv >= p.lines || (t1[dv + kL] == 0.0 && t2[dv + kL] == 0.0)) continue;
        for (int dh = -kL; dh <= kL; ++dh)
            if (th[dh + kL] != 0.0 && s + dh >= 0 && s + dh < ns && bits[j + dv][s + dh]) return true;
    }
    return false;
}

class Fitter {
public:
    Fitter(const SphereFitConfig& cfg, const Patch& p, SphereFitWorkspace& w) : cfg_(cfg), p_(p), w_(w) {
        for (int i = 0; i < p_.cols; ++i) xrel_[static_cast<size_t>(i)] = (p_.x0 - 1 + i) - p_.xc;
        for (int j = 0; j < p_.lines; ++j) vrel_[static_cast<size_t>(j)] = 2.0 * (p_.j0 + j) + p_.parity - p_.vc;
        m_[0] = p_.colour.y_dn;
        m_[1] = p_.colour.cb_dn;
        m_[2] = p_.colour.cr_dn;
        const int nx = p_.x1 - p_.x0 + 1;
        for (int j = 0; j < p_.lines; ++j)
            for (int x = 0; x < nx; ++x) wy_[static_cast<size_t>(j * nx + x)] = 1.0 / w_.var_y[static_cast<size_t>(j * nx + x)];
        background_moments();
        n_obs_ = count_observations();
    }

    // Coverage and coverage × shading of the marker per model pixel at t; with kDeriv also their derivatives by
    // the shape parameters (centre x, v, radius, e1, e2) into the workspace. Coverage is a ramp one sub-cell wide
    // across the outline, whose derivative is exact; shading's radial slope is taken across the sub-cell near the
    // rim (where the pointwise slope of √(1 − ρ²/r²) is unbounded), analytically elsewhere.
    template <bool kDeriv>
    void raster(const Vec& t, double* cov, double* shade) const {
        const int n = p_.lines * p_.cols, ss = cfg_.supersample;
        const double x0 = t[kX0], v0 = t[kV0], r = std::max(t[kR], 0.25);
        const double e1 = std::clamp(t[kE1], -0.5, 0.5), e2 = std::clamp(t[kE2], -0.5, 0.5);
        const double h = 1.0 / ss, inv_h = ss, inv_r2 = 1.0 / (r * r), ap = cfg_.aperture_lines_px;
        const double amb = cfg_.shade_ambient, dif = cfg_.shade_diffuse;
        // Longest semi-axis r / √(1 − |e|), plus half a pixel's diagonal.
        const double reach = r / std::sqrt(1.0 - std::hypot(e1, e2)) + 0.25 + 0.5 * std::max(1.0, ap);
        // Sub-samples within r − h/2 (metric ρ) are wholly covered, beyond r + h/2 not at all.
        const double in2 = r > 0.5 * h ? (r - 0.5 * h) * (r - 0.5 * h) : 0.0, out2 = (r + 0.5 * h) * (r + 0.5 * h);
        auto q_of = [&](double rho) { return std::sqrt(std::max(0.0, 1.0 - rho * rho * inv_r2)); };
        double* dc = w_.dcov.data();
        double* ds = w_.dshade.data();
        for (int j = 0; j < p_.lines; ++j) {
            const double dv = 2.0 * (p_.j0 + j) + p_.parity - v0;
            for (int i = 0; i < p_.cols; ++i) {
                const int k = j * p_.cols + i;
                const double dx = (p_.x0 - 1 + i) - x0;
                double c = 0, sh = 0, gc[kShapePar] = {}, gs[kShapePar] = {};
                const bool near = dx * dx + dv * dv < reach * reach;
                if constexpr (kDeriv) w_.touch[k] = near;
                if (near) {
                    for (int sy = 0; sy < ss; ++sy) {
                        const double yy = dv + ap * (-0.5 + (sy + 0.5) * h);
                        for (int sxi = 0; sxi < ss; ++sxi) {
                            const double xx = dx - 0.5 + (sxi + 0.5) * h;
                            const double d2 = (1.0 + e1) * xx * xx + 2.0 * e2 * xx * yy + (1.0 - e1) * yy * yy;
                            if (d2 >= out2) continue;
                            const double q = std::sqrt(std::max(0.0, 1.0 - d2 * inv_r2));
                            const double shading = amb + dif * q;
                            if constexpr (!kDeriv) {
                                const double cs =
                                    d2 <= in2 ? 1.0 : std::clamp((r - std::sqrt(d2)) * inv_h + 0.5, 0.0, 1.0);
                                c += cs;
                                sh += cs * shading;
                                continue;
                            } else {
                                // ∂ρ²/∂(x0, v0, e1, e2); ∂ρ²/∂r = 0.
                                const double qx = -2.0 * ((1.0 + e1) * xx + e2 * yy);
                                const double qv = -2.0 * (e2 * xx + (1.0 - e1) * yy);
                                const double qe1 = xx * xx - yy * yy, qe2 = 2.0 * xx * yy;
                                if (d2 <= in2 && q > 0.5) {
                                    // Wholly covered, shading smooth: ∂q/∂ρ² = −1 / (2 r² q), no ρ needed.
                                    const double g = -0.5 * dif * inv_r2 / q;
                                    c += 1.0;
                                    sh += shading;
                                    gs[0] += g * qx;
                                    gs[1] += g * qv;
                                    gs[2] += dif * d2 * inv_r2 / (r * q);
                                    gs[3] += g * qe1;
                                    gs[4] += g * qe2;
                                    continue;
                                }
                                const double rho = std::sqrt(d2);
                                const double u = (r - rho) * inv_h + 0.5;
                                const bool ramp = u < 1.0;
                                const double cs = ramp ? u : 1.0;
                                c += cs;
                                sh += cs * shading;
                                // d/dρ and d/dr of coverage and of coverage × shading at this sub-sample.
                                const double dq_drho =
                                    q > 0.5 ? -rho * inv_r2 / q : (q_of(rho + 0.5 * h) - q_of(rho - 0.5 * h)) * inv_h;
                                const double dq_dr = -(rho / r) * dq_drho;
                                const double dcs = ramp ? inv_h : 0.0;  // = ∂cs/∂r = −∂cs/∂ρ
                                const double ds_drho = -dcs * shading + cs * dif * dq_drho;
                                gc[2] += dcs;
                                gs[2] += dcs * shading + cs * dif * dq_dr;
                                if (rho > 1e-12) {
                                    const double to_rho = 0.5 / rho;  // ∂ρ = ∂ρ² / (2ρ)
                                    const double dp[4] = {qx * to_rho, qv * to_rho, qe1 * to_rho, qe2 * to_rho};
                                    const int slot[4] = {0, 1, 3, 4};
                                    for (int m = 0; m < 4; ++m) {
                                        gc[slot[m]] -= dcs * dp[m];
                                        gs[slot[m]] += ds_drho * dp[m];
                                    }
                                }
                            }
                        }
                    }
                }
                const double a = h * h;
                cov[k] = c * a;
                shade[k] = sh * a;
                if constexpr (kDeriv)
                    for (int m = 0; m < kShapePar; ++m) {
                        dc[m * n + k] = gc[m] * a;
                        ds[m * n + k] = gs[m] * a;
                    }
            }
        }
    }

    // raster() with per-pixel analytic integrals (SphereFitModel::kAnalytic); the same outputs. A model without
    // shading (flat discs) renders its coverage alone.
    template <bool kDeriv>
    void raster_analytic(const Vec& t, double* cov, double* shade) const {
        if (cfg_.shade_diffuse == 0.0)
            raster_analytic<kDeriv, false>(t, cov, shade);
        else
            raster_analytic<kDeriv, true>(t, cov, shade);
    }
    template <bool kDeriv, bool kShade>
    void raster_analytic(const Vec& t, double* cov, double* shade) const {
        const int n = p_.lines * p_.cols;
        const double x0 = t[kX0], v0 = t[kV0], r = std::max(t[kR], 0.25);
        const double e1 = std::clamp(t[kE1], -0.5, 0.5), e2 = std::clamp(t[kE2], -0.5, 0.5);
        const double ap = cfg_.aperture_lines_px, amb = cfg_.shade_ambient, dif = cfg_.shade_diffuse;
        double* dc = w_.dcov.data();
        double* ds = w_.dshade.data();
        // Only the box the marker can reach is visited: ρ ≥ √(1 − |e|)·|d|, and pixel_integral() refuses
        // ρ > r + pixel_reach(ap). Everything else is zero: each pixel of the new box is written, zero where the
        // marker does not reach it, and of the previous render's box only what lies outside the new one is cleared
        // (consecutive renders' boxes nearly coincide; clearing all of it first was an eighth of the render).
        std::array<int, 4>& box = written_[kDeriv ? 0 : 1];
        const std::array<int, 4> old = box;
        auto clear = [&](int k) {
            cov[k] = shade[k] = 0.0;
            if constexpr (kDeriv) {
                w_.touch[k] = 0;
                for (int m = 0; m < kShapePar; ++m) dc[m * n + k] = ds[m * n + k] = 0.0;
            }
        };
        const double px_reach = pixel_reach(ap);
        const double reach = (r + px_reach) / std::sqrt(1.0 - std::hypot(e1, e2)) + 1e-9;
        box = {0, -1, 0, -1};
        if (std::isfinite(x0) && std::isfinite(v0) && std::isfinite(reach)) {
            // Clamped before the conversion: a wild trial point may lie far outside the patch.
            auto index = [](double v, int hi) {
                return static_cast<int>(std::clamp(v, -1.0, static_cast<double>(hi + 1)));
            };
            box[2] = std::max(0, index(std::floor(x0 - reach) - (p_.x0 - 1), p_.cols));
            box[3] = std::min(p_.cols - 1, index(std::ceil(x0 + reach) - (p_.x0 - 1), p_.cols));
            box[0] = std::max(0, index(std::floor((v0 - reach - p_.parity) / 2.0) - p_.j0, p_.lines));
            box[1] = std::min(p_.lines - 1, index(std::ceil((v0 + reach - p_.parity) / 2.0) - p_.j0, p_.lines));
        }  // else a diverged trial: nothing
        const int j_lo = box[0], j_hi = box[1], i_lo = box[2], i_hi = box[3];
        for (int j = old[0]; j <= old[1]; ++j) {
            if (j < j_lo || j > j_hi || i_lo > i_hi) {
                for (int i = old[2]; i <= old[3]; ++i) clear(j * p_.cols + i);
                continue;
            }
            for (int i = old[2]; i <= std::min(old[3], i_lo - 1); ++i) clear(j * p_.cols + i);
            for (int i = std::max(old[2], i_hi + 1); i <= old[3]; ++i) clear(j * p_.cols + i);
        }
        PixelIntegral pi;
        for (int j = j_lo; j <= j_hi; ++j) {
            const double dv = 2.0 * (p_.j0 + j) + p_.parity - v0;
            for (int i = i_lo; i <= i_hi; ++i) {
                const int k = j * p_.cols + i;
                const double dx = (p_.x0 - 1 + i) - x0;
                if (!pixel_integral<kDeriv, kShade>(dx, dv, r, e1, e2, ap, pi, px_reach)) {
                    clear(k);
                    continue;
                }
                cov[k] = pi.cov;
                shade[k] = kShade ? amb * pi.cov + dif * pi.q : amb * pi.cov;
                if constexpr (kDeriv) {
                    w_.touch[k] = 1;
                    if (pi.inside) {
                        for (int m = 0; m < kShapePar; ++m) {
                            dc[m * n + k] = 0.0;
                            ds[m * n + k] = dif * pi.dq_dp[m];
                        }
                    } else {
                        // ∂/∂r of c(ρ; r) = [ρ < r] is −∂/∂ρ; q(ρ; r) = φ(ρ/r) gives ∂q/∂r = −(ρ/r)·∂q/∂ρ.
                        const double dsh = kShade ? amb * pi.dcov + dif * pi.dq : amb * pi.dcov;
                        for (int m = 0; m < kShapePar; ++m) {
                            dc[m * n + k] = pi.dcov * pi.drho[m];
                            ds[m * n + k] = dsh * pi.drho[m];
                        }
                        if constexpr (!kShade) {
                            dc[2 * n + k] = -pi.dcov;
                            ds[2 * n + k] = -amb * pi.dcov;
                            continue;
                        }
                        const double rho_r = std::sqrt(std::max(0.0, dx * dx * (1.0 + e1) + 2.0 * e2 * dx * dv +
                                                                       dv * dv * (1.0 - e1))) / r;
                        dc[2 * n + k] = -pi.dcov;
                        ds[2 * n + k] = -amb * pi.dcov - dif * rho_r * pi.dq;
                    }
                }
            }
        }
    }

    // Model value of every model pixel and channel at t, from a render (cov, shade) of t's sphere.
    void model(const Vec& t, const double* cov, const double* shade, double* val) const {
        const int n = p_.lines * p_.cols;
        outline_weights(t);
        for (int ch = 0; ch < 3; ++ch) {
            const double b0 = t[kB0 + 3 * ch], bx = t[kB0 + 3 * ch + 1], bv = t[kB0 + 3 * ch + 2];
            const double beyond = p_.outline ? t[kB2 + ch] : 0.0, am = t[kA] * m_[ch];
            const double limb = p_.outline ? t[kG + ch] : 0.0;
            double* out = val + ch * n;
            if (!p_.outline) {  // the same values without the outline's terms (weight 1, no limb, nothing beyond)
                for (int j = 0; j < p_.lines; ++j) {
                    for (int i = 0; i < p_.cols; ++i) {
                        const int k = j * p_.cols + i;
                        const double bg = b0 + bx * xrel_[static_cast<size_t>(i)] + bv * vrel_[static_cast<size_t>(j)];
                        out[k] = kOffset[ch] + am * shade[k] + (1.0 - cov[k]) * (bg - kOffset[ch]);
                    }
                }
                continue;
            }
            for (int j = 0; j < p_.lines; ++j)
                for (int i = 0; i < p_.cols; ++i) {
                    const int k = j * p_.cols + i;
                    const double inside = b0 + bx * xrel_[static_cast<size_t>(i)] + bv * vrel_[static_cast<size_t>(j)] +
                                          limb * w_.edge_p[k];
                    const double we = w_.edge_w[k];
                    const double bg = we * inside + (1.0 - we) * beyond;
                    out[k] = kOffset[ch] + am * shade[k] + (1.0 - cov[k]) * (bg - kOffset[ch]);
                }
        }
    }

    // Σ (r/σ)² of the observations against model values `val`.
    double chi2(const double* val) const {
        const int nx = p_.x1 - p_.x0 + 1;
        const double wc = 1.0 / var_c();
        double sum = 0;
        for (int j = 0; j < p_.lines; ++j) {
            const double* vy = val + j * p_.cols;
            for (int x = 0; x < nx; ++x) {
                const int o = j * nx + x;
                const double r = w_.obs_y[o] - vy[x + 1];
                sum += w_.keep_y[o] * r * r * wy_[static_cast<size_t>(o)];
            }
            int s = 0;
            for (int x = p_.x0 + (p_.x0 & 1); x <= p_.x1; x += 2, ++s) {
                const int i = x - p_.x0 + 1, o = j * nx + s;
                for (int ch = 1; ch <= 2; ++ch) {
                    if (!(ch == 1 ? w_.keep_cb[o] : w_.keep_cr[o])) continue;
                    const double r = (ch == 1 ? w_.obs_cb[o] : w_.obs_cr[o]) - chroma_at(val, ch, j, i);
                    sum += r * r * wc;
                }
            }
        }
        return sum;
    }

    // Σ (r/σ)² at t (renders into the workspace's trial arrays).
    double cost(const Vec& t) {
        const int n = SphereFitWorkspace::kPx;
        double* cov = w_.trial.data();
        double* shade = cov + n;
        if (cfg_.model == SphereFitModel::kAnalytic)
            raster_analytic<false>(t, cov, shade);
        else
            raster<false>(t, cov, shade);
        model(t, cov, shade, w_.val.data());
        return chi2(w_.val.data());
    }

    // JᵀWJ (lower triangle) and JᵀWr at t, from the base render and derivatives in the workspace (linearise());
    // returns Σ (r/σ)² at t.
    double normal_equations(const Vec& t, Mat& a, Vec& g) const {
        if (p_.chain || p_.hchain) return normal_equations_chain(t, a, g);
        if (p_.outline) return normal_equations_outline(t, a, g);
        return normal_equations_marker(t, a, g);
    }

    // Per channel (Y, Cb, Cr), moments of the kept observations over the background's design (1, x, v):
    // Σw, Σwx, Σwv, Σwx², Σwxv, Σwv², Σw·o, Σw·o·x, Σw·o·v, Σw·o². Fixed for a patch and its kept set: the
    // observations the marker does not reach enter the normal equations through them (all kept minus those
    // reached), so that a linearisation costs only the marker's pixels.
    void background_moments() {
        const int nx = p_.x1 - p_.x0 + 1;
        const double wc = 1.0 / var_c();
        for (auto& m : mom_) m.fill(0.0);
        // Per line, the sums over x (Σw, Σwx, Σwx², Σwo, Σwox, Σwo²); v enters once per line.
        auto add_line = [](std::array<double, 10>& m, const double l[6], double v) {
            m[0] += l[0];
            m[1] += l[1];
            m[2] += l[0] * v;
            m[3] += l[2];
            m[4] += l[1] * v;
            m[5] += l[0] * v * v;
            m[6] += l[3];
            m[7] += l[4];
            m[8] += l[3] * v;
            m[9] += l[5];
        };
        for (int j = 0; j < p_.lines; ++j) {
            const double vj = vrel_[static_cast<size_t>(j)];
            double ly[6], lcb[6], lcr[6];  // set below from the lanes' sums
            const uint8_t* keep_y = w_.keep_y.data() + j * nx;
            const double* obs_y = w_.obs_y.data() + j * nx;
            const double* wy = wy_.data() + j * nx;
            const double* xr = xrel_.data() + 1;
            // Σw, Σwx, Σwx², Σwo, Σwox, Σwo² of one observation (double) or of two in the lanes of a V2.
            auto accumulate = [](auto* l, auto w, auto xx, auto ob) {
                const auto wx = w * xx, wo = w * ob;
                l[0] += w;
                l[1] += wx;
                l[2] += wx * xx;
                l[3] += wo;
                l[4] += wo * xx;
                l[5] += wo * ob;
            };
            // Two columns per step in the two lanes of a vector (independent sums, added at the end of the line).
            V2 acc[6] = {};
            int x = 0;
            for (; x + 1 < nx; x += 2)
                accumulate(acc, V2{double(keep_y[x]), double(keep_y[x + 1])} * V2{wy[x], wy[x + 1]},
                           V2{xr[x], xr[x + 1]}, V2{obs_y[x], obs_y[x + 1]});
            for (int q = 0; q < 6; ++q) ly[q] = acc[q][0] + acc[q][1];
            for (; x < nx; ++x) accumulate(ly, keep_y[x] * wy[x], xr[x], obs_y[x]);
            // Chroma samples at even columns: sample s at model column i = x − x0 + 1.
            const int i0 = (p_.x0 & 1) + 1, ns = (p_.x1 - (p_.x0 + (p_.x0 & 1))) / 2 + 1;
            // Cb and Cr in the two lanes (the same columns, weights and σ).
            const uint8_t *kcb = w_.keep_cb.data() + j * nx, *kcr = w_.keep_cr.data() + j * nx;
            const double *ocb = w_.obs_cb.data() + j * nx, *ocr = w_.obs_cr.data() + j * nx;
            V2 acc_c[6] = {};
            for (int s = 0; s < ns; ++s) {
                const double xs = xrel_[static_cast<size_t>(i0 + 2 * s)];
                accumulate(acc_c, V2{double(kcb[s]), double(kcr[s])}, V2{xs, xs}, V2{ocb[s], ocr[s]});
            }
            for (int q = 0; q < 6; ++q) {  // the chroma's weight is one σ for all
                lcb[q] = acc_c[q][0] * wc;
                lcr[q] = acc_c[q][1] * wc;
            }
            add_line(mom_[0], ly, vj);
            add_line(mom_[1], lcb, vj);
            add_line(mom_[2], lcr, vj);
        }
    }

    // normal_equations without an outline: only the observations the marker reaches (touch) are visited, their
    // model values formed in place; the rest enter through the background moments.
    double normal_equations_marker(const Vec& t, Mat& a, Vec& g) const {
        constexpr int nr = kRow - 5;  // shape, amplitude, the channel's background (the outline's 5 are last)
        constexpr int ns = nr + 1;    // row stride: even, so that the rank-one updates go in pairs (SIMD)
        const int n = p_.lines * p_.cols, nx = p_.x1 - p_.x0 + 1;
        const double wc = 1.0 / var_c();
        const double* cov = w_.cov.data();
        const double* shade = w_.shade.data();
        const double* dc = w_.dcov.data();
        const double* ds = w_.dshade.data();
        const uint8_t* touch = w_.touch.data();
        double acc[3][nr * ns] = {}, acc_g[3][nr] = {}, chi2 = 0;
        std::array<double, 10> reached[3] = {};  // background moments of the visited observations
        double am[3], b0[3], bx[3], bv[3];
        for (int ch = 0; ch < 3; ++ch) {
            am[ch] = t[kA] * m_[ch];
            b0[ch] = t[kB0 + 3 * ch];
            bx[ch] = t[kB0 + 3 * ch + 1];
            bv[ch] = t[kB0 + 3 * ch + 2];
        }
        // Model value and compact derivative row of model pixel k (column i) in channel ch.
        auto pixel = [&](int ch, int i, int k, double vj, double* row) {
            const double x = xrel_[static_cast<size_t>(i)];
            const double under = b0[ch] + bx[ch] * x + bv[ch] * vj - kOffset[ch], open = 1.0 - cov[k];
            for (int q = 0; q < kShapePar; ++q) row[q] = am[ch] * ds[q * n + k] - dc[q * n + k] * under;
            if (!cfg_.fit_ellipse) row[3] = row[4] = 0.0;
            row[5] = shade[k] * m_[ch];
            row[6] = open;
            row[7] = open * x;
            row[8] = open * vj;
            row[9] = 0.0;
            return kOffset[ch] + am[ch] * shade[k] + open * under;
        };
        // Rows of an observation the marker wholly covers end at the amplitude (q1 = 6): the background's
        // entries are multiplied by the open fraction, 0. Without shading such a row's shape entries are 0 too
        // (q0 = 5): only the amplitude's are added.
        auto add = [&]<int q0, int q1>(std::integer_sequence<int, q0, q1>, int ch, const double* row, double r,
                                       double wgt, double x, double vj, double o) {
            double* m = acc[ch];
            double* gg = acc_g[ch];
            chi2 += wgt * r * r;
            for (int q = q0; q < q1; ++q) {
                const double wq = wgt * row[q];
                gg[q] += wq * r;
                // The lower triangle rounded up to whole pairs (row[nr] is 0).
                for (int u = q0 & ~1; u <= q; u += 2) {
                    m[q * ns + u] += wq * row[u];
                    m[q * ns + u + 1] += wq * row[u + 1];
                }
            }
            std::array<double, 10>& mo = reached[ch];
            mo[0] += wgt;
            mo[1] += wgt * x;
            mo[2] += wgt * vj;
            mo[3] += wgt * x * x;
            mo[4] += wgt * x * vj;
            mo[5] += wgt * vj * vj;
            mo[6] += wgt * o;
            mo[7] += wgt * o * x;
            mo[8] += wgt * o * vj;
            mo[9] += wgt * o * o;
        };
        constexpr std::integer_sequence<int, 0, nr> kFull;
        constexpr std::integer_sequence<int, 0, 6> kCovered;
        constexpr std::integer_sequence<int, 5, 6> kCoveredFlat;
        // A flat model's wholly covered pixel has no shape derivatives: coverage 1 exactly and no shading.
        const bool flat = cfg_.shade_diffuse == 0.0 && cfg_.model == SphereFitModel::kAnalytic;
        double row[ns], crow[2][SphereFitWorkspace::kCols][ns], cval[2][SphereFitWorkspace::kCols];
        for (int j = 0; j < p_.lines; ++j) {
            const double vj = vrel_[static_cast<size_t>(j)];
            const uint8_t* tl = touch + j * p_.cols;
            for (int x = 0; x < nx; ++x) {
                const int o = j * nx + x, i = x + 1;
                if (!tl[i] || !w_.keep_y[o]) continue;
                const double mod = pixel(0, i, j * p_.cols + i, vj, row);
                if (cov[j * p_.cols + i] == 1.0 && flat)
                    add(kCoveredFlat, 0, row, w_.obs_y[o] - mod, wy_[static_cast<size_t>(o)], xrel_[static_cast<size_t>(i)],
                        vj, w_.obs_y[o]);
                else if (cov[j * p_.cols + i] == 1.0)
                    add(kCovered, 0, row, w_.obs_y[o] - mod, wy_[static_cast<size_t>(o)], xrel_[static_cast<size_t>(i)], vj,
                        w_.obs_y[o]);
                else
                    add(kFull, 0, row, w_.obs_y[o] - mod, wy_[static_cast<size_t>(o)], xrel_[static_cast<size_t>(i)], vj,
                        w_.obs_y[o]);
            }
            int s = 0, have = -1;  // model pixels up to `have` hold their chroma rows in crow
            for (int x = p_.x0 + (p_.x0 & 1); x <= p_.x1; x += 2, ++s) {
                const int i = x - p_.x0 + 1, o = j * nx + s;
                if (!tl[i - 1] && !tl[i] && !tl[i + 1]) continue;
                const bool keep[2] = {w_.keep_cb[o] != 0, w_.keep_cr[o] != 0};
                if (!keep[0] && !keep[1]) continue;
                for (int m = std::max(i - 1, have + 1); m <= i + 1; ++m) {
                    cval[0][m] = pixel(1, m, j * p_.cols + m, vj, crow[0][m]);
                    cval[1][m] = pixel(2, m, j * p_.cols + m, vj, crow[1][m]);
                    have = m;
                }
                const int k = j * p_.cols + i;
                const bool covered = cov[k - 1] == 1.0 && cov[k] == 1.0 && cov[k + 1] == 1.0;
                for (int c = 0; c < 2; ++c) {
                    if (!keep[c]) continue;
                    const double* q0 = crow[c][i - 1];
                    const double* q1 = crow[c][i];
                    const double* q2 = crow[c][i + 1];
                    for (int q = 0; q < ns; ++q) row[q] = 0.25 * (q0[q] + q2[q]) + 0.5 * q1[q];
                    const double mod = 0.25 * (cval[c][i - 1] + cval[c][i + 1]) + 0.5 * cval[c][i];
                    const double obs = c == 0 ? w_.obs_cb[o] : w_.obs_cr[o];
                    if (covered && flat)
                        add(kCoveredFlat, 1 + c, row, obs - mod, wc, xrel_[static_cast<size_t>(i)], vj, obs);
                    else if (covered)
                        add(kCovered, 1 + c, row, obs - mod, wc, xrel_[static_cast<size_t>(i)], vj, obs);
                    else
                        add(kFull, 1 + c, row, obs - mod, wc, xrel_[static_cast<size_t>(i)], vj, obs);
                }
            }
        }
        // The observations the marker does not reach: model = background b·β exactly, derivatives (1, x, v) by β.
        for (int ch = 0; ch < 3; ++ch) {
            double mo[10];
            for (int q = 0; q < 10; ++q) mo[q] = mom_[static_cast<size_t>(ch)][static_cast<size_t>(q)] - reached[ch][static_cast<size_t>(q)];
            const double mm[3][3] = {{mo[0], mo[1], mo[2]}, {mo[1], mo[3], mo[4]}, {mo[2], mo[4], mo[5]}};
            const double bo[3] = {mo[6], mo[7], mo[8]}, be[3] = {b0[ch], bx[ch], bv[ch]};
            double quad = 0, lin = 0;
            for (int q = 0; q < 3; ++q) {
                double mb = 0;
                for (int u = 0; u < 3; ++u) mb += mm[q][u] * be[u];
                acc_g[ch][6 + q] += bo[q] - mb;
                for (int u = 0; u <= q; ++u) acc[ch][(6 + q) * ns + 6 + u] += mm[q][u];
                quad += be[q] * mb;
                lin += be[q] * bo[q];
            }
            chi2 += std::max(0.0, mo[9] - 2.0 * lin + quad);
        }
        scatter(acc[0], sizeof acc[0] / sizeof(double), ns, acc_g[0], kRow - 5, nr, a, g);
        return chi2;
    }

    // normal_equations with an outline: every observation depends on the outline's parameters; those the marker
    // does not reach have no shape or amplitude derivatives, so their rank-one update skips the first 6.
    double normal_equations_outline(const Vec& t, Mat& a, Vec& g) const {
        constexpr int nr = kRow;
        const int n = p_.lines * p_.cols, nx = p_.x1 - p_.x0 + 1;
        double* val = w_.val.data();
        model(t, w_.cov.data(), w_.shade.data(), val);
        const double wc = 1.0 / var_c();
        // Per channel, the normal equations over the row's compact parameters; scattered at the end.
        double acc[3][kRow * (kRow + 1)] = {}, acc_g[3][kRow] = {}, chi2 = 0;
        // Rows over compact parameters q0 ≤ q < q1: an observation the marker does not reach has no shape or
        // amplitude entries (q0 = 6), one it wholly covers none past the amplitude (q1 = 6: all are multiplied by
        // the open fraction, 0).
        auto add = [&]<int q0, int q1>(std::integral_constant<int, q0>, std::integral_constant<int, q1>, int ch,
                                       const double* row, double r, double wgt) {
            double* am = acc[ch];
            double* gg = acc_g[ch];
            chi2 += wgt * r * r;
            for (int q = q0; q < q1; ++q) {
                const double wq = wgt * row[q];
                gg[q] += wq * r;
                // The lower triangle rounded up to whole pairs (SIMD); row[q + 1] for q = nr − 1 is row[kRow], 0.
                for (int u = q0; u <= q; u += 2) {
                    am[q * kRow + u] += wq * row[u];
                    am[q * kRow + u + 1] += wq * row[u + 1];
                }
            }
        };
        // An observation beyond the outline that the marker does not reach depends only on the level beyond it
        // (compact 11), with derivative 1.
        auto add_beyond = [&](int ch, double r, double wgt) {
            chi2 += wgt * r * r;
            acc_g[ch][11] += wgt * r;
            acc[ch][11 * kRow + 11] += wgt;
        };
        const double* edge_w = w_.edge_w.data();
        constexpr std::integral_constant<int, 0> kFromShape;
        constexpr std::integral_constant<int, 6> kFromBackground, kToAmplitude;
        constexpr std::integral_constant<int, nr> kToOutline;
        const double* cov = w_.cov.data();
        const uint8_t* touch = w_.touch.data();
        // An observation inside the outline and off its ramp that the marker does not reach (most of them): its
        // row is D_ch·u with u = (1, x, v, P′·∂dist/∂φ, P′, P′·∂dist/∂κ, P) the same in every channel and
        // D_ch = diag(1, 1, 1, −G, G, −G, 1), G the channel's limb gain (compact parameters 6–10, 12, 13; 11 is 0).
        // Their outer products are summed once for the luma and once for both chroma channels (a sample's Cb and
        // Cr share u), and scaled by D at the end.
        constexpr int kU = 7;
        constexpr int kUIdx[kU] = {6, 7, 8, 9, 10, 12, 13};
        double uu[2][kU * kU] = {}, ug[3][kU] = {};  // Σ w·u·uᵀ (lower; luma, chroma), Σ w·r·u per channel
        auto shared_u = [&](int i, int j, double* u) {
            const int k = j * p_.cols + i;
            const double dp = w_.edge_dp[k];
            u[0] = 1.0;
            u[1] = xrel_[static_cast<size_t>(i)];
            u[2] = vrel_[static_cast<size_t>(j)];
            u[3] = dp * w_.edge_dphi[k];
            u[4] = dp;
            u[5] = dp * w_.edge_dkappa[k];
            u[6] = w_.edge_p[k];
        };
        auto add_shared = [&](double* m, const double* u, double wgt) {
            for (int q = 0; q < kU; ++q) {
                const double wq = wgt * u[q];
                for (int v = 0; v <= q; ++v) m[q * kU + v] += wq * u[v];
            }
        };
        double row[kRow + 1] = {};
        double crow[2][SphereFitWorkspace::kCols][kRow];  // one line's chroma pixel rows
        for (int j = 0; j < p_.lines; ++j) {
            for (int x = 0; x < nx; ++x) {
                const int o = j * nx + x, k = j * p_.cols + x + 1;
                if (!w_.keep_y[o]) continue;
                if (!touch[k] && edge_w[k] == 0.0) {
                    add_beyond(0, w_.obs_y[o] - val[k], wy_[static_cast<size_t>(o)]);
                    continue;
                }
                if (!touch[k] && edge_w[k] == 1.0) {
                    double u[kU];
                    shared_u(x + 1, j, u);
                    const double r = w_.obs_y[o] - val[k], wgt = wy_[static_cast<size_t>(o)];
                    chi2 += wgt * r * r;
                    add_shared(uu[0], u, wgt);
                    for (int q = 0; q < kU; ++q) ug[0][q] += wgt * r * u[q];
                    continue;
                }
                pixel_row(t, 0, x + 1, j, row);
                if (!touch[k])
                    add(kFromBackground, kToOutline, 0, row, w_.obs_y[o] - val[k], wy_[static_cast<size_t>(o)]);
                else if (cov[k] == 1.0)
                    add(kFromShape, kToAmplitude, 0, row, w_.obs_y[o] - val[k], wy_[static_cast<size_t>(o)]);
                else
                    add(kFromShape, kToOutline, 0, row, w_.obs_y[o] - val[k], wy_[static_cast<size_t>(o)]);
            }
            // Chroma: each model pixel's row is computed once per line and channel (a sample filters three
            // pixels, and neighbouring samples share one).
            int s = 0, have = -1;  // model pixels up to `have` hold their rows in crow
            for (int x = p_.x0 + (p_.x0 & 1); x <= p_.x1; x += 2, ++s) {
                const int i = x - p_.x0 + 1, o = j * nx + s, k = j * p_.cols + i;
                const bool reached = touch[k - 1] || touch[k] || touch[k + 1];
                const bool keep[2] = {w_.keep_cb[o] != 0, w_.keep_cr[o] != 0};
                if (!keep[0] && !keep[1]) continue;
                if (!reached && edge_w[k - 1] == 0.0 && edge_w[k] == 0.0 && edge_w[k + 1] == 0.0) {
                    for (int ch = 1; ch <= 2; ++ch)
                        if (keep[ch - 1])
                            add_beyond(ch, (ch == 1 ? w_.obs_cb[o] : w_.obs_cr[o]) - filtered(val + ch * n + j * p_.cols, i),
                                       wc);
                    continue;
                }
                if (!reached && keep[0] && keep[1] && edge_w[k - 1] == 1.0 && edge_w[k] == 1.0 && edge_w[k + 1] == 1.0) {
                    double u0[kU], u1[kU], u2[kU], u[kU];
                    shared_u(i - 1, j, u0);
                    shared_u(i, j, u1);
                    shared_u(i + 1, j, u2);
                    for (int q = 0; q < kU; ++q) u[q] = 0.25 * (u0[q] + u2[q]) + 0.5 * u1[q];
                    add_shared(uu[1], u, wc);
                    for (int ch = 1; ch <= 2; ++ch) {
                        const double r = (ch == 1 ? w_.obs_cb[o] : w_.obs_cr[o]) - filtered(val + ch * n + j * p_.cols, i);
                        chi2 += wc * r * r;
                        for (int q = 0; q < kU; ++q) ug[ch][q] += wc * r * u[q];
                    }
                    continue;
                }
                for (int m = std::max(i - 1, have + 1); m <= i + 1; ++m) {
                    pixel_row(t, 1, m, j, crow[0][m]);
                    pixel_row(t, 2, m, j, crow[1][m]);
                    have = m;
                }
                const bool covered = cov[k - 1] == 1.0 && cov[k] == 1.0 && cov[k + 1] == 1.0;
                for (int ch = 1; ch <= 2; ++ch) {
                    if (!keep[ch - 1]) continue;
                    const double mod = filtered(val + ch * n + j * p_.cols, i);
                    const double res = (ch == 1 ? w_.obs_cb[o] : w_.obs_cr[o]) - mod;
                    const double* q0 = crow[ch - 1][i - 1];
                    const double* q1 = crow[ch - 1][i];
                    const double* q2 = crow[ch - 1][i + 1];
                    for (int q = 0; q < nr; ++q) row[q] = 0.25 * (q0[q] + q2[q]) + 0.5 * q1[q];
                    if (!reached)
                        add(kFromBackground, kToOutline, ch, row, res, wc);
                    else if (covered)
                        add(kFromShape, kToAmplitude, ch, row, res, wc);
                    else
                        add(kFromShape, kToOutline, ch, row, res, wc);
                }
            }
        }
        for (int ch = 0; ch < 3; ++ch) {
            const double gain = t[kG + ch], d[kU] = {1.0, 1.0, 1.0, -gain, gain, -gain, 1.0};
            const double* m = uu[ch == 0 ? 0 : 1];
            for (int q = 0; q < kU; ++q) {
                acc_g[ch][kUIdx[q]] += d[q] * ug[ch][q];
                for (int v = 0; v <= q; ++v) acc[ch][kUIdx[q] * kRow + kUIdx[v]] += d[q] * d[v] * m[q * kU + v];
            }
        }
        scatter(acc[0], sizeof acc[0] / sizeof(double), kRow, acc_g[0], kRow, nr, a, g);
        return chi2;
    }

    // The normal equations from the per-channel ones over each channel's compact row of parameters (row_params):
    // `acc` holds 3 channels `acc_size` apart, lower triangles with row stride `stride`; `acc_g` 3 channels
    // `g_size` apart; `nr` rows each. The lower triangle is mirrored.
    void scatter(const double* acc, size_t acc_size, int stride, const double* acc_g, int g_size, int nr, Mat& a,
                 Vec& g) const {
        a.fill(0.0);
        g.fill(0.0);
        for (int ch = 0; ch < 3; ++ch) {
            int idx[kRow];
            row_params(ch, idx);
            const double* am = acc + size_t(ch) * acc_size;
            const double* gm = acc_g + ch * g_size;
            for (int q = 0; q < nr; ++q) {
                g[static_cast<size_t>(idx[q])] += gm[q];
                for (int u = 0; u <= q; ++u) a[static_cast<size_t>(idx[q] * kMaxPar + idx[u])] += am[q * stride + u];
            }
        }
        for (int q = 0; q < np(); ++q)
            for (int u = q + 1; u < np(); ++u)
                a[static_cast<size_t>(q * kMaxPar + u)] = a[static_cast<size_t>(u * kMaxPar + q)];
    }

    // Base render with its derivatives by the shape parameters, in one pass.
    void linearise(const Vec& t) {
        lin_t_ = t;
        if (cfg_.model == SphereFitModel::kAnalytic)
            raster_analytic<true>(t, w_.cov.data(), w_.shade.data());
        else
            raster<true>(t, w_.cov.data(), w_.shade.data());
    }

    // intensity_centroid_analytic() at t from the last linearisation's render (at lin_t_), to first order in
    // t − lin_t_ through its derivatives: the fit ends at or one small unverified step from that point, so no render
    // is needed. False where that render is not at hand, is cut by the patch, or is too far from t.
    bool centroid_from_render(const Vec& t, double& cx, double& cy) const {
        if (cfg_.model != SphereFitModel::kAnalytic) return false;
        double d[kShapePar];
        for (int m = 0; m < kShapePar; ++m) {
            d[m] = t[m] - lin_t_[m];
            if (!(std::fabs(d[m]) < 1e-2)) return false;  // an unverified last step (small_step): ≤ 3e-4 px off
        }
        const int n = p_.lines * p_.cols;
        const std::array<int, 4>& box = written_[0];
        const double* shade = w_.shade.data();
        const double* ds = w_.dshade.data();
        // The marker is convex: where the render reaches the patch's first or last line or column and that holds
        // nothing, nothing lies beyond it either.
        for (int j : {0, p_.lines - 1})
            if (j >= box[0] && j <= box[1])
                for (int i = box[2]; i <= box[3]; ++i)
                    if (shade[j * p_.cols + i] != 0.0) return false;
        for (int i : {0, p_.cols - 1})
            if (i >= box[2] && i <= box[3])
                for (int j = box[0]; j <= box[1]; ++j)
                    if (shade[j * p_.cols + i] != 0.0) return false;
        double si = 0, sx = 0, sv = 0;
        for (int j = box[0]; j <= box[1]; ++j) {
            // Two columns per step in the lanes of a vector.
            V2 line2 = {}, line_x2 = {};
            int i = box[2];
            for (; i + 1 <= box[3]; i += 2) {
                const int k = j * p_.cols + i;
                V2 in = {shade[k], shade[k + 1]};
                for (int m = 0; m < kShapePar; ++m) in += d[m] * V2{ds[m * n + k], ds[m * n + k + 1]};
                line2 += in;
                line_x2 += in * V2{double(p_.x0 - 1 + i), double(p_.x0 + i)};
            }
            double line = line2[0] + line2[1], line_x = line_x2[0] + line_x2[1];
            for (; i <= box[3]; ++i) {
                const int k = j * p_.cols + i;
                double in = shade[k];
                for (int m = 0; m < kShapePar; ++m) in += d[m] * ds[m * n + k];
                line += in;
                line_x += in * (p_.x0 - 1 + i);
            }
            si += line;
            sx += line_x;
            sv += line * (2.0 * (p_.j0 + j) + p_.parity);
        }
        if (!(si > 0)) return false;
        cx = sx / si;
        cy = 0.5 * (sv / si - p_.parity);
        return std::isfinite(cx) && std::isfinite(cy);
    }

    int np() const { return p_.outline ? kMaxPar : kPhi; }
    double var_c() const { return p_.chroma_sigma_dn * p_.chroma_sigma_dn + 1.0 / 12.0; }
    // Observations still in the fit (counted when the kept set changes).
    int observations() const { return n_obs_; }
    int count_observations() const {
        const int nx = p_.x1 - p_.x0 + 1, nc = (p_.x1 - (p_.x0 + (p_.x0 & 1))) / 2 + 1;
        int n = 0;
        for (int j = 0; j < p_.lines; ++j) {
            for (int x = 0; x < nx; ++x) n += w_.keep_y[j * nx + x];
            for (int c = 0; c < nc; ++c) n += w_.keep_cb[j * nx + c] + w_.keep_cr[j * nx + c];
        }
        return n;
    }

    // Where the left-out observations lie about the fitted centre: |mean of e^{iθ}| (one-sided: near 1) and
    // |mean of e^{2iθ}| (on one line through the centre: near 1), over those outside the fitted disc.
    void outlier_spread(const Vec& t, double& r1, double& r2) const {
        const int nx = p_.x1 - p_.x0 + 1;
        double c1 = 0, s1 = 0, c2 = 0, s2 = 0;
        int n = 0;
        auto add = [&](int x, int j) {
            const double dx = (p_.x0 + x) - t[kX0], dv = 2.0 * (p_.j0 + j) + p_.parity - t[kV0];
            const double d = std::hypot(dx, dv);
            if (d < t[kR] + 0.5) return;
            const double c = dx / d, s = dv / d;
            c1 += c;
            s1 += s;
            c2 += c * c - s * s;
            s2 += 2 * c * s;
            ++n;
        };
        for (int j = 0; j < p_.lines; ++j) {
            for (int x = 0; x < nx; ++x)
                if (!w_.keep_y[j * nx + x] && !w_.hidden_y[j * nx + x]) add(x, j);
            int c = 0;
            for (int x = p_.x0 + (p_.x0 & 1); x <= p_.x1; x += 2, ++c)
                if (!w_.hidden_c[j * nx + c])
                    for (int rep = 0; rep < 2 - w_.keep_cb[j * nx + c] - w_.keep_cr[j * nx + c]; ++rep) add(x - p_.x0, j);
        }
        r1 = n ? std::hypot(c1, s1) / n : 1.0;
        r2 = n ? std::hypot(c2, s2) / n : 0.0;
    }

    // Leaves out of the fit the observations the shaft's image touches at t (a luma pixel's box widened by m, a
    // chroma sample's three filtered columns widened by m), and only those (earlier outliers come back); returns
    // how many luma pixels; `changed`: the set differs from the one before.
    int mask_hidden(const Vec& t, const MarkerHint& predicted, double m, bool& changed) {
        const OutlineNorm nm(predicted, t[kR], t[kE1], t[kE2]);
        const MarkerHint hint = hint_at(predicted, nm, t[kX0], t[kV0]);
        const int nx = p_.x1 - p_.x0 + 1;
        const double hv = 0.5 * cfg_.aperture_lines_px + m;
        int covered = 0;
        changed = false;
        uint8_t touched[kMaxCoverCols];  // columns x0 − 1 … x1 + 1: a chroma sample spans three
        // Per line and chroma sample: the occluder reaches its three filtered columns (the chain spreads it down
        // the lines: a chroma observation is hidden where any line it takes is).
        uint8_t ctouch[SphereFitWorkspace::kLines][SphereFitWorkspace::kSamples];
        const int ns = (p_.x1 - (p_.x0 + (p_.x0 & 1))) / 2 + 1;
        for (int j = 0; j < p_.lines; ++j) {
            const double dv = 2.0 * (p_.j0 + j) + p_.parity - t[kV0];
            line_cover(hint, nm, p_.x0 - 1 - t[kX0], dv, nx + 2, m, hv, touched);
            for (int x = 0; x < nx; ++x) {
                const int o = j * nx + x;
                const uint8_t c = touched[x + 1] != 0;
                const uint8_t h = c | w_.foreign_y[o];
                changed |= h != w_.hidden_y[o];
                w_.hidden_y[o] = h;
                w_.keep_y[o] = !h;
                covered += c;
            }
            int sidx = 0;
            for (int x = p_.x0 + (p_.x0 & 1); x <= p_.x1; x += 2, ++sidx) {
                const int i = x - p_.x0 + 1;
                ctouch[j][sidx] = (touched[i - 1] | touched[i] | touched[i + 1]) != 0;
            }
        }
        for (int j = 0; j < p_.lines; ++j)
            for (int sidx = 0; sidx < ns; ++sidx) {
                const int o = j * nx + sidx;
                const uint8_t c = w_.foreign_c[o] || chain_reaches(cfg_, p_, ctouch, ns, j, sidx);
                changed |= c != w_.hidden_c[o];
                w_.hidden_c[o] = c;
                w_.keep_cb[o] = w_.keep_cr[o] = !c;
            }
        background_moments();
        n_obs_ = count_observations();
        return covered;
    }

    // Leaves out of the fit exactly the observations whose residual at t exceeds k σ; returns how many.
    int drop_outliers(const Vec& t, double k) {
        cost(t);
        const int nx = p_.x1 - p_.x0 + 1;
        const double* val = w_.val.data();
        const double k2 = k * k, wc = 1.0 / var_c();
        int dropped = 0;
        for (int j = 0; j < p_.lines; ++j) {
            for (int x = 0; x < nx; ++x) {
                const int o = j * nx + x;
                const double r = w_.obs_y[o] - val[j * p_.cols + x + 1];
                w_.keep_y[o] = r * r * wy_[static_cast<size_t>(o)] <= k2 && !w_.hidden_y[o];
                dropped += !w_.keep_y[o];
            }
            int s = 0;
            for (int x = p_.x0 + (p_.x0 & 1); x <= p_.x1; x += 2, ++s) {
                const int i = x - p_.x0 + 1, o = j * nx + s;
                for (int ch = 1; ch <= 2; ++ch) {
                    uint8_t& keep = ch == 1 ? w_.keep_cb[o] : w_.keep_cr[o];
                    const double r = (ch == 1 ? w_.obs_cb[o] : w_.obs_cr[o]) - chroma_at(val, ch, j, i);
                    keep = r * r * wc <= k2 && !w_.hidden_c[o];
                    dropped += !keep;
                }
            }
        }
        background_moments();
        n_obs_ = count_observations();
        return dropped;
    }

private:
    // A model pixel's derivatives touch 14 parameters: the 5 of the marker's shape, amplitude, its channel's
    // background level and slopes, and (with an outline) the outline's angle, offset, its channel's level beyond
    // it, the curvature and its channel's limb gain. Increasing, so that a compact lower triangle scatters into the
    // lower triangle.
    static constexpr int kRow = 14;
    static void row_params(int ch, int* idx) {
        const int p[kRow] = {kX0, kV0, kR, kE1, kE2, kA, kB0 + 3 * ch, kB0 + 3 * ch + 1, kB0 + 3 * ch + 2,
                             kPhi, kD, kB2 + ch, kKappa, kG + ch};
        for (int q = 0; q < kRow; ++q) idx[q] = p[q];
    }

    // The camera's [1 2 1] co-sited chroma filter at model column i.
    static double filtered(const double* line, int i) { return 0.25 * (line[i - 1] + line[i + 1]) + 0.5 * line[i]; }

    // The chains' taps for an observation on model line j of channel ch (1 Cb, 2 Cr) over the lines, and for one at
    // chroma sample s of the patch over the samples; offsets −kChromaChainLines … kChromaChainLines; the identity
    // where the source has no such chain.
    const double* vtaps(int j, int ch) const { return chain_vtaps(cfg_, p_, j, ch); }
    const double* htaps(int s) const { return chain_htaps(cfg_, p_, s); }

    // The model's chroma observation at model line j, column i of channel ch from model values `val`: the camera's
    // filter, and with the chains the source's down the lines and across the columns.
    double chroma_at(const double* val, int ch, int j, int i) const {
        const int n = p_.lines * p_.cols;
        if (!p_.chain && !p_.hchain) return filtered(val + ch * n + j * p_.cols, i);
        constexpr int kL = kChromaChainLines;
        const double* tv = vtaps(j, ch);
        const double* th = htaps((i - 1 - (p_.x0 & 1)) / 2);
        double sum = 0;
        for (int dv = -kL; dv <= kL; ++dv) {
            if (tv[dv + kL] == 0.0) continue;
            const double* line = val + ch * n + std::clamp(j + dv, 0, p_.lines - 1) * p_.cols;
            for (int dh = -kL; dh <= kL; ++dh) {
                const double w = tv[dv + kL] * th[dh + kL];
                if (w != 0.0) sum += w * filtered(line, std::clamp(i + 2 * dh, 1, p_.cols - 2));
            }
        }
        return sum;
    }

    // normal_equations with the vertical chroma chain: every kept observation's full row (a chroma observation's
    // the chain's sum of its lines' [1 2 1] rows); no sparsity, for the few recorded sources that need it.
    double normal_equations_chain(const Vec& t, Mat& a, Vec& g) const {
        constexpr int R = kRow;
        static_assert(R == SphereFitWorkspace::kChainRow);
        const int n = p_.lines * p_.cols, nx = p_.x1 - p_.x0 + 1;
        const int nr = p_.outline ? kRow : kRow - 5;
        double* val = w_.val.data();
        model(t, w_.cov.data(), w_.shade.data(), val);
        const double wc = 1.0 / var_c();
        double acc[3][R * R] = {}, acc_g[3][R] = {}, chi2 = 0;
        auto add = [&](int ch, const double* row, double r, double wgt) {
            chi2 += wgt * r * r;
            for (int q = 0; q < nr; ++q) {
                const double wq = wgt * row[q];
                acc_g[ch][q] += wq * r;
                for (int u = 0; u <= q; ++u) acc[ch][q * R + u] += wq * row[u];
            }
        };
        double row[R + 1] = {};
        for (int j = 0; j < p_.lines; ++j)
            for (int x = 0; x < nx; ++x) {
                const int o = j * nx + x;
                if (!w_.keep_y[o]) continue;
                pixel_row(t, 0, x + 1, j, row);
                add(0, row, w_.obs_y[o] - val[j * p_.cols + x + 1], wy_[static_cast<size_t>(o)]);
            }
        // Each line's filtered rows and values per chroma sample, then the chain down the lines.
        const int ns = (p_.x1 - (p_.x0 + (p_.x0 & 1))) / 2 + 1, ls = ns * R;
        double* hrow = w_.chain_row.data();  // [channel][line][sample][R]
        double* hval = w_.chain_val.data();  // [channel][line][sample]
        double prow[SphereFitWorkspace::kCols][R + 1];
        for (int ch = 1; ch <= 2; ++ch)
            for (int j = 0; j < p_.lines; ++j) {
                const int i_first = (p_.x0 & 1) + 1;  // model column of the first sample
                for (int i = i_first - 1; i <= i_first + 2 * (ns - 1) + 1; ++i) pixel_row(t, ch, i, j, prow[i]);
                int s = 0;
                for (int x = p_.x0 + (p_.x0 & 1); x <= p_.x1; x += 2, ++s) {
                    const int i = x - p_.x0 + 1;
                    double* h = hrow + ((ch - 1) * p_.lines + j) * ls + s * R;
                    for (int q = 0; q < nr; ++q) h[q] = 0.25 * (prow[i - 1][q] + prow[i + 1][q]) + 0.5 * prow[i][q];
                    hval[((ch - 1) * p_.lines + j) * ns + s] = filtered(val + ch * n + j * p_.cols, i);
                }
            }
        constexpr int kL = kChromaChainLines;
        for (int ch = 1; ch <= 2; ++ch)
            for (int j = 0; j < p_.lines; ++j) {
                const double* tv = vtaps(j, ch);
                for (int s = 0; s < ns; ++s) {
                    const int o = j * nx + s;
                    if (!(ch == 1 ? w_.keep_cb[o] : w_.keep_cr[o])) continue;
                    const double* th = htaps(s);
                    double mod = 0;
                    for (int q = 0; q < nr; ++q) row[q] = 0.0;
                    for (int dv = -kL; dv <= kL; ++dv) {
                        if (tv[dv + kL] == 0.0) continue;
                        const int l = std::clamp(j + dv, 0, p_.lines - 1);
                        for (int dh = -kL; dh <= kL; ++dh) {
                            const double w = tv[dv + kL] * th[dh + kL];
                            if (w == 0.0) continue;
                            const int sh = std::clamp(s + dh, 0, ns - 1);
                            const double* h = hrow + ((ch - 1) * p_.lines + l) * ls + sh * R;
                            for (int q = 0; q < nr; ++q) row[q] += w * h[q];
                            mod += w * hval[((ch - 1) * p_.lines + l) * ns + sh];
                        }
                    }
                    add(ch, row, (ch == 1 ? w_.obs_cb[o] : w_.obs_cr[o]) - mod, wc);
                }
            }
        scatter(acc[0], R * R, R, acc_g[0], R, nr, a, g);
        return chi2;
    }

    // Per model pixel, for the outline term (a sphere's limb: the eye's, seen beside a marker): the weight of the
    // background inside it (1 everywhere without an outline); the limb profile P(s), √ of the depth s inside the
    // outline averaged over the pixel (a sphere's shading near its limb rises as √(2s/R)); dP/ds; ∂dist/∂φ and
    // ∂dist/∂κ. The outline is a parabola: dist = n·x − D + κ/2·τ², τ the coordinate along it.
    void outline_weights(const Vec& t) const {
        const int n = p_.lines * p_.cols;
        if (!p_.outline) {
            std::fill(w_.edge_w.begin(), w_.edge_w.begin() + n, 1.0);
            std::fill(w_.edge_p.begin(), w_.edge_p.begin() + n, 0.0);
            return;
        }
        const double cp = std::cos(t[kPhi]), sp = std::sin(t[kPhi]), kappa = t[kKappa];
        for (int j = 0; j < p_.lines; ++j)
            for (int i = 0; i < p_.cols; ++i) {
                const int k = j * p_.cols + i;
                const double x = xrel_[static_cast<size_t>(i)], v = vrel_[static_cast<size_t>(j)];
                const double tau = -sp * x + cp * v, nrm = cp * x + sp * v;
                const double dist = nrm - t[kD] + 0.5 * kappa * tau * tau;
                w_.edge_w[k] = std::clamp(0.5 - dist, 0.0, 1.0);
                const double s = -dist, hi = s + 0.5, lo = std::max(0.0, s - 0.5);
                const double shi = hi > 0 ? std::sqrt(hi) : 0.0, slo = std::sqrt(lo);
                w_.edge_p[k] = hi > 0 ? (2.0 / 3.0) * (hi * shi - lo * slo) : 0.0;
                w_.edge_dp[k] = shi - slo;
                w_.edge_dphi[k] = tau - kappa * tau * nrm;
                w_.edge_dkappa[k] = 0.5 * tau * tau;
            }
    }

    // Compact derivative row of model pixel (ch, i, j); edge_w must hold t's outline weights.
    void pixel_row(const Vec& t, int ch, int i, int j, double* row) const {
        const int k = j * p_.cols + i, n = p_.lines * p_.cols;
        const double x = xrel_[static_cast<size_t>(i)], v = vrel_[static_cast<size_t>(j)];
        const double limb = p_.outline ? t[kG + ch] : 0.0;
        const double inside = t[kB0 + 3 * ch] + t[kB0 + 3 * ch + 1] * x + t[kB0 + 3 * ch + 2] * v + limb * w_.edge_p[k];
        const double we = w_.edge_w[k];
        const double bg = p_.outline ? we * inside + (1.0 - we) * t[kB2 + ch] : inside;
        const double open = 1.0 - w_.cov[k], under = bg - kOffset[ch], am = t[kA] * m_[ch];
        if (w_.touch[k]) {
            for (int q = 0; q < kShapePar; ++q) row[q] = am * w_.dshade[q * n + k] - w_.dcov[q * n + k] * under;
            if (!cfg_.fit_ellipse) row[3] = row[4] = 0.0;  // e1, e2 held at 0
            row[5] = w_.shade[k] * m_[ch];
        } else {
            for (int q = 0; q <= kShapePar; ++q) row[q] = 0.0;  // the marker does not reach it
        }
        row[6] = open * we;
        row[7] = open * we * x;
        row[8] = open * we * v;
        if (!p_.outline) return;
        const bool ramp = we > 0.0 && we < 1.0;
        // ∂bg/∂dist: the step moves (in its ramp) and so does the limb profile (s = −dist).
        const double dbg = open * (-(ramp ? inside - t[kB2 + ch] : 0.0) - we * limb * w_.edge_dp[k]);
        row[9] = dbg * w_.edge_dphi[k];
        row[10] = -dbg;
        row[11] = open * (1.0 - we);
        row[12] = dbg * w_.edge_dkappa[k];
        row[13] = open * we * w_.edge_p[k];
    }

    const SphereFitConfig& cfg_;
    const Patch& p_;
    SphereFitWorkspace& w_;
    std::array<double, SphereFitWorkspace::kCols> xrel_{};
    std::array<double, SphereFitWorkspace::kLines> vrel_{};
    double m_[3] = {};
    std::array<std::array<double, 10>, 3> mom_{};  // background_moments()
    Vec lin_t_{};                                  // the point of the last linearise()
    int n_obs_ = 0;                                // observations() (kept Y, Cb, Cr samples)
    std::array<double, SphereFitWorkspace::kPx> wy_;  // 1 / var_y: the luma observations' weights
    // The box (lines, columns) raster_analytic() last wrote, with and without derivatives; the whole patch at first.
    mutable std::array<int, 4> written_[2] = {{0, p_.lines - 1, 0, p_.cols - 1}, {0, p_.lines - 1, 0, p_.cols - 1}};
};

// intensity_centroid() from the analytic pixel integrals: Σ x·I / Σ I over the pixels the marker reaches.
void intensity_centroid_analytic(const SphereFitConfig& cfg, const Vec& t, int parity, double& cx, double& cy) {
    const double x0 = t[kX0], v0 = t[kV0], r = t[kR], e1 = t[kE1], e2 = t[kE2], ap = cfg.aperture_lines_px;
    const double reach = r / std::sqrt(1.0 - std::hypot(e1, e2)) + 1.5;
    const double px_reach = 0.62 * (1.0 + ap);  // t's ellipticity is not clamped here: the wider bound
    double si = 0, sx = 0, sv = 0;
    PixelIntegral pi;
    int lo_v = static_cast<int>(std::floor(v0 - reach));
    lo_v += ((lo_v - parity) & 1);
    const int hi_v = static_cast<int>(std::ceil(v0 + reach));
    const int lo_x = static_cast<int>(std::floor(x0 - reach)), hi_x = static_cast<int>(std::ceil(x0 + reach));
    for (int v = lo_v; v <= hi_v; v += 2)
        for (int x = lo_x; x <= hi_x; ++x) {
            if (!pixel_integral<false>(x - x0, v - v0, r, e1, e2, ap, pi, px_reach)) continue;
            const double in = cfg.shade_ambient * pi.cov + cfg.shade_diffuse * pi.q;
            si += in;
            sx += in * x;
            sv += in * v;
        }
    cx = sx / si;
    cy = 0.5 * (sv / si - parity);
}

// Intensity centroid of the fitted sphere over the field's pixels (pixel centres weighted by the coverage ×
// shading each pixel integrates — the rig's truth definition), field px.
void intensity_centroid(const SphereFitConfig& cfg, const Vec& t, int parity, double& cx, double& cy) {
    constexpr int S = 16;  // sub-samples per pixel side near the outline; 4 inside, where the shading is smooth
    const double x0 = t[kX0], v0 = t[kV0], r = t[kR], e1 = t[kE1], e2 = t[kE2];
    const double inv_r2 = 1.0 / (r * r), ap = cfg.aperture_lines_px, ecc = std::hypot(e1, e2);
    const double reach = r / std::sqrt(1.0 - ecc) + 1.0;
    auto metric = [&](double xx, double yy) {
        return (1.0 + e1) * xx * xx + 2.0 * e2 * xx * yy + (1.0 - e1) * yy * yy;
    };
    // Σ ambient + diffuse·√(1 − ρ²/r²) over n × n sub-samples of the pixel at (x, v), scaled to S × S.
    auto integrate = [&](int x, int v, int n) {
        const double hn = 1.0 / n;
        double in = 0;
        for (int sy = 0; sy < n; ++sy) {
            const double yy = v + ap * (-0.5 + (sy + 0.5) * hn) - v0;
            for (int sxi = 0; sxi < n; ++sxi) {
                const double xx = x - 0.5 + (sxi + 0.5) * hn - x0;
                const double q = 1.0 - metric(xx, yy) * inv_r2;
                if (q > 0) in += cfg.shade_ambient + cfg.shade_diffuse * std::sqrt(q);
            }
        }
        return in * (S / n) * (S / n);
    };
    double si = 0, sx = 0, sv = 0;
    const int lo_v = static_cast<int>(std::floor(v0 - reach)), hi_v = static_cast<int>(std::ceil(v0 + reach));
    const int lo_x = static_cast<int>(std::floor(x0 - reach)), hi_x = static_cast<int>(std::ceil(x0 + reach));
    for (int v = lo_v; v <= hi_v; ++v) {
        if (((v - parity) & 1) != 0) continue;
        for (int x = lo_x; x <= hi_x; ++x) {
            // The metric is convex: its largest value over the pixel is at a corner, and its smallest is at least
            // (1 − |e|) × the squared distance from the centre to the pixel.
            const double dx0 = x - 0.5 - x0, dx1 = x + 0.5 - x0, dv0 = v - 0.5 * ap - v0, dv1 = v + 0.5 * ap - v0;
            const double ex = std::max(0.0, std::max(dx0, -dx1)), ev = std::max(0.0, std::max(dv0, -dv1));
            if ((1.0 - ecc) * (ex * ex + ev * ev) >= r * r) continue;  // wholly outside
            const double qmax =
                std::max(std::max(metric(dx0, dv0), metric(dx0, dv1)), std::max(metric(dx1, dv0), metric(dx1, dv1)));
            // Wholly inside with the shading at ≥ 0.3 of its range: 4 × 4 sub-samples are enough.
            const double in = integrate(x, v, qmax < 0.91 * r * r ? 4 : S);
            si += in;
            sx += in * x;
            sv += in * v;
        }
    }
    cx = sx / si;
    cy = 0.5 * (sv / si - parity);
}

// Intensity centroid of the part of the fitted sphere the hint's occluders leave visible (field px), as
// intensity_centroid(): pixels clear of them or wholly behind them from their analytic integrals, the others from
// n × n sub-samples, each in the sphere and not behind an occluder; `visible_fraction`: the share of the sphere's
// light left.
// frame_lines > 0: the image's height in frame lines (and 720 columns); the part of the marker beyond the image's
// edge is not seen, as if hidden (the pipeline's centroid and the truth's are of the part in the image).
void visible_centroid(const SphereFitConfig& cfg, const Vec& t, int parity, const MarkerHint& predicted, double& cx,
                      double& cy, double* visible_fraction = nullptr, int n = 8, int frame_lines = 0) {
    const double x0 = t[kX0], v0 = t[kV0], r = t[kR], e1 = t[kE1], e2 = t[kE2], ap = cfg.aperture_lines_px;
    const double reach = r / std::sqrt(1.0 - std::min(0.9, std::hypot(e1, e2))) + 1.5, inv_r2 = 1.0 / (r * r);
    const double px_reach = 0.62 * (1.0 + ap);  // t's ellipticity is not clamped here: the wider bound
    const OutlineNorm nm(predicted, r, e1, e2);
    const MarkerHint hint = hint_at(predicted, nm, x0, v0);
    double si = 0, sx = 0, sv = 0, whole = 0;
    PixelIntegral pi;
    int lo_v = static_cast<int>(std::floor(v0 - reach));
    lo_v += ((lo_v - parity) & 1);
    const int hi_v = static_cast<int>(std::ceil(v0 + reach));
    const int lo_x = static_cast<int>(std::floor(x0 - reach)), hi_x = static_cast<int>(std::ceil(x0 + reach));
    uint8_t state[kMaxCoverCols];
    const int ncols = std::min(hi_x - lo_x + 1, kMaxCoverCols - 1);
    for (int v = lo_v; v <= hi_v; v += 2) {
        line_cover(hint, nm, lo_x - x0, v - v0, ncols, 0.0, 0.5 * ap, state);
        const bool off_line = frame_lines > 0 && (v < 0 || v >= frame_lines);
        for (int k = 0; k < ncols; ++k) {
            const int x = lo_x + k;
            const bool off = off_line || (frame_lines > 0 && (x < 0 || x >= 720));
            double in = 0, whole_px = 0;
            if (state[k] != 1) {  // clear, or wholly covered: the analytic integral
                if (!pixel_integral<false>(x - x0, v - v0, r, e1, e2, ap, pi, px_reach)) continue;
                const double full = cfg.shade_ambient * pi.cov + cfg.shade_diffuse * pi.q;
                whole += full;
                if (state[k] == 0 && !off) in = full;
            } else {
                for (int b = 0; b < n; ++b) {
                    const double dv = v + ap * (-0.5 + (b + 0.5) / n) - v0;
                    for (int a = 0; a < n; ++a) {
                        const double dx = x - 0.5 + (a + 0.5) / n - x0;
                        const double q = 1.0 - ((1.0 + e1) * dx * dx + 2.0 * e2 * dx * dv + (1.0 - e1) * dv * dv) * inv_r2;
                        if (q <= 0) continue;
                        double qx, qy;
                        nm(dx, dv, qx, qy);
                        const double shade = cfg.shade_ambient + cfg.shade_diffuse * std::sqrt(q);
                        whole_px += shade;
                        if (!off && !hint_covers(hint, qx, qy)) in += shade;
                    }
                }
                in /= n * n;
                whole += whole_px / (n * n);
            }
            si += in;
            sx += in * x;
            sv += in * v;
        }
    }
    cx = si > 0 ? sx / si : x0;
    cy = si > 0 ? 0.5 * (sv / si - parity) : 0.5 * (v0 - parity);
    if (visible_fraction) *visible_fraction = whole > 0 ? si / whole : 0.0;
}

}  // namespace

bool hinted_centroid_offset(const SphereFitConfig& cfg, const MarkerHint& hint, int parity, double& dx_px,
                            double& dv_px, double& visible) {
    dx_px = dv_px = visible = 0.0;
    if (!(hint.radius_px > 0.25) || !std::isfinite(hint.centre_x_px) || !std::isfinite(hint.centre_v_px) ||
        !(std::hypot(hint.e1, hint.e2) < 0.5))
        return false;
    Vec t{};
    t[kX0] = hint.centre_x_px;
    t[kV0] = hint.centre_v_px;
    t[kR] = hint.radius_px;
    t[kE1] = hint.e1;
    t[kE2] = hint.e2;
    double cx = 0, cy = 0;
    visible_centroid(cfg, t, parity & 1, hint, cx, cy, &visible, 4);
    dx_px = cx - t[kX0];
    dv_px = 2.0 * cy + (parity & 1) - t[kV0];
    return visible > 0 && std::isfinite(dx_px) && std::isfinite(dv_px);
}

namespace {

// One pixel of the patch's border: position (frame px) and Y, Cb, Cr.
struct BorderPx {
    double x, v, c[3];
};

// The outline's offset, levels and limb gains from the border's profile across it (t holds the start from the
// border's mid-level crossings). Inside the outline a limb's shading rises as √depth (the model's P), so the
// mid-level crossing lies up to a pixel or more inside the step, and the levels on the border are not those at the
// step: started there, the fit spent two or three more linearisations walking the offset and the luma gain in.
// The offset comes from a coarse search and a parabola, the levels and gains from least squares at each offset.
void outline_profile_start(const BorderPx* border, int nb, const Patch& p, Vec& t) {
    const double cp = std::cos(t[kPhi]), sp = std::sin(t[kPhi]);
    // Each border pixel's coordinate along the outline's normal: fixed over the search, which moves only the offset.
    std::array<double, 2 * (kFitMaxCols + kFitMaxLines)> along;
    for (int k = 0; k < nb; ++k) along[static_cast<size_t>(k)] = cp * (border[k].x - p.xc) + sp * (border[k].v - p.vc);
    // Least squares of channels 0 … n_ch − 1 over the border against we·(b0 + G·P) + (1 − we)·b2 at offset D + dd
    // (the design is the same for every channel); returns channel 0's residual sum of squares (infinite when the
    // design is singular) and each channel's levels in lev[ch] (b0, G, b2).
    auto fit = [&](double dd, int n_ch, double lev[3][3]) {
        double m[6] = {}, g[3][3] = {}, oo[3] = {};  // lower triangle 00, 10, 11, 20, 21, 22
        const double off = t[kD] + dd;
        for (int k = 0; k < nb; ++k) {
            const double dist = along[static_cast<size_t>(k)] - off;
            const double we = std::clamp(0.5 - dist, 0.0, 1.0), s = -dist;
            const double hi = s + 0.5, lo = std::max(0.0, s - 0.5);
            const double pr = hi > 0 ? (2.0 / 3.0) * (hi * std::sqrt(hi) - lo * std::sqrt(lo)) : 0.0;
            const double a[3] = {we, we * pr, 1.0 - we};
            m[0] += a[0] * a[0];
            m[1] += a[1] * a[0];
            m[2] += a[1] * a[1];
            m[3] += a[2] * a[0];
            m[4] += a[2] * a[1];
            m[5] += a[2] * a[2];
            for (int ch = 0; ch < n_ch; ++ch) {
                const double o = border[k].c[ch];
                for (int q = 0; q < 3; ++q) g[ch][q] += a[q] * o;
                oo[ch] += o * o;
            }
        }
        // 3 × 3 by Cholesky.
        const double l00 = m[0] > 0 ? std::sqrt(m[0]) : 0.0;
        if (!(l00 > 1e-9)) return HUGE_VAL;
        const double l10 = m[1] / l00, l20 = m[3] / l00;
        const double d1 = m[2] - l10 * l10;
        if (!(d1 > 1e-9 * m[2])) return HUGE_VAL;
        const double l11 = std::sqrt(d1), l21 = (m[4] - l20 * l10) / l11;
        const double d2 = m[5] - l20 * l20 - l21 * l21;
        if (!(d2 > 1e-9 * m[5])) return HUGE_VAL;
        const double l22 = std::sqrt(d2);
        double sse = 0;
        for (int ch = n_ch - 1; ch >= 0; --ch) {
            const double y0 = g[ch][0] / l00, y1 = (g[ch][1] - l10 * y0) / l11, y2 = (g[ch][2] - l20 * y0 - l21 * y1) / l22;
            lev[ch][2] = y2 / l22;
            lev[ch][1] = (y1 - l21 * lev[ch][2]) / l11;
            lev[ch][0] = (y0 - l10 * lev[ch][1] - l20 * lev[ch][2]) / l00;
            sse = oo[ch] - (y0 * y0 + y1 * y1 + y2 * y2);
        }
        return sse;
    };
    // Coarse search over whole pixels, then half a pixel either side of the best and a parabola through the three.
    // The range reaches far inside: an outline whose step the profile does not match (a shaft's edge, a shadow)
    // fits best as a smooth gradient, the step moved out of the way.
    constexpr int kN = 10;
    constexpr double kLo = -1.0;
    double lev[3][3], best_sse = HUGE_VAL, dd = 0;
    for (int q = 0; q < kN; ++q) {
        const double e = fit(kLo + q, 1, lev);
        if (e < best_sse) {
            best_sse = e;
            dd = kLo + q;
        }
    }
    if (!(best_sse < HUGE_VAL)) return;
    const double below = fit(dd - 0.5, 1, lev), above = fit(dd + 0.5, 1, lev);
    const double c2 = below - 2.0 * best_sse + above;
    if (below < HUGE_VAL && above < HUGE_VAL && c2 > 0) {
        const double at = dd + 0.25 * (below - above) / c2;  // vertex of the parabola (step 0.5)
        if (fit(at, 1, lev) < best_sse) dd = at;
    }
    const bool solved = fit(dd, 3, lev) < HUGE_VAL;  // the levels at the offset found (before t[kD] moves to it)
    t[kD] += dd;
    if (!solved) return;
    for (int ch = 0; ch < 3; ++ch) {
        t[kB0 + 3 * ch] = lev[ch][0];
        t[kG + ch] = lev[ch][1];
        t[kB2 + ch] = lev[ch][2];
    }
}

// Start of the marker's radius and ellipticity from the chroma moments of the blob (the observations are in the
// workspace, t holds the box's radius and the background's start). Each chroma sample's excess over the
// background, projected on the class's chroma, is A·(coverage × shading) filtered [1 2 1], A ≈ 1: its sum over the
// samples is ¼·area·S̄ (samples at every other column and field line, S̄ the mean shading), its covariance
// k·r²·M⁻¹ plus the filter's and the pixel's spread. From the box's half width (≈ 0.5 px off) the fit needed a
// linearisation more.
void moment_start(const BlobBox& blob, const Patch& p, const SphereFitConfig& cfg, const SphereFitWorkspace& w,
                  Vec& t) {
    const double mcb = p.colour.cb_dn, mcr = p.colour.cr_dn, m2 = mcb * mcb + mcr * mcr;
    if (!(m2 > 100.0)) return;  // a colourless class: no chroma to measure it by
    const int nx = p.x1 - p.x0 + 1;
    const double cp = std::cos(t[kPhi]), sp = std::sin(t[kPhi]);
    const int j_lo = std::max(0, blob.y_min - 1 - p.j0), j_hi = std::min(p.lines - 1, blob.y_max + 1 - p.j0);
    const int x_lo = std::max(p.x0, blob.x_min - 2), x_hi = std::min(p.x1, blob.x_max + 2);
    double s0 = 0, sx = 0, sv = 0, sxx = 0, sxv = 0, svv = 0;
    for (int j = j_lo; j <= j_hi; ++j) {
        const double v = 2.0 * (p.j0 + j) + p.parity - p.vc;
        int s = 0;
        for (int x = p.x0 + (p.x0 & 1); x <= p.x1; x += 2, ++s) {
            if (x < x_lo || x > x_hi) continue;
            const double dx = x - p.xc;
            const bool beyond = p.outline && cp * dx + sp * v - t[kD] > 0.0;
            const double bcb = beyond ? t[kB2 + 1] : t[kB0 + 3], bcr = beyond ? t[kB2 + 2] : t[kB0 + 6];
            const double wt = ((w.obs_cb[static_cast<size_t>(j * nx + s)] - bcb) * mcb +
                               (w.obs_cr[static_cast<size_t>(j * nx + s)] - bcr) * mcr) / m2;
            s0 += wt;
            sx += wt * dx;
            sv += wt * v;
            sxx += wt * dx * dx;
            sxv += wt * dx * v;
            svv += wt * v * v;
        }
    }
    if (!(s0 > 1.0)) return;
    // Radius from the sum: the background's chroma under the marker is hidden by it (¼·area·P less excess, P its
    // projection), and the shading's mean over a sphere's disc is ambient + ⅔·diffuse.
    const double mean_shade = cfg.shade_ambient + cfg.shade_diffuse * (2.0 / 3.0);
    const double under = ((t[kB0 + 3] - 128.0) * mcb + (t[kB0 + 6] - 128.0) * mcr) / m2;
    const double r = std::sqrt(4.0 * s0 / (3.14159265358979 * std::max(0.2, mean_shade - under)));
    if (!(r > 0.5 * t[kR] && r < 2.0 * t[kR])) return;  // not one marker's blob: keep the box's start
    t[kR] = r;
    // Ellipticity from the covariance k·r²·M⁻¹ (M⁻¹ ∝ [[1 − e1, −e2], [−e2, 1 + e1]]), less the [1 2 1] filter's
    // spread over the even columns (½ px²) and the pixel's (1/12 and ap²/12).
    const double mx = sx / s0, mv = sv / s0, ap = cfg.aperture_lines_px;
    // With the source's chroma chain, less its spread down the lines too (a field line is 2 frame px).
    const double chain = p.chain ? 4.0 * chain_variance_lines(cfg, p.parity) : 0.0;
    const double chain_x = p.hchain ? 4.0 * chain_variance_samples(cfg) : 0.0;
    const double cxx = sxx / s0 - mx * mx - 0.5 - 1.0 / 12.0 - chain_x, cvv = svv / s0 - mv * mv - ap * ap / 12.0 - chain,
                 cxv = sxv / s0 - mx * mv;
    if (!(cxx > 0 && cvv > 0)) return;
    const double e1 = (cvv - cxx) / (cvv + cxx), e2 = -2.0 * cxv / (cvv + cxx), e = std::hypot(e1, e2);
    const double keep = e > 0.2 ? 0.2 / e : 1.0;  // noise: the plausible range's inner part
    t[kE1] = keep * e1;
    t[kE2] = keep * e2;
}

}  // namespace

// The start behind a hint's occluders takes a second step only past this (field px).
constexpr double kStartSecondStepPx = 0.25;

SphereFitResult fit_sphere(const uint8_t* field, int height, const BlobBox& blob, const SphereFitConfig& cfg,
                           SphereFitWorkspace& w, const MarkerHint* hint, const PatchMask* mask, bool start_at_hint) {
    SphereFitResult res;
    constexpr int kWidth = 720, kStride = 1440;
    if (blob.class_id < 1 || blob.class_id > 4 || blob.x_max < blob.x_min || blob.y_max < blob.y_min) return res;
    Patch p;
    p.x0 = std::max(1, blob.x_min - cfg.margin_px);
    p.x1 = std::min(kWidth - 2, blob.x_max + cfg.margin_px);
    p.j0 = std::max(0, blob.y_min - cfg.margin_lines);
    p.j1 = std::min(height - 1, blob.y_max + cfg.margin_lines);
    p.parity = blob.parity & 1;
    p.cols = p.x1 - p.x0 + 3;
    p.lines = p.j1 - p.j0 + 1;
    p.core_j0 = p.j0;
    p.core_j1 = p.j1;
    p.core_x0 = p.x0;
    p.core_x1 = p.x1;
    // The source's chroma chains, where the field and the workspace have their lines and columns beyond the patch's.
    constexpr int kCL = kChromaChainLines;
    // At the field's top and bottom the edge taps fold the lines beyond it onto the edge line: the patch stops there.
    const bool edges = cfg.chroma_chain_field_lines == height;
    const int cj0 = edges ? std::max(0, p.j0 - kCL) : p.j0 - kCL;
    const int cj1 = edges ? std::min(height - 1, p.j1 + kCL) : p.j1 + kCL;
    if (cfg.chroma_chain && cj0 >= 0 && cj1 <= height - 1 && cj1 - cj0 + 1 <= kFitMaxLines) {
        p.chain = true;
        p.edge_height = edges ? height : 0;
        p.j0 = cj0;
        p.j1 = cj1;
        p.lines = cj1 - cj0 + 1;
    }
    if (cfg.chroma_chain_h && !hint && p.x0 - 2 * kCL >= 1 && p.x1 + 2 * kCL <= kWidth - 2 &&
        p.x1 - p.x0 + 1 + 4 * kCL <= kFitMaxCols) {
        p.hchain = true;
        p.x0 -= 2 * kCL;
        p.x1 += 2 * kCL;
        p.cols += 4 * kCL;
    }
    p.chroma_sigma_dn = p.chain || p.hchain ? cfg.chain_chroma_noise_dn
                                            : cfg.chroma_noise_dn > 0 ? cfg.chroma_noise_dn : cfg.noise_dn;
    if (hint && hint->radius_ratio == 0 && hint->occluder_radius > 0)
        p.chroma_sigma_dn = std::max(p.chroma_sigma_dn, cfg.eye_hidden_chroma_noise_dn);
    const double margin = cfg.occluder_margin_px;
    res.refusal = FitRefusal::kStorage;
    if (p.x1 - p.x0 + 1 > kFitMaxCols || p.lines > kFitMaxLines || p.x1 <= p.x0) return res;
    p.colour = cfg.colour[blob.class_id];
    const double cx0 = blob.cx_px, cy0 = blob.cy_px;
    p.xc = cx0;
    p.vc = 2.0 * cy0 + p.parity;

    // Observations and the border's levels.
    std::fill(w.keep_y.begin(), w.keep_y.end(), uint8_t{1});
    std::fill(w.keep_cb.begin(), w.keep_cb.end(), uint8_t{1});
    std::fill(w.keep_cr.begin(), w.keep_cr.end(), uint8_t{1});
    const int nx = p.x1 - p.x0 + 1;
    // Another instrument's shaft or another marker in the patch is neither this marker nor background: its pixels
    // are left out, as observations (always: hidden) and from the border's levels, except where the marker is.
    const bool masked = mask && (mask->count > 0 || mask->disc_count > 0);
    auto foreign_at = [&](int x, int j) {
        const double v = 2.0 * j + p.parity, hv = 0.5 * cfg.aperture_lines_px;
        if (std::hypot(x - mask->keep_x_px, v - mask->keep_v_px) < mask->keep_radius_px) return false;
        for (int k = 0; k < std::min(mask->count, PatchMask::kMaxShafts); ++k)
            if (shaft_touches(mask->shafts[static_cast<size_t>(k)], x, v, 0.5, hv)) return true;
        for (int k = 0; k < std::min(mask->disc_count, PatchMask::kMaxDiscs); ++k) {
            const ForeignDisc& d = mask->discs[static_cast<size_t>(k)];
            if (box_within(x - d.x_px, v - d.v_px, 0.5, hv, d.r_px)) return true;
        }
        return false;
    };
    std::fill(w.foreign_y.begin(), w.foreign_y.end(), uint8_t{0});
    std::fill(w.foreign_c.begin(), w.foreign_c.end(), uint8_t{0});
    const int ns = (p.x1 - (p.x0 + (p.x0 & 1))) / 2 + 1;
    if (masked) {
        for (int j = 0; j < p.lines; ++j) {
            uint8_t col[kFitMaxCols + 2];  // columns x0 − 1 … x1 + 1: a chroma sample filters three
            for (int x = p.x0 - 1; x <= p.x1 + 1; ++x) col[x - p.x0 + 1] = foreign_at(x, p.j0 + j);
            for (int x = 0; x < nx; ++x) w.foreign_y[j * nx + x] = col[x + 1];
            int s = 0;
            for (int x = p.x0 + (p.x0 & 1); x <= p.x1; x += 2, ++s) {
                const int i = x - p.x0 + 1;
                w.foreign_c[j * nx + s] = (col[i - 1] | col[i] | col[i + 1]) != 0;
            }
        }
        if (p.chain || p.hchain) {  // the chains take a foreign pixel's chroma into the observations about it
            uint8_t line_c[kFitMaxLines][SphereFitWorkspace::kSamples];
            for (int j = 0; j < p.lines; ++j)
                for (int s = 0; s < ns; ++s) line_c[j][s] = w.foreign_c[j * nx + s];
            for (int j = 0; j < p.lines; ++j)
                for (int s = 0; s < ns; ++s) w.foreign_c[j * nx + s] = chain_reaches(cfg, p, line_c, ns, j, s);
        }
    }
    if (p.chain || p.hchain)  // the chains' own lines and columns: modelled, not observed
        for (int j = 0; j < p.lines; ++j) {
            const bool line_out = p.j0 + j < p.core_j0 || p.j0 + j > p.core_j1;
            for (int x = 0; x < nx; ++x)
                if (line_out || p.x0 + x < p.core_x0 || p.x0 + x > p.core_x1) w.foreign_y[j * nx + x] = 1;
            int s = 0;
            for (int x = p.x0 + (p.x0 & 1); x <= p.x1; x += 2, ++s)
                if (line_out || x < p.core_x0 || x > p.core_x1) w.foreign_c[j * nx + s] = 1;
        }
    if (masked || p.chain || p.hchain)
        for (int o = 0; o < SphereFitWorkspace::kPx; ++o) {
            w.keep_y[o] = !w.foreign_y[o];
            w.keep_cb[o] = w.keep_cr[o] = !w.foreign_c[o];
        }
    const double shot = cfg.shot_gain,
                 n2 = cfg.noise_dn * cfg.noise_dn + cfg.luma_noise_floor_dn * cfg.luma_noise_floor_dn;
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
    Vec t{};
    t[kX0] = cx0;
    t[kV0] = p.vc;
    // The box is about a column wider than the marker each side (4:2:2 chroma spreads it): from 9 columns on, a
    // start that much smaller saves about one iteration (narrower boxes keep half the width: a smaller start
    // refuses more 4-6 px markers).
    const double half_box = 0.5 * (blob.x_max - blob.x_min + 1);
    t[kR] = half_box >= 4.5 ? half_box - 1.0 : half_box;
    // The pipeline's centroid is the visible part's: with a shaft, start the centre where the model's visible
    // centroid meets it (the shaft's image moves with the centre; the eye's outline does not). A second step only
    // where the first moved the centre by more than kStartSecondStepPx: below it the fit ends where it would have
    // (`eyesim fpga --refine`, sweep seed 1, raw and DV: every figure within 2e-5 px at 0.2–0.3 px, a third
    // of the start steps saved; one step everywhere lost 7–11 %).
    auto start_behind_occluders = [&] {
        if (hint && start_at_hint) {
            t[kX0] = hint->centre_x_px;
            t[kV0] = hint->centre_v_px;
            return;
        }
        for (int k = 0; hint && k < 2; ++k) {
            double vx, vy;
            visible_centroid(cfg, t, p.parity, *hint, vx, vy, nullptr, 4, 2 * height);  // a start: 4 × 4 sub-samples do
            t[kX0] += cx0 - vx;
            t[kV0] += 2.0 * (cy0 - vy);
            if (std::hypot(cx0 - vx, cy0 - vy) <= kStartSecondStepPx) break;
        }
    };
    start_behind_occluders();
    const OutlineNorm border_norm(hint ? *hint : MarkerHint{}, t[kR], 0.0, 0.0);
    const MarkerHint border_hint = hint ? hint_at(*hint, border_norm, t[kX0], t[kV0]) : MarkerHint{};
    const double hidden_hx = 0.5 + margin, hidden_hv = 0.5 * cfg.aperture_lines_px + margin;

    // Border walk, clockwise: levels, and where the luma crosses its mid level (an outline through the patch). The
    // shaft's pixels are not the background's.
    std::array<BorderPx, 2 * (kFitMaxCols + kFitMaxLines)> border;
    int nb = 0;
    auto push = [&](int x, int j) {
        if (masked && w.foreign_y[(j - p.j0) * nx + (x - p.x0)]) return;
        if (hint && box_touches_occluder(border_hint, border_norm, x - t[kX0], 2.0 * j + p.parity - t[kV0], hidden_hx, hidden_hv))
            return;
        const uint8_t* line = field + static_cast<size_t>(j) * kStride;
        border[static_cast<size_t>(nb++)] = {double(x), 2.0 * j + p.parity,
                                             {double(line[2 * x + 1]), double(line[4 * (x >> 1)]), double(line[4 * (x >> 1) + 2])}};
    };
    for (int x = p.core_x0; x < p.core_x1; ++x) push(x, p.core_j0);
    for (int j = p.core_j0; j < p.core_j1; ++j) push(p.core_x1, j);
    for (int x = p.core_x1; x > p.core_x0; --x) push(x, p.core_j1);
    for (int j = p.core_j1; j > p.core_j0; --j) push(p.core_x0, j);
    double lo = 1e9, hi = -1e9, mean[3] = {0, 0, 0};
    for (int k = 0; k < nb; ++k) {
        lo = std::min(lo, border[k].c[0]);
        hi = std::max(hi, border[k].c[0]);
        for (int c = 0; c < 3; ++c) mean[c] += border[k].c[c] / nb;
    }

    t[kA] = 1.0;
    for (int c = 0; c < 3; ++c) t[kB0 + 3 * c] = mean[c];
    if (hi - lo > cfg.outline_step_dn) {
        const double mid = 0.5 * (lo + hi);
        // The outline crosses the border where the luma passes from one side of the mid level to the other. A
        // side changes only past mid ± h, so that noise on a border running along a gentle limb gradient, or a
        // sample exactly at mid, makes no crossing (either took the outline model from a marker in some fields,
        // and its fit then refused the limb as outliers: surgery seed 22, one eye marker in 5 of 20 fields); the
        // crossing is placed where the samples last bracketed mid, as before.
        const double h = std::max(3.0 * std::sqrt(n2 + shot * std::max(0.0, mid - 16.0)), 0.1 * (hi - lo));
        double cross[2][2];
        int nc = 0;
        int k0 = 0;  // the walk starts at a sample clearly on one side
        while (k0 < nb && std::fabs(border[k0].c[0] - mid) <= h) ++k0;
        bool above = k0 < nb && border[k0].c[0] > mid;
        for (int s = 1; k0 < nb && s <= nb; ++s) {
            const int k = (k0 + s) % nb;
            if (above ? border[k].c[0] >= mid - h : border[k].c[0] <= mid + h) continue;
            // The last sample before k still on the old side of mid (it exists: the previous change, or k0, is).
            int m = (k + nb - 1) % nb;
            while (above ? border[m].c[0] < mid : border[m].c[0] > mid) m = (m + nb - 1) % nb;
            const BorderPx& a = border[m];
            const BorderPx& b = border[(m + 1) % nb];
            if (nc < 2) {
                const double u = std::clamp((mid - a.c[0]) / (b.c[0] - a.c[0]), 0.0, 1.0);
                cross[nc][0] = a.x + u * (b.x - a.x);
                cross[nc][1] = a.v + u * (b.v - a.v);
            }
            ++nc;
            above = !above;
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
                    outline_profile_start(border.data(), nb, p, t);
                }
            }
        }
    }

    res.refusal = FitRefusal::kHintOutline;
    if (hint && p.outline && !cfg.hint_with_outline) return res;

    moment_start(blob, p, cfg, w, t);
    w.hidden_y = w.foreign_y;
    w.hidden_c = w.foreign_c;
    // The outline the pose predicts, held by a prior: a hint's, or, started at the prediction, a merged blob's (the
    // other marker's pixels left out, the arc left lets the shape drift: sweep seed 135, H.264, an eye marker fitted
    // with e = 0.43 into its neighbour's half). That blob's moments lie between the two markers: it starts at the
    // marker's predicted centre.
    MarkerHint shape;
    const bool merged_start =
        !(hint && hint->radius_px > 0) && start_at_hint && mask && mask->merged && mask->keep_outline_r_px > 0;
    if (hint && hint->radius_px > 0) {
        shape = *hint;
    } else if (merged_start) {
        shape.radius_px = mask->keep_outline_r_px;
        shape.e1 = mask->keep_e1;
        shape.e2 = mask->keep_e2;
        t[kX0] = mask->keep_x_px;
        t[kV0] = mask->keep_v_px;
    }
    if (shape.radius_px > 0) {  // the pose's outline is a better start than the visible part's moments
        t[kR] = shape.radius_px;
        t[kE1] = shape.e1;
        t[kE2] = shape.e2;
    }
    start_behind_occluders();  // again at this radius
    // Where the centre started: with a hint, the visible part's centroid lies up to a radius from it.
    const double x_start = hint ? t[kX0] : cx0, v_start = hint ? t[kV0] : p.vc;

    Fitter f(cfg, p, w);
    bool mask_changed = false;
    if (hint) res.hidden_pixels = f.mask_hidden(t, *hint, margin, mask_changed);
    const int np = f.np();
    double chi2 = 0;
    bool chi2_at_t = false;  // chi2 holds χ² at t (measured, or predicted for an unverified last step)
    int it = 0;
    // A Gauss–Newton step this small is taken without another linearisation: the steps shrink by a factor of
    // about ten each (the derivatives are exact to a few per cent), so it leaves ≈ 5e-4 px, far below the noise's
    // 0.01 px (5e-3 instead of 2e-3 px cut the linearisations per 6–10 px marker from 3.5 to 2.8; the held-out
    // seeds' RMS moved by 1e-4 px).
    auto small_step = [](const Vec& d) {
        return std::fabs(d[kX0]) < 5e-3 && std::fabs(d[kV0]) < 1e-2 && std::fabs(d[kR]) < 5e-3;
    };
    // The first step itself, where the configuration takes it unconfirmed (SphereFitConfig::
    // first_step_unverified_px; x in frame px, v in frame lines: two a field line).
    const double first_px = cfg.first_step_unverified_px;
    auto small_first = [first_px](const Vec& d) {
        return first_px > 0 && std::fabs(d[kX0]) < first_px && std::fabs(d[kV0]) < 2.0 * first_px &&
               std::fabs(d[kR]) < first_px;
    };
    // Levenberg–Marquardt from t; with give_up, stops early on a fit that stays hopeless (another object in the
    // patch).
    // Each trial point is linearised at once: its χ² comes with its normal equations, which an accepted step
    // needs next (no separate cost render).
    // Normal equations at t and at the trial point; an accepted trial's become t's by swapping the two.
    Mat mats[2];
    Vec grads[2];
    int at_t = 0;
    // The pose's prediction of the outline, as three more observations (a MarkerHint with radius_px).
    const bool prior = shape.radius_px > 0;
    auto with_prior = [&](const Vec& tt, double c, Mat& a, Vec& g) {
        if (!prior) return c;
        const double pr[3] = {shape.radius_px, shape.e1, shape.e2};
        const double sg[3] = {shape.radius_sigma * shape.radius_px, shape.e_sigma, shape.e_sigma};
        const int idx[3] = {kR, kE1, kE2};
        for (int k = 0; k < 3; ++k) {
            const double wgt = 1.0 / (sg[k] * sg[k]), res_k = pr[k] - tt[idx[k]];
            a[static_cast<size_t>(idx[k] * kMaxPar + idx[k])] += wgt;
            g[static_cast<size_t>(idx[k])] += wgt * res_k;
            c += wgt * res_k * res_k;
        }
        return c;
    };
    auto solve = [&](int max_it, bool give_up) {
        f.linearise(t);
        chi2 = with_prior(t, f.normal_equations(t, mats[at_t], grads[at_t]), mats[at_t], grads[at_t]);
        chi2_at_t = true;
        double lambda = 1e-3;
        const int dof = std::max(1, f.observations() - np);
        for (int k = 0; k < max_it; ++k, ++it) {
            bool improved = false, converged = false;
            double gain = 0;
            for (int tries = 0; tries < 8 && !improved; ++tries) {
                Vec d;
                const Mat& a = mats[at_t];
                const Vec& g = grads[at_t];
                if (np == kPhi ? solve_damped_blocks(a, g, kLayoutMarker, lambda, d)
                                : solve_damped_blocks(a, g, kLayoutOutline, lambda, d)) {
                    Vec tt = t;
                    for (int q = 0; q < np; ++q) tt[q] += d[q];
                    if (tries == 0 && (k > 0 ? small_step(d) : small_first(d))) {
                        // The step after an accepted one is already below the noise's reach (or a first step the
                        // configuration takes unconfirmed, small_first): take it unverified
                        // (its χ² change is far below one) instead of rendering once more to confirm it. Its χ² is
                        // the linear model's, χ² − 2dᵀg + dᵀAd, for the refusal test (no render for that either).
                        double dad = 0, dg = 0;
                        for (int q = 0; q < np; ++q) {
                            dg += d[q] * g[q];
                            double ad = 0;
                            for (int u = 0; u < np; ++u) ad += a[static_cast<size_t>(q * kMaxPar + u)] * d[u];
                            dad += d[q] * ad;
                        }
                        chi2 = std::max(0.0, chi2 - 2.0 * dg + dad);
                        t = tt;
                        converged = true;
                        break;
                    }
                    f.linearise(tt);
                    const double c1 =
                        with_prior(tt, f.normal_equations(tt, mats[1 - at_t], grads[1 - at_t]), mats[1 - at_t], grads[1 - at_t]);
                    if (c1 < chi2) {
                        at_t = 1 - at_t;
                        // Centre and radius settled far below the noise's reach (≈ 0.01 px): another step buys nothing.
                        converged = small_step(d);
                        gain = chi2 - c1;
                        t = tt;
                        chi2 = c1;
                        lambda = std::max(1e-7, lambda * 0.3);
                        improved = true;
                        break;
                    }
                    // A step this small that does not lower χ² means the minimum is reached (to the model's
                    // sub-cell smoothness); damping it further only costs renders.
                    if (small_step(d)) {
                        converged = true;
                        break;
                    }
                }
                lambda *= 10.0;
            }
            if (!improved || gain < 1e-6 * chi2 || converged) break;
            if (give_up && k >= 3 && chi2 > 4.0 * cfg.max_reduced_chi2 * dof) break;
        }
    };
    // Observations of something the model does not hold (a shaft beside an instrument marker) are taken out and
    // the fit is run again on the rest, as long as they are few. Not with an outline: there the misfit is the
    // outline model's own (a curved, shaded limb), which leaving pixels out does not mend.
    const bool may_drop = cfg.max_outlier_fraction > 0 && !p.outline;
    solve(cfg.max_iterations, true);
    // The shaft's image follows the centre: mask it again where the fit ended, and refit if the set moved.
    for (int k = 0; hint && k < 2; ++k) {
        res.hidden_pixels = f.mask_hidden(t, *hint, margin, mask_changed);
        if (!mask_changed) break;
        solve(cfg.max_iterations, true);
    }
    if (may_drop && chi2 > cfg.max_reduced_chi2 * std::max(1, f.observations() - np)) {
        const int before = f.observations();
        bool too_many = false;
        // The first fit is pulled by what it cannot model: tighten the cut over rounds (3, 2, 1 × outlier_sigma)
        // so that the first cut takes only the grossest misfits.
        for (int round = 3; round >= 1; --round) {
            res.outliers = f.drop_outliers(t, round * cfg.outlier_sigma);
            chi2_at_t = false;
            too_many = res.outliers > cfg.max_outlier_fraction * before;
            if (too_many) break;
            solve(cfg.max_iterations, true);
            // A refit whose centre is this far from the pipeline's will not come within max_shift_outliers_px.
            if (gate_distance(cfg, t[kX0] - cx0, 0.5 * (t[kV0] - p.vc)) > 4.0 * cfg.max_shift_outliers_px) break;
        }
        // Only a band through the marker is a shaft; left-out pixels on one side (an eye limb the background
        // model cannot follow) or all round it are not mended by leaving them out.
        double r1 = 1, r2 = 0;
        f.outlier_spread(t, r1, r2);
        res.outlier_band = !too_many && r1 < 0.5 && r2 > 0.6;
    }
    res.iterations = it;
    res.outline = p.outline;
    res.reduced_chi2 = (chi2_at_t ? chi2 : f.cost(t)) / std::max(1, f.observations() - np);
    res.radius_px = t[kR];
    res.e1 = t[kE1];
    res.e2 = t[kE2];
    res.centre_x_px = t[kX0];
    res.centre_y_px = 0.5 * (t[kV0] - p.parity);
    const double box_r = 0.5 * (blob.x_max - blob.x_min + 1);
    res.refusal = FitRefusal::kChi2;
    if (!(res.reduced_chi2 <= cfg.max_reduced_chi2)) return res;
    res.refusal = FitRefusal::kImplausible;
    // A hint's radius comes from the pose (held by a prior): the blob's box, which is what the occluders left of
    // the marker, bounds it no more (a marker 86 % behind the eye can be a one-column blob on video).
    const double max_r = hint && hint->radius_px > 0 ? 1.5 * hint->radius_px + 1.0 : 2.0 * box_r + 2.0;
    // The centre near where it started, or with a hint near the pose's prediction where another class's blob
    // overlaps this one (BlobBox::foreign_overlap: its chroma spoiled the moments the start came from) or where
    // the marker is mostly hidden (below).
    auto near = [&](double x, double v) { return std::fabs(t[kX0] - x) < 1.5 && std::fabs(t[kV0] - v) < 2.0; };
    const bool merged = mask && mask->merged;
    if (!(t[kR] > 0.5 && t[kR] < max_r && t[kA] > 0.2 && t[kA] < 5.0 && std::hypot(t[kE1], t[kE2]) < 0.3)) return res;
    double visible = 1.0;  // the share of the marker's light the hint's occluders leave
    if (hint) visible_centroid(cfg, t, p.parity, *hint, res.cx_px, res.cy_px, &visible, 8, 2 * height);
    // A marker mostly hidden: the pipeline's centroid of what is left, and so the start, can be a pixel off (its
    // chroma spread across the occluder's edge), and the pose anchors the fit instead (checked below).
    const bool sliver = hint && visible < cfg.prediction_gate_visible;
    // A marker the field's top or bottom edge cuts, on a source whose chroma chain repeats the edge line (4:2:0):
    // the pipeline's centroid of what is left lies up to 0.65 px inward (the edge line's chroma repeated over the
    // next lines), and the start with it; the pose anchors the fit too (sweep seed 94, FFV1 4:2:0: fits with χ²
    // 0.5–0.9 refused as not anchored). Not the pose's gate below: a field old, it is 0.2–0.3 px off a marker in
    // motion that the edge hardly cuts.
    const bool edge_cut = hint && p.edge_height > 0 && (blob.y_min == 0 || blob.y_max == height - 1);
    const bool anchored = near(x_start, v_start) ||
                          (hint && (blob.foreign_overlap || sliver || edge_cut) &&
                           near(hint->centre_x_px, hint->centre_v_px)) ||
                          (merged && near(mask->keep_x_px, mask->keep_v_px));
    if (!anchored) return res;
    res.hinted = hint != nullptr;
    if (!hint && !f.centroid_from_render(t, res.cx_px, res.cy_px)) {  // with a hint: the visible part's, above
        if (cfg.model == SphereFitModel::kAnalytic)
            intensity_centroid_analytic(cfg, t, p.parity, res.cx_px, res.cy_px);
        else
            intensity_centroid(cfg, t, p.parity, res.cx_px, res.cy_px);
    }
    if (!std::isfinite(res.cx_px) || !std::isfinite(res.cy_px)) return res;
    res.refusal = FitRefusal::kOutliers;
    if (res.outliers > 0 && !res.outlier_band) return res;
    // Both estimate the same centroid; a fit that moves far from the pipeline's has modelled something else (a
    // partly occluded marker's hidden half, a neighbour in the patch). A fit that left observations out has less
    // to stand on: it must agree more closely.
    res.refusal = FitRefusal::kShift;
    // Two markers of one class joined into this blob: its centroid lies between them; the prediction anchors the gate.
    if (merged) {
        const double merged_gate = merged_start ? kMergedStartMaxShiftPx : kMergedMaxShiftPx;
        if (std::hypot(t[kX0] - mask->keep_x_px, 0.5 * (t[kV0] - mask->keep_v_px)) > merged_gate) return res;
        res.refusal = FitRefusal::kNone;
        res.ok = true;
        return res;
    }
    // The pipeline's centroid of a marker mostly hidden is itself off by up to a few tenths of a pixel (few pixels,
    // their chroma spread across the occluder's edge): the gate widens as the visible share shrinks.
    const double gate = (hint && cfg.max_shift_hinted_px > 0 ? cfg.max_shift_hinted_px : cfg.max_shift_px) *
                        (blob.foreign_overlap || (blob.foreign_touch && !hint) ? kForeignOverlapGateScale : 1.0);
    const double max_shift = (res.outliers > 0 ? cfg.max_shift_outliers_px : gate) / std::max(0.3, visible);
    // A sliver (above) is gated by the pose's prediction instead (below): the pipeline's centroid that anchors this
    // gate is what could not be trusted (FFV1 4:1:1 `surgery` seed 145: an eye marker 93 % hidden, fitted 0.11 px
    // from the truth and 2.7 px from the pipeline's centroid).
    if (!sliver && gate_distance(cfg, res.cx_px - cx0, res.cy_px - cy0) > max_shift) return res;
    // A marker mostly hidden leaves the fit a sliver, and the gate above is wide for it: the fit must also lie
    // within the plain gate (not widened by the hidden share) of the visible centroid the pose predicts (the
    // hint's centre, a field old). Sweep seed 14, MPEG-2: an eye marker 77 % behind the eye's outline fitted 1.3 px
    // from the pipeline's centroid and 1.8 px from the truth; seed 6: a light-pipe marker 85 % hidden fitted 0.9 px
    // off where the pipeline's centroid was within 0.2 px.
    if (sliver) {
        Vec tp = t;
        tp[kX0] = hint->centre_x_px;
        tp[kV0] = hint->centre_v_px;
        double px = 0, py = 0;
        visible_centroid(cfg, tp, p.parity, *hint, px, py, nullptr, 8, 2 * height);
        if (gate_distance(cfg, res.cx_px - px, res.cy_px - py) > gate) return res;
    }
    res.refusal = FitRefusal::kNone;
    res.ok = true;
    return res;
}

}  // namespace eyesim::tracking
