#pragma once
/// \file
/// The fair OpenCV peer of the FPGA model: the same job (every colour class's blobs in a 720×288 UYVY field,
/// subpixel centroids) with the same class definitions (the register map's hue wedges, saturation and luma
/// bands), written as an experienced OpenCV user would, and tuned (docs/bench/fpga-model.md, "The fair peer"):
///
///  1. one full-field pass over the native UYVY bytes (OpenCV universal intrinsics, no colour conversion): per
///     block of 16 px × 8 lines, the bytewise max and min of its chroma give the grey-box test; a block outside
///     the box is then tested pair by pair against the grey disc no class reaches (radius min SAT_MIN less the
///     0.71 an odd pixel's rounding can add), which makes the mask exact; flagged blocks form a coarse mask;
///  2. candidate boxes: the coarse mask's 8-connected components (connectedComponentsWithStats, CV_16U labels),
///     each shrunk to the extent of its pairs outside the disc and widened by the ring and background margins;
///  3. inside each box only: class of every pixel from an exact 256 × 256 Cb/Cr table (odd pixels take the
///     rounded mean of their neighbouring chroma pairs, as the co-siting defines) and the luma band, then per
///     class present connectedComponentsWithStats (8-connected, CV_16U) on the box's classified extent;
///  4. per component: a background chroma plane fitted to the unclassified pairs of a band (5 columns, 2 lines)
///     around its ring, and the centroid of the chroma projection on the class hue minus that plane, minus a
///     level of 2 σ (σ: the band's own scatter about the plane), over the component and its ring (pixels within
///     2 columns and 1 line that no other blob owns).
/// Same output rules as the model: MIN_AREA / MAX_AREA, CLASS_ENABLE, the classes' hue, saturation and luma bands.

#include "detection.hpp"

#include "eyesim/fpga/register_map.hpp"

#include <opencv2/core.hpp>
#include <opencv2/core/hal/intrin.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

