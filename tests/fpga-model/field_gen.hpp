#pragma once
/// \file
/// Test helpers: synthetic UYVY fields (label images, anti-aliased markers with noise), the classified mask the
/// pipeline must see (recomputed pixel by pixel), and OpenCV connected components on it as the reference.

#include "eyesim/fpga/colour.hpp"
#include "eyesim/fpga/pipeline.hpp"

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <tuple>
#include <vector>

namespace eyesim::fpga::test {

inline constexpr int W = 720;

/// Default marker colours (sRGB), index = class id (0 = background grey).
inline const std::array<std::array<double, 3>, 5> kColours{{{90, 90, 90},
                                                            {220, 40, 40},
                                                            {40, 200, 60},
                                                            {40, 80, 220},
                                                            {230, 210, 40}}};

/// A UYVY field.
struct Field {
    int height = 288;
    std::vector<uint8_t> bytes;
    explicit Field(int h = 288) : height(h), bytes(static_cast<size_t>(h) * W * 2) {}
    uint8_t* line(int y) { return bytes.data() + static_cast<size_t>(y) * W * 2; }
    const uint8_t* line(int y) const { return bytes.data() + static_cast<size_t>(y) * W * 2; }
};

/// Field from a label image (0 background, 1..4 class): each pair takes the chroma of its even pixel's label;
/// luma is bright for labelled pixels and dark (below every class's luma band) for background, so the mask
/// follows the labels at pixel resolution wherever chroma allows.
inline Field field_from_labels(const cv::Mat1b& labels) {
    Field f(labels.rows);
    for (int y = 0; y < labels.rows; ++y) {
        uint8_t* p = f.line(y);
        for (int k = 0; k < W / 2; ++k) {
            const int l0 = labels(y, 2 * k), l1 = labels(y, 2 * k + 1);
            const int lc = l0 != 0 ? l0 : l1;
            const auto& c = kColours[static_cast<size_t>(lc)];
            const Ycc ycc = rgb_to_ycc(c[0], c[1], c[2]);
            p[4 * k + 0] = to_byte(ycc.cb);
            p[4 * k + 2] = to_byte(ycc.cr);
            p[4 * k + 1] = l0 != 0 ? to_byte(ycc.y) : 18;
            p[4 * k + 3] = l1 != 0 ? to_byte(ycc.y) : 18;
        }
    }
    return f;
}

/// Luma, interpolated chroma (as the datapath computes it) of pixel x of a line.
inline std::tuple<int, int, int> pixel_ycc(const uint8_t* line, int x) {
    const int k = x >> 1;
    const uint8_t* q = line + 4 * k;
    int cb = q[0], cr = q[2];
    if ((x & 1) && k < W / 2 - 1) {
        cb = (cb + q[4] + 1) >> 1;
        cr = (cr + q[6] + 1) >> 1;
    }
    return {q[1 + 2 * (x & 1)], cb, cr};
}

/// Class of every pixel, recomputed pixel by pixel (no runs, no fast path), ROI applied.
inline cv::Mat1b classify_field(const Pipeline& p, const Field& f) {
    cv::Mat1b m(f.height, W, uint8_t{0});
    const PipelineParams& par = p.params();
    for (int y = 0; y < f.height; ++y) {
        for (int x = 0; x < W; ++x) {
            bool in_roi = par.roi_enable == 0;
            for (int w = 0; w < kNumRoiWindows; ++w)
                if ((par.roi_enable >> w) & 1)
                    in_roi = in_roi || (x >= par.roi_x0[w] && x <= par.roi_x1[w] && y >= par.roi_y0[w] &&
                                        y <= par.roi_y1[w]);
            if (!in_roi) continue;
            const auto [yy, cb, cr] = pixel_ycc(f.line(y), x);
            m(y, x) = p.classify(static_cast<uint8_t>(yy), static_cast<uint8_t>(cb), static_cast<uint8_t>(cr));
        }
    }
    return m;
}

/// One reference component (OpenCV) with exact integer and floating weighted sums.
struct RefBlob {
    int cls = 0;
    int area = 0;
    int x0 = 0, y0 = 0, x1 = 0, y1 = 0;
    uint64_t sw = 0, swx = 0, swy = 0, swxx = 0, swyy = 0, swxy = 0;
    double rw = 0, rwx = 0, rwy = 0;
    uint32_t pn = 0;           ///< pixels with w > 0 (component and ring)
    uint64_t psx = 0;          ///< their Σx
    int64_t band_r = 0;        ///< BG_OFFSET band: Σ residual of the chroma samples beside the component's runs
    uint32_t band_n = 0;       ///< and their number
    int ring_pixels = 0;
    bool ring_shared = false;  ///< a ring pixel also touches another blob: the first claim decides, sums skipped
    bool operator<(const RefBlob& o) const {
        return std::tie(cls, y0, x0, area, x1, y1) < std::tie(o.cls, o.y0, o.x0, o.area, o.x1, o.y1);
    }
};

/// True when pixel (x, y) is processed under the pipeline's ROI registers.
inline bool roi_contains(const PipelineParams& par, int x, int y) {
    if (par.roi_enable == 0) return true;
    for (int w = 0; w < kNumRoiWindows; ++w)
        if (((par.roi_enable >> w) & 1) && x >= par.roi_x0[w] && x <= par.roi_x1[w] && y >= par.roi_y0[w] &&
            y <= par.roi_y1[w])
            return true;
    return false;
}

/// BG_TRACK, modelled independently for a whole field: the cell backgrounds in effect while line y is labelled
/// (state[y]). Line y's pixels, and the ring pixels of line y - 1 first claimed from line y, are weighted with
/// state[y], which has learnt from lines up to y - 2: state[0] = state[1] = neutral, and state[y] is state[y - 1]
/// after learning line y - 2, whose cells hold where a classified pixel lies within kBgHoldColumns on lines
/// y - 3 .. y - 1 or a pixel of the cell is outside the ROI windows containing line y - 2.
struct BgReference {
    bool on = false;
    std::vector<std::array<int, 2 * kBgCells>> q4;      ///< per line: Cb, Cr ×16 of every cell
    std::vector<std::array<double, 2 * kBgCells>> fl;   ///< floating counterpart

    /// Background ×128 at pixel x under state[y]: linear between cell centres 8j + 3, clamped at the ends.
    void at(int y, int x, int& cb_q7, int& cr_q7, double& cb, double& cr) const {
        const double pos = std::clamp((x - 3) / 8.0, 0.0, static_cast<double>(kBgCells - 1));
        const int j0 = std::min(static_cast<int>(pos), kBgCells - 2);
        const int f8 = static_cast<int>(std::lround((pos - j0) * 8));
        const auto& s = q4[static_cast<size_t>(y)];
        const auto& d = fl[static_cast<size_t>(y)];
        const size_t i = static_cast<size_t>(2 * j0);
        cb_q7 = s[i] * (8 - f8) + s[i + 2] * f8;
        cr_q7 = s[i + 1] * (8 - f8) + s[i + 3] * f8;
        cb = (d[i] * (8 - f8) + d[i + 2] * f8) / 8;
        cr = (d[i + 1] * (8 - f8) + d[i + 3] * f8) / 8;
    }
};

inline BgReference background_reference(const Pipeline& p, const Field& f, const cv::Mat1b& cls_mask) {
    BgReference r;
    const PipelineParams& par = p.params();
    const int n = par.bg_track_shift;
    r.on = n != 0 && par.weight_mode == 1;
    std::array<int, 2 * kBgCells> s;
    std::array<double, 2 * kBgCells> d;
    s.fill(128 * 16);
    d.fill(128.0);
    std::vector<bool> seeded(kBgCells, false);
    cv::Mat1b hold;
    cv::dilate(cls_mask != 0, hold, cv::getStructuringElement(cv::MORPH_RECT, {2 * kBgHoldColumns + 1, 3}));
    for (int y = 0; y < f.height; ++y) {
        const int yl = y - 2;  // the line state[y] has last learnt
        if (r.on && yl >= 0) {
            for (int j = 0; j < kBgCells; ++j) {
                bool learn = true;
                for (int x = 8 * j; x < 8 * j + 8; ++x) learn = learn && !hold(yl, x) && roi_contains(par, x, yl);
                if (!learn) continue;
                int scb = 0, scr = 0;
                for (int k = 4 * j; k < 4 * j + 4; ++k) {
                    scb += f.line(yl)[4 * k];
                    scr += f.line(yl)[4 * k + 2];
                }
                const size_t i = static_cast<size_t>(2 * j);
                if (!seeded[static_cast<size_t>(j)]) {
                    seeded[static_cast<size_t>(j)] = true;
                    s[i] = 4 * scb;
                    s[i + 1] = 4 * scr;
                    d[i] = scb / 4.0;
                    d[i + 1] = scr / 4.0;
                    continue;
                }
                s[i] += (4 * scb - s[i] + (1 << (n - 1))) >> n;  // the rounding step the register defines
                s[i + 1] += (4 * scr - s[i + 1] + (1 << (n - 1))) >> n;
                d[i] += (scb / 4.0 - d[i]) / (1 << n);
                d[i + 1] += (scr / 4.0 - d[i + 1]) / (1 << n);
            }
        }
        r.q4.push_back(s);
        r.fl.push_back(d);
    }
    return r;
}

/// Adds pixel (x, y) with the weight of class c to b (fixed and floating reference weights), against the
/// background state of line sy when BG_TRACK is on.
inline void add_pixel(const Pipeline& p, const Field& f, int c, int x, int y, RefBlob& b, const BgReference& bg,
                      int sy) {
    const uint8_t* px = f.line(y) + 4 * (x >> 1);
    const int yy = px[1 + 2 * (x & 1)];
    const bool interp = (x & 1) && (x >> 1) < W / 2 - 1;
    const int cb2 = interp ? px[0] + px[4] : 2 * px[0], cr2 = interp ? px[2] + px[6] : 2 * px[2];
    int bcb_q7 = 128 * 128, bcr_q7 = 128 * 128;
    double bcb = 128.0, bcr = 128.0;
    if (bg.on) bg.at(sy, x, bcb_q7, bcr_q7, bcb, bcr);
    const uint64_t w = p.weight2_bg(static_cast<uint8_t>(c), yy, cb2, cr2, bcb_q7, bcr_q7);
    const uint64_t ux = static_cast<uint64_t>(x), uy = static_cast<uint64_t>(y);
    b.sw += w;
    b.swx += w * ux;
    b.swy += w * uy;
    b.swxx += w * ux * ux;
    b.swyy += w * uy * uy;
    b.swxy += w * ux * uy;
    if (w != 0) {
        ++b.pn;
        b.psx += ux;
    }
    // Floating reference: exact mean of the neighbouring chroma pairs, minus the floating background.
    const uint8_t* q = f.line(y) + 4 * (x >> 1);
    double cbd = q[0], crd = q[2];
    if ((x & 1) && (x >> 1) < W / 2 - 1) {
        cbd = 0.5 * (q[0] + q[4]);
        crd = 0.5 * (q[2] + q[6]);
    }
    const double wr = p.weight_reference(static_cast<uint8_t>(c), yy, cbd - bcb + 128.0, crd - bcr + 128.0);
    b.rw += wr;
    b.rwx += wr * x;
    b.rwy += wr * y;
}

/// OpenCV connectedComponentsWithStats (8-connected) per class on the classified mask, plus weighted sums over
/// each component and, with EDGE_RING in a weighted mode, its ring of background pixels (within kRingColumns
/// columns and one line).
inline std::vector<RefBlob> reference_blobs(const Pipeline& p, const Field& f, const cv::Mat1b& cls_mask) {
    std::vector<RefBlob> out;
    const BgReference bg = background_reference(p, f, cls_mask);
    cv::Mat1i comp(f.height, W, -1);
    for (int c = 1; c <= kNumClasses; ++c) {
        cv::Mat1b mask = (cls_mask == c) / 255;
        cv::Mat labels, stats, centroids;
        const int n = cv::connectedComponentsWithStats(mask, labels, stats, centroids, 8, CV_32S);
        const int base = static_cast<int>(out.size());
        for (int i = 1; i < n; ++i) {
            RefBlob b;
            b.cls = c;
            b.area = stats.at<int>(i, cv::CC_STAT_AREA);
            b.x0 = stats.at<int>(i, cv::CC_STAT_LEFT);
            b.y0 = stats.at<int>(i, cv::CC_STAT_TOP);
            b.x1 = b.x0 + stats.at<int>(i, cv::CC_STAT_WIDTH) - 1;
            b.y1 = b.y0 + stats.at<int>(i, cv::CC_STAT_HEIGHT) - 1;
            out.push_back(b);
        }
        for (int y = 0; y < f.height; ++y)
            for (int x = 0; x < W; ++x) {
                const int l = labels.at<int>(y, x);
                if (l == 0) continue;
                comp(y, x) = base + l - 1;
                add_pixel(p, f, c, x, y, out[static_cast<size_t>(base + l - 1)], bg, y);
            }
    }
    const PipelineParams& par = p.params();
    // BG_OFFSET: every maximal span of one component on a line (a run) takes the unclassified chroma samples (even
    // x, inside the ROI) kBandNearColumns..kBandFarColumns columns beside it, weighed against line y's background.
    if (par.bg_offset && par.weight_mode == 1) {
        for (int y = 0; y < f.height; ++y)
            for (int x = 0; x < W;) {
                const int id = comp(y, x);
                if (id < 0) {
                    ++x;
                    continue;
                }
                int x1 = x;
                while (x1 + 1 < W && comp(y, x1 + 1) == id) ++x1;
                RefBlob& b = out[static_cast<size_t>(id)];
                for (int xx = std::max(0, x - kBandFarColumns); xx <= std::min(W - 1, x1 + kBandFarColumns); ++xx) {
                    if ((xx & 1) || (xx > x - kBandNearColumns && xx < x1 + kBandNearColumns)) continue;
                    if (cls_mask(y, xx) != 0 || !roi_contains(par, xx, y)) continue;
                    const uint8_t* q = f.line(y) + 2 * xx;
                    int bcb = 128 * 128, bcr = 128 * 128;
                    double dcb, dcr;
                    if (bg.on) bg.at(y, xx, bcb, bcr, dcb, dcr);
                    b.band_r += p.band_residual(static_cast<uint8_t>(b.cls), 2 * q[0], 2 * q[2], bcb, bcr);
                    ++b.band_n;
                }
                x = x1 + 1;
            }
    }
    if (par.edge_ring && par.weight_mode != 0) {
        for (int y = 0; y < f.height; ++y)
            for (int x = 0; x < W; ++x) {
                if (cls_mask(y, x) != 0 || !roi_contains(par, x, y)) continue;
                int ids[15], n = 0;
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -kRingColumns; dx <= kRingColumns; ++dx) {
                        const int yy = y + dy, xx = x + dx;
                        if (yy < 0 || yy >= f.height || xx < 0 || xx >= W || comp(yy, xx) < 0) continue;
                        const int id = comp(yy, xx);
                        if (std::find(ids, ids + n, id) == ids + n) ids[n++] = id;
                    }
                if (n == 1) {
                    RefBlob& b = out[static_cast<size_t>(ids[0])];
                    // Claimed while line y is labelled when the blob has pixels beside it or on the line above,
                    // else (only above the blob) while line y + 1 is.
                    bool now = false;
                    for (int dy = -1; dy <= 0; ++dy)
                        for (int dx = -kRingColumns; dx <= kRingColumns; ++dx) {
                            const int yy = y + dy, xx = x + dx;
                            now = now || (yy >= 0 && xx >= 0 && xx < W && comp(yy, xx) == ids[0]);
                        }
                    add_pixel(p, f, b.cls, x, y, b, bg, now ? y : y + 1);
                    ++b.ring_pixels;
                } else {
                    for (int i = 0; i < n; ++i) out[static_cast<size_t>(ids[i])].ring_shared = true;
                }
            }
    }
    std::sort(out.begin(), out.end());
    return out;
}