namespace eyesim::fpga::bench {

/// Tuning knobs of the peer (the defaults are the tuned peer; the others are the variants tried).
struct OpenCvPeerConfig {
    bool disc_test = true;       ///< blocks outside the grey box tested against the grey disc (false: box only)
    bool contours = false;       ///< candidate boxes from findContours + boundingRect instead of components
    int block_lines = 8;         ///< coarse block height (lines); blocks are 16 px wide
    int ccl = cv::CCL_DEFAULT;   ///< connectedComponentsWithStats algorithm (cv::CCL_WU, CCL_GRANA, CCL_DEFAULT)
    bool plane = true;           ///< background: plane fitted to the band (true) or the band's mean (false)
    double level = 0.0;          ///< subtracted from the projection before clamping at 0 (chroma DN)...
    double level_sigmas = 2.0;   ///< ...plus this many σ of the band's projection about its plane (noise estimate)
    int ring_columns = 2;        ///< ring: pixels within this many columns of the component...
    int ring_lines = 1;          ///< ...and this many lines
    int band_columns = 5;        ///< background band outside the ring: columns...
    int band_lines = 2;          ///< ...and lines
};

/// The fair OpenCV peer (single-threaded when the caller sets cv::setNumThreads(1)); reusable buffers, so one
/// instance per thread.
class OpenCvPeer {
public:
    /// Classes, bands and the area filter from `regs` (the model's register map).
    explicit OpenCvPeer(const RegisterMap& regs = RegisterMap{}, const OpenCvPeerConfig& cfg = {}) : cfg_(cfg) {
        const PipelineParams p = decode(regs);
        min_area_ = static_cast<int>(p.min_area_px);
        max_area_ = static_cast<int>(p.max_area_px);
        int sat_min = 255;
        for (int c = 1; c <= kNumClasses; ++c) {
            const int i = c - 1;
            enabled_[static_cast<size_t>(c)] = (p.class_enable >> i) & 1;
            if (!enabled_[static_cast<size_t>(c)]) continue;
            sat_min = std::min<int>(sat_min, p.sat_min[static_cast<size_t>(i)]);
            luma_min_[static_cast<size_t>(c)] = p.luma_min[static_cast<size_t>(i)];
            luma_max_[static_cast<size_t>(c)] = p.luma_max[static_cast<size_t>(i)];
            const double a = p.hue_centre[static_cast<size_t>(i)] * 2.0 * CV_PI / 256.0;
            dir_cb_[static_cast<size_t>(c)] = std::cos(a);
            dir_cr_[static_cast<size_t>(c)] = std::sin(a);
        }
        // The exact class table: hue = atan2(Cr − 128, Cb − 128) in 1/256 turn, first matching class wins.
        lut_.assign(256 * 256, 0);
        for (int cb = 0; cb < 256; ++cb)
            for (int cr = 0; cr < 256; ++cr) {
                const double dcb = cb - 128.0, dcr = cr - 128.0, sat = std::hypot(dcb, dcr);
                double hue = std::atan2(dcr, dcb) / (2.0 * CV_PI) * 256.0;
                if (hue < 0) hue += 256.0;
                for (int c = 1; c <= kNumClasses; ++c) {
                    const size_t i = static_cast<size_t>(c - 1);
                    if (!enabled_[static_cast<size_t>(c)]) continue;
                    double d = std::fmod(hue - p.hue_centre[i], 256.0);
                    if (d < -128.0) d += 256.0;
                    if (d >= 128.0) d -= 256.0;
                    if (std::fabs(d) <= p.hue_half_width[i] && sat >= p.sat_min[i] && sat <= p.sat_max[i]) {
                        lut_[static_cast<size_t>(cb << 8 | cr)] = static_cast<uint8_t>(c);
                        break;
                    }
                }
            }
        // Full-field test thresholds. Disc: a pair is a candidate when dCb² + dCr² ≥ (sat_min − 0.71)² (an odd
        // pixel's chroma is the mean of two pairs, so it lies in the disc when both do, and its rounding moves it
        // by at most 0.71). Box: the largest square grey box whose every entry is background in the table (a mean
        // of two pairs in the box rounds into the box).
        const double r_min = std::max(0.0, sat_min - 0.7072);
        sat_min_sq_ = static_cast<int>(std::floor(r_min * r_min));
        box_half_ = 0;
        for (int t = 1; t < 128; ++t) {
            bool bg = true;
            for (int cb = 128 - t; cb <= 128 + t && bg; ++cb)
                for (int cr = 128 - t; cr <= 128 + t && bg; ++cr) bg = lut_[static_cast<size_t>(cb << 8 | cr)] == 0;
            if (!bg) break;
            box_half_ = t;
        }
    }

    /// Detections of one field of `height` lines of 720 UYVY pixels (valid until the next call).
    const std::vector<Detection>& run(const uint8_t* uyvy, int height) {
        out_.clear();
        tiles_.clear();
        height_ = height;
        field_ = uyvy;
        coarse_mask(uyvy, height);
        if (cfg_.contours) {
            cv::findContours(coarse_, contours_, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
            for (const auto& c : contours_) add_tile(cv::boundingRect(c));
        } else {
            const int n = cv::connectedComponentsWithStats(coarse_, cc_labels_, cc_stats_, cc_centroids_, 8, CV_16U, cfg_.ccl);
            for (int i = 1; i < n; ++i)
                add_tile(cv::Rect(cc_stats_.at<int>(i, cv::CC_STAT_LEFT), cc_stats_.at<int>(i, cv::CC_STAT_TOP),
                                  cc_stats_.at<int>(i, cv::CC_STAT_WIDTH), cc_stats_.at<int>(i, cv::CC_STAT_HEIGHT)),
                         i);
        }
        if (tiles_.empty()) return out_;
        // The boxes side by side in one buffer, classified in place.
        int buffer_w = 0, buffer_h = 0;
        for (Tile& t : tiles_) {
            t.ox = buffer_w;
            buffer_w += t.w;
            buffer_h = std::max(buffer_h, t.h);
        }
        cls_.create(buffer_h, buffer_w);
        for (Tile& t : tiles_) classify(t);
        // Per box, on the bounding box of its classified pixels only (connectedComponentsWithStats costs ≈ 3 ns
        // a pixel here: one call over all boxes side by side, margins included, cost 2–3× more), per class
        // present; a box's only class needs no mask of its own.
        for (const Tile& t : tiles_) {
            if (t.present == 0) continue;
            const cv::Rect core(t.ox + t.cx0, t.cy0, t.cx1 - t.cx0 + 1, t.cy1 - t.cy0 + 1);
            const cv::Mat1b view = cls_(core);
            for (int c = 1; c <= kNumClasses; ++c) {
                if (!((t.present >> c) & 1)) continue;
                const cv::Mat1b* mask = &view;
                if (t.cls != c) {
                    cv::compare(view, c, class_mask_, cv::CMP_EQ);
                    mask = &class_mask_;
                }
                const int n = cv::connectedComponentsWithStats(*mask, labels_, stats_, centroids_, 8, CV_16U, cfg_.ccl);
                for (int i = 1; i < n; ++i) {
                    const int area = stats_.at<int>(i, cv::CC_STAT_AREA);
                    if (area < min_area_ || area > max_area_) continue;
                    centroid(t, c, i, core,
                             cv::Rect(core.x + stats_.at<int>(i, cv::CC_STAT_LEFT), core.y + stats_.at<int>(i, cv::CC_STAT_TOP),
                                      stats_.at<int>(i, cv::CC_STAT_WIDTH), stats_.at<int>(i, cv::CC_STAT_HEIGHT)));
                }
            }
        }
        return out_;
    }

    /// Half-width of the grey box the box test uses (for the docs).
    int box_half_width() const { return box_half_; }

    static constexpr int kWidth = 720;        ///< pixels per line
    static constexpr int kBlockPixels = 16;   ///< coarse block width (8 chroma pairs)

private:
    struct Tile {
        int x0 = 0, y0 = 0, w = 0, h = 0;  // the box in the field
        int ox = 0;                        // its first column in the buffer
        unsigned present = 0;              // bit c: class c present
        int cls = 0;                       // the single class present; 0 none, -1 several
        int cx0 = 0, cx1 = -1, cy0 = 0, cy1 = -1;  // bounding box of its classified pixels (tile coordinates)
        int kx0 = 0, kx1 = -1, ky0 = 0, ky1 = -1;  // extent of the candidates and their odd neighbours (field)
        int label = -1;                    // its coarse component (-1: from a contour, no check)
        bool foreign = false;              // holds classified pixels of another coarse component
    };
    // Step 1: the coarse mask (one byte per block, 255 where a pair could hold a class). Per block, the
    // bytewise max and min over its lines give the grey-box test in two instructions per vector and line; a
    // block outside the box is then tested pair by pair against the grey disc (exact, and rare: only blocks with
    // colour or noise beyond the box get there).
    void coarse_mask(const uint8_t* uyvy, int height) {
        constexpr int kBlocks = kWidth / kBlockPixels;  // 45
        const int rows = (height + cfg_.block_lines - 1) / cfg_.block_lines;
        coarse_.create(rows, kBlocks);
        const cv::v_uint8x16 mask_uv = cv::v_reinterpret_as_u8(cv::v_setall_u16(0x00FF));
        const cv::v_uint8x16 hi = cv::v_setall_u8(static_cast<uint8_t>(128 + box_half_));
        const cv::v_uint8x16 lo = cv::v_setall_u8(static_cast<uint8_t>(128 - box_half_));
        for (int r = 0; r < rows; ++r) {
            const int ya = r * cfg_.block_lines, yb = std::min(height, ya + cfg_.block_lines);
            const uint8_t* first = uyvy + static_cast<size_t>(ya) * 2 * kWidth;
            uint8_t* row = coarse_.ptr<uint8_t>(r);
            const bool ahead = r + 1 < rows && (r + 2) * cfg_.block_lines <= height;
            for (int b = 0; b < kBlocks; ++b) {  // block by block down its lines (measured faster than line by line)
                const uint8_t* q = first + 32 * b;
                // Four read streams: without a prefetch of the next block row this pass ran at half the speed
                // of a plain read when the fields come from DRAM.
                if (ahead && (b & 1) == 0)
                    for (int y = 0; y < cfg_.block_lines; ++y) __builtin_prefetch(q + (cfg_.block_lines + y) * 2 * kWidth, 0, 0);
                cv::v_uint8x16 max0 = cv::v_load(q), max1 = cv::v_load(q + 16), min0 = max0, min1 = max1;
                for (int y = ya + 1; y < yb; ++y) {
                    q += 2 * kWidth;
                    const cv::v_uint8x16 x0 = cv::v_load(q), x1 = cv::v_load(q + 16);
                    max0 = cv::v_max(max0, x0);
                    min0 = cv::v_min(min0, x0);
                    max1 = cv::v_max(max1, x1);
                    min1 = cv::v_min(min1, x1);
                }
                const cv::v_uint8x16 out = ((cv::v_max(max0, max1) > hi) | (cv::v_min(min0, min1) < lo)) & mask_uv;
                row[b] = cv::v_check_any(out) && (!cfg_.disc_test || block_in_disc(uyvy, b, ya, yb)) ? 255 : 0;
            }
        }
    }

    // True when a pair of block b on lines ya..yb-1 has dCb² + dCr² ≥ sat_min² (16-bit lanes: Cb, Cr alternate,
    // each with the Y above it).
    bool block_in_disc(const uint8_t* uyvy, int b, int ya, int yb) const {
        const cv::v_uint16x8 lo8 = cv::v_setall_u16(0x00FF), c128 = cv::v_setall_u16(128);
        const cv::v_uint32x4 lo16 = cv::v_setall_u32(0xFFFF);
        const cv::v_int32x4 thr = cv::v_setall_s32(sat_min_sq_ - 1);
        cv::v_int32x4 any = cv::v_setzero_s32();
        for (int y = ya; y < yb; ++y)
            for (int h = 0; h < 2; ++h) {
                const uint8_t* q = uyvy + static_cast<size_t>(y) * 2 * kWidth + 32 * b + 16 * h;
                const cv::v_uint16x8 d = cv::v_absdiff(cv::v_load(reinterpret_cast<const uint16_t*>(q)) & lo8, c128);
                const cv::v_uint32x4 sq = cv::v_reinterpret_as_u32(cv::v_mul_wrap(d, d));
                any = any | (cv::v_reinterpret_as_s32((sq & lo16) + (sq >> 16)) > thr);
            }
        return cv::v_check_any(any);
    }

    // Doubled chroma of pixel x of a line: 2·Cb of its pair (even x), the sum of the two pairs' (odd x; the
    // last pixel keeps its own pair's).
    static void chroma2(const uint8_t* line, int x, int& cb2, int& cr2) {
        const int k = x >> 1;
        const uint8_t* q = line + 4 * k;
        const bool odd = (x & 1) && k < kWidth / 2 - 1;
        cb2 = odd ? q[0] + q[4] : 2 * q[0];
        cr2 = odd ? q[2] + q[6] : 2 * q[2];
    }

    static constexpr uint8_t kForeign = 0xFF;  // class image: another coarse component's classified pixel

    // True when pixel (x, y) lies in a block of coarse component `label` (always for label −1).
    bool owns(int label, int x, int y) const {
        return label < 0 || cc_labels_.at<uint16_t>(y / cfg_.block_lines, x / kBlockPixels) == label;
    }

    // Step 2: a candidate box from a coarse component: the tight extent of its pairs outside the grey disc
    // (scalar: a few hundred pairs), widened by the odd pixel beside a pair, the ring and the background band.
    void add_tile(const cv::Rect& blocks, int label = -1) {
        const int ky0 = blocks.x * kBlockPixels / 2, ky1 = (blocks.x + blocks.width) * kBlockPixels / 2;
        const int ly0 = blocks.y * cfg_.block_lines, ly1 = std::min(height_, (blocks.y + blocks.height) * cfg_.block_lines);
        int kmin = kWidth, kmax = -1, lmin = height_, lmax = -1;
        for (int y = ly0; y < ly1; ++y) {
            const uint8_t* line = field_ + static_cast<size_t>(y) * 2 * kWidth;
            for (int k = ky0; k < ky1; ++k) {
                if (!owns(label, 2 * k, y)) continue;
                const int du = line[4 * k] - 128, dv = line[4 * k + 2] - 128;
                if (du * du + dv * dv < sat_min_sq_) continue;
                kmin = std::min(kmin, k);
                kmax = std::max(kmax, k);
                lmin = std::min(lmin, y);
                lmax = y;
            }
        }
        if (kmax < 0) return;
        const int mx = 1 + cfg_.ring_columns + cfg_.band_columns, my = cfg_.ring_lines + cfg_.band_lines;
        Tile t;
        t.label = label;
        t.kx0 = 2 * kmin - 1;
        t.kx1 = 2 * kmax + 1;
        t.ky0 = lmin;
        t.ky1 = lmax;
        t.x0 = std::max(0, 2 * kmin - mx);
        t.y0 = std::max(0, lmin - my);
        t.w = std::min(kWidth - 1, 2 * kmax + mx) - t.x0 + 1;
        t.h = std::min(height_ - 1, lmax + my) - t.y0 + 1;
        tiles_.push_back(t);
    }

    // Step 3: class of every pixel of a box (exact table on the pixel's chroma, luma band), into the box's place
    // in the buffer.
    void classify(Tile& t) {
        unsigned present = 0;
        t.cx0 = t.w;
        t.cx1 = -1;
        t.cy0 = t.h;
        t.cy1 = -1;
        // Only the candidates' extent (pairs outside the disc, their odd neighbours) can hold a class; the
        // weights read the chroma from the field.
        const int kx0 = std::max(0, t.kx0 - t.x0), kx1 = std::min(t.w - 1, t.kx1 - t.x0);
        for (int y = 0; y < t.h; ++y) {
            const uint8_t* line = field_ + static_cast<size_t>(t.y0 + y) * 2 * kWidth;
            uint8_t* cl = cls_.ptr<uint8_t>(y) + t.ox;
            std::fill_n(cl, t.w, uint8_t{0});
            if (t.y0 + y < t.ky0 || t.y0 + y > t.ky1) continue;
            for (int i = kx0; i <= kx1; ++i) {
                int cb2, cr2;
                chroma2(line, t.x0 + i, cb2, cr2);
                const int x = t.x0 + i;
                uint8_t c = lut_[static_cast<size_t>(((cb2 + 1) >> 1) << 8 | ((cr2 + 1) >> 1))];
                const int luma = field_[static_cast<size_t>(t.y0 + y) * 2 * kWidth + 2 * static_cast<size_t>(x) + 1];
                if (c != 0 && (luma < luma_min_[c] || luma > luma_max_[c])) c = 0;
                // A pixel of another coarse component (a box may reach into another's bounding box): not
                // labelled here, and kept out of this box's rings and bands.
                if (c != 0 && !(owns(t.label, x, t.y0 + y) || ((x & 1) && x + 1 < kWidth && owns(t.label, x + 1, t.y0 + y)))) {
                    cl[i] = kForeign;
                    t.foreign = true;
                    continue;
                }
                cl[i] = c;
                present |= 1u << c;
                if (c != 0) {
                    t.cx0 = std::min(t.cx0, i);
                    t.cx1 = std::max(t.cx1, i);
                    t.cy0 = std::min(t.cy0, y);
                    t.cy1 = y;
                }
            }
        }
        t.present = present & ~1u;
        t.cls = 0;
        for (int c = 1; c <= kNumClasses; ++c)
            if (t.present == (1u << c)) t.cls = c;
        if (t.present != 0 && (t.cls == 0 || t.foreign)) t.cls = -1;  // several classes, or foreign pixels
    }

    // Step 4: background plane and weighted centroid of component `label` of class c (box coordinates).
    void centroid(const Tile& t, int c, int label, const cv::Rect& core, const cv::Rect& r) {
        // Ring window and the band around it (buffer coordinates, clipped to the box's tile).
        const int tx0 = t.ox, tx1 = t.ox + t.w - 1, ty1 = t.h - 1;
        const int wx0 = std::max(tx0, r.x - cfg_.ring_columns), wx1 = std::min(tx1, r.x + r.width - 1 + cfg_.ring_columns);
        const int wy0 = std::max(0, r.y - cfg_.ring_lines), wy1 = std::min(ty1, r.y + r.height - 1 + cfg_.ring_lines);
        const int ox0 = std::max(tx0, wx0 - cfg_.band_columns), ox1 = std::min(tx1, wx1 + cfg_.band_columns);
        const int oy0 = std::max(0, wy0 - cfg_.band_lines), oy1 = std::min(ty1, wy1 + cfg_.band_lines);
        const int bx0 = t.x0 - t.ox, by0 = t.y0;  // field = buffer + (bx0, by0)
        const double cx = 0.5 * (wx0 + wx1), cy = 0.5 * (wy0 + wy1);
        // Background: the band's unclassified pixels at chroma sample positions (even x), least squares plane
        // b(x, y) = a + bx·(x − cx) + by·(y − cy) for Cb and Cr (or their means).
        double n = 0, sx = 0, sy = 0, sxx = 0, sxy = 0, syy = 0;
        double sb = 0, sbx = 0, sby = 0, sr = 0, srx = 0, sry = 0, sbb = 0, sbr = 0, srr = 0;
        for (int y = oy0; y <= oy1; ++y) {
            const uint8_t* cl = cls_.ptr<uint8_t>(y);
            const uint8_t* line = field_ + static_cast<size_t>(by0 + y) * 2 * kWidth;
            const bool inside_lines = y >= wy0 && y <= wy1;
            for (int x = ox0 + ((bx0 + ox0) & 1); x <= ox1; x += 2) {
                if ((inside_lines && x >= wx0 && x <= wx1) || cl[x] != 0) continue;
                const uint8_t* q = line + 2 * (bx0 + x);  // an even pixel: its own pair's chroma
                const double dx = x - cx, dy = y - cy, vb = q[0], vr = q[2];
                n += 1;
                sx += dx;
                sy += dy;
                sxx += dx * dx;
                sxy += dx * dy;
                syy += dy * dy;
                sb += vb;
                sbx += vb * dx;
                sby += vb * dy;
                sr += vr;
                srx += vr * dx;
                sry += vr * dy;
                sbb += vb * vb;
                sbr += vb * vr;
                srr += vr * vr;
            }
        }
        double ab = 128, gbx = 0, gby = 0, ar = 128, grx = 0, gry = 0;
        bool planar = false;
        if (n > 0) {
            ab = sb / n;
            ar = sr / n;
            const double det = n * (sxx * syy - sxy * sxy) - sx * (sx * syy - sxy * sy) + sy * (sx * sxy - sxx * sy);
            if (cfg_.plane && n >= 6 && std::fabs(det) > 1e-6 * n * n * n) {
                auto solve = [&](double s0, double s1, double s2, double& a, double& gx, double& gy) {
                    // Cramer's rule on [n sx sy; sx sxx sxy; sy sxy syy] · (a, gx, gy) = (s0, s1, s2).
                    a = (s0 * (sxx * syy - sxy * sxy) - sx * (s1 * syy - sxy * s2) + sy * (s1 * sxy - sxx * s2)) / det;
                    gx = (n * (s1 * syy - sxy * s2) - s0 * (sx * syy - sxy * sy) + sy * (sx * s2 - s1 * sy)) / det;
                    gy = (n * (sxx * s2 - s1 * sxy) - sx * (sx * s2 - s1 * sy) + s0 * (sx * sxy - sxx * sy)) / det;
                };
                solve(sb, sbx, sby, ab, gbx, gby);
                solve(sr, srx, sry, ar, grx, gry);
                planar = true;
            }
        }
        const double dcb = dir_cb_[static_cast<size_t>(c)], dcr = dir_cr_[static_cast<size_t>(c)];
        // The level: noise of the projection p about the fitted background, RSS = Σp² − fit · Xᵀp.
        double level = cfg_.level;
        const double dof = n - (planar ? 3 : 1);
        if (cfg_.level_sigmas > 0 && dof >= 3) {
            const double spp = dcb * dcb * sbb + 2 * dcb * dcr * sbr + dcr * dcr * srr;
            const double rss = spp - (ab * dcb + ar * dcr) * (dcb * sb + dcr * sr) -
                               (gbx * dcb + grx * dcr) * (dcb * sbx + dcr * srx) -
                               (gby * dcb + gry * dcr) * (dcb * sby + dcr * sry);
            level += cfg_.level_sigmas * std::sqrt(std::max(0.0, rss) / dof);
        }
        // Weights: projection on the class hue of (chroma − background) − level, over the component and the
        // pixels of the ring no other blob owns.
        double sw = 0, swx = 0, swy = 0;
        for (int y = wy0; y <= wy1; ++y) {
            const uint8_t* cl = cls_.ptr<uint8_t>(y);
            // Labels exist on the classified pixels' box only, and only classified pixels are looked up.
            const uint16_t* lb = y >= core.y && y < core.y + core.height ? labels_.ptr<uint16_t>(y - core.y) - core.x : nullptr;
            const uint8_t* line = field_ + static_cast<size_t>(by0 + y) * 2 * kWidth;
            const double dy = y - cy;
            // Projection of the background plane along the line, as a linear function of x − cx.
            const double p0 = (ab + gby * dy) * dcb + (ar + gry * dy) * dcr, px = gbx * dcb + grx * dcr;
            for (int x = wx0; x <= wx1; ++x) {
                if (cl[x] != 0 && !(cl[x] == c && lb[x] == label)) continue;
                int cb2, cr2;
                chroma2(line, bx0 + x, cb2, cr2);
                const double v = 0.5 * (cb2 * dcb + cr2 * dcr) - p0 - px * (x - cx) - level;
                if (v <= 0) continue;
                sw += v;
                swx += v * x;
                swy += v * y;
            }
        }
        if (sw > 0) out_.push_back({c, bx0 + swx / sw, by0 + swy / sw});
    }

    OpenCvPeerConfig cfg_;
    std::vector<uint8_t> lut_;
    std::array<bool, kNumClasses + 1> enabled_{};
    std::array<int, kNumClasses + 1> luma_min_{}, luma_max_{};
    std::array<double, kNumClasses + 1> dir_cb_{}, dir_cr_{};
    int sat_min_sq_ = 0, box_half_ = 0, min_area_ = 1, max_area_ = kWidth * 288;
    std::vector<Tile> tiles_;
    int height_ = 0;
    const uint8_t* field_ = nullptr;
    cv::Mat1b coarse_, cls_, class_mask_;
    cv::Mat cc_labels_, cc_stats_, cc_centroids_, labels_, stats_, centroids_;
    std::vector<std::vector<cv::Point>> contours_;
    std::vector<Detection> out_;
};

}  // namespace eyesim::fpga::bench