/// Runs a whole field, collecting every emitted blob (sink callback), sorted like RefBlob.
inline std::vector<Blob> run_field(Pipeline& p, const Field& f, uint32_t counter = 0, uint8_t parity = 0) {
    std::vector<Blob> blobs;
    blobs.reserve(1024);
    p.set_sink([](void* ctx, const Blob& b) { static_cast<std::vector<Blob>*>(ctx)->push_back(b); }, &blobs);
    p.process_field(f.bytes.data(), f.height, counter, parity);
    p.set_sink(nullptr, nullptr);
    std::sort(blobs.begin(), blobs.end(), [](const Blob& a, const Blob& b) {
        return std::tie(a.class_id, a.y_min, a.x_min, a.area_px, a.x_max, a.y_max) <
               std::tie(b.class_id, b.y_min, b.x_min, b.area_px, b.x_max, b.y_max);
    });
    return blobs;
}

/// An anti-aliased elliptical marker (frame-px radius r; in the field its vertical radius is r/2).
struct Marker {
    int cls = 1;
    double cx = 0, cy = 0;  ///< field px
    double rx = 4, ry = 2;  ///< field px
};

/// Renders markers over a uniform background with `ss`×`ss` supersampling per pixel, mixes colours in sRGB,
/// filters chroma [1 2 1]/4 co-sited (as BT.656 sources do), adds Gaussian noise (σ in 8-bit codes).
/// `truth` (optional) receives each marker's coverage-weighted centroid over pixel centres, the rig's definition
/// of the truth centroid (luma contribution over the pixel apertures, before noise).
inline Field render_markers(const std::vector<Marker>& markers, double noise_sigma, uint32_t seed, int height = 288,
                            int ss = 8, const std::array<double, 3>& bg = {14, 14, 18},
                            std::vector<std::array<double, 2>>* truth = nullptr) {
    if (truth) truth->clear();
    std::vector<double> Y(static_cast<size_t>(height) * W), CB(Y.size()), CR(Y.size());
    const Ycc bgc = rgb_to_ycc(bg[0], bg[1], bg[2]);
    std::fill(Y.begin(), Y.end(), bgc.y);
    std::fill(CB.begin(), CB.end(), bgc.cb);
    std::fill(CR.begin(), CR.end(), bgc.cr);
    for (const Marker& m : markers) {
        const auto& c = kColours[static_cast<size_t>(m.cls)];
        const Ycc mc = rgb_to_ycc(c[0], c[1], c[2]);
        const int x0 = std::max(0, static_cast<int>(std::floor(m.cx - m.rx - 1)));
        const int x1 = std::min(W - 1, static_cast<int>(std::ceil(m.cx + m.rx + 1)));
        const int y0 = std::max(0, static_cast<int>(std::floor(m.cy - m.ry - 1)));
        const int y1 = std::min(height - 1, static_cast<int>(std::ceil(m.cy + m.ry + 1)));
        double sa = 0, sax = 0, say = 0;
        for (int y = y0; y <= y1; ++y) {
            for (int x = x0; x <= x1; ++x) {
                int hits = 0;
                for (int sy = 0; sy < ss; ++sy)
                    for (int sx = 0; sx < ss; ++sx) {
                        const double px = x - 0.5 + (sx + 0.5) / ss, py = y - 0.5 + (sy + 0.5) / ss;
                        const double u = (px - m.cx) / m.rx, v = (py - m.cy) / m.ry;
                        hits += (u * u + v * v <= 1.0);
                    }
                if (hits == 0) continue;
                const double a = static_cast<double>(hits) / (ss * ss);
                sa += a;
                sax += a * x;
                say += a * y;
                const size_t i = static_cast<size_t>(y) * W + static_cast<size_t>(x);
                Y[i] = (1 - a) * Y[i] + a * mc.y;
                CB[i] = (1 - a) * CB[i] + a * mc.cb;
                CR[i] = (1 - a) * CR[i] + a * mc.cr;
            }
        }
        if (truth) truth->push_back({sa > 0 ? sax / sa : m.cx, sa > 0 ? say / sa : m.cy});
    }
    std::mt19937 rng(seed);
    std::normal_distribution<double> noise(0.0, noise_sigma);
    Field f(height);
    for (int y = 0; y < height; ++y) {
        uint8_t* p = f.line(y);
        const size_t r = static_cast<size_t>(y) * W;
        for (int k = 0; k < W / 2; ++k) {
            const int x = 2 * k;
            const size_t i = r + static_cast<size_t>(x);
            const size_t im = x > 0 ? i - 1 : i;
            const double cb = 0.25 * CB[im] + 0.5 * CB[i] + 0.25 * CB[i + 1];
            const double cr = 0.25 * CR[im] + 0.5 * CR[i] + 0.25 * CR[i + 1];
            p[4 * k + 0] = to_byte(cb + (noise_sigma > 0 ? noise(rng) : 0.0));
            p[4 * k + 1] = to_byte(Y[i] + (noise_sigma > 0 ? noise(rng) : 0.0));
            p[4 * k + 2] = to_byte(cr + (noise_sigma > 0 ? noise(rng) : 0.0));
            p[4 * k + 3] = to_byte(Y[i + 1] + (noise_sigma > 0 ? noise(rng) : 0.0));
        }
    }
    return f;
}

}  // namespace eyesim::fpga::test
