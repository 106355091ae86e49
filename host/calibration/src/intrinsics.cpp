#include "eyesim/calibration/intrinsics.hpp"

#include "eyesim/rig/pal.hpp"
#include "eyesim/rig/recording.hpp"

#include <fmt/format.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/LU>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <stdexcept>

namespace eyesim::calibration {

namespace {

constexpr int kCoverageCols = 16, kCoverageRows = 12;
/// A view is an outlier beyond 3× the median view RMS, but never below this (frame px).
constexpr double kOutlierFloorPx = 0.02;

/// Luma of a UYVY field (720 × 288).
void uyvy_luma(const std::vector<uint8_t>& uyvy, cv::Mat& out) {
    out.create(rig::kFieldHeight, rig::kFieldWidth, CV_8U);
    for (int y = 0; y < rig::kFieldHeight; ++y) {
        const uint8_t* in = uyvy.data() + static_cast<size_t>(y) * rig::kFieldWidth * 2;
        uint8_t* o = out.ptr<uint8_t>(y);
        for (int x = 0; x < rig::kFieldWidth; ++x) o[x] = in[2 * x + 1];
    }
}

/// Puts detection `b` in the corner order of `a`, the previous detection of the same board (the detector may
/// number a symmetric board from either end).
void align_to(const std::vector<cv::Point2f>& a, std::vector<cv::Point2f>& b) {
    if (a.size() != b.size() || a.empty()) return;
    if (cv::norm(b.front() - a.front()) > cv::norm(b.back() - a.front())) std::reverse(b.begin(), b.end());
}

/// Largest corner displacement between two detections in the same corner order.
double max_displacement(const std::vector<cv::Point2f>& a, const std::vector<cv::Point2f>& b) {
    if (a.size() != b.size() || a.empty()) return HUGE_VAL;
    double m = 0;
    for (size_t i = 0; i < a.size(); ++i) m = std::max(m, static_cast<double>(cv::norm(b[i] - a[i])));
    return m;
}

/// What a view looks like, for spreading the selection: image position, size and foreshortening.
std::vector<double> view_descriptor(const std::vector<cv::Point2f>& c, int cols, int rows) {
    const cv::Point2f p00 = c[0], p10 = c[static_cast<size_t>(cols - 1)], p01 = c[static_cast<size_t>((rows - 1) * cols)],
                      p11 = c.back();
    cv::Point2f m(0, 0);
    for (const auto& p : c) m += p;
    m *= 1.0f / static_cast<float>(c.size());
    const double top = cv::norm(p10 - p00), bottom = cv::norm(p11 - p01);
    const double left = cv::norm(p01 - p00), right = cv::norm(p11 - p10);
    const double size = std::sqrt(std::max(1e-9, (top + bottom) * (left + right) / 4));
    return {m.x / rig::kFrameWidth, m.y / rig::kFrameHeight, std::log(size / 100.0),
            std::log(std::max(1e-9, top) / std::max(1e-9, bottom)), std::log(std::max(1e-9, left) / std::max(1e-9, right))};
}

}  // namespace

std::vector<cv::Point2f> find_board_corners(const cv::Mat& luma, int parity, int board_cols, int board_rows) {
    std::vector<cv::Point2f> corners;
    cv::Mat img = luma;
    if (parity >= 0) {
        // A field row spans two frame rows: stretch it to frame geometry so the detector sees square squares.
        // cv::resize samples destination row r at source row (r + 0.5) / 2 - 0.5, i.e. frame row 2y + p = r - 0.5 + p.
        cv::resize(luma, img, cv::Size(rig::kFrameWidth, rig::kFrameHeight), 0, 0, cv::INTER_LINEAR);
    }
    const int flags = cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_FAST_CHECK;
    if (!cv::findChessboardCorners(img, cv::Size(board_cols, board_rows), corners, flags)) return {};
    if (static_cast<int>(corners.size()) != board_cols * board_rows) return {};
    // Window: up to 8 px each side, within about a third of the smallest square seen.
    double step = HUGE_VAL;
    for (int r = 0; r < board_rows; ++r)
        for (int c = 0; c + 1 < board_cols; ++c)
            step = std::min(step, static_cast<double>(cv::norm(corners[static_cast<size_t>(r * board_cols + c + 1)] -
                                                               corners[static_cast<size_t>(r * board_cols + c)])));
    const int half = std::clamp(static_cast<int>(step / 3), 2, 8);
    cv::cornerSubPix(img, corners, cv::Size(half, half), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-4));
    if (parity >= 0)
        for (auto& p : corners) p.y += static_cast<float>(parity - 0.5);
    return corners;
}

namespace {

/// One luma sample in frame coordinates, and its photometric group (BoardImage::group).
struct Sample {
    double u, v, luma;
    int group;
};

/// Fits the corner model (see refine_board_corners) to `s`; `x` holds the start and gets the result: the geometry
/// u0 v0 θ1 θ2 ln σ, then per photometric group its levels and shading m gx gy a hx hy. `info` (may be null) gets
/// the information matrix of (u0, v0). Returns false when the fit fails.
bool fit_corner(const std::vector<Sample>& s, int groups, Eigen::VectorXd& x, Eigen::Matrix2d* info) {
    const int n = 5 + 6 * groups;
    constexpr int kN = 3;  // kN × kN points over the pixel square
    constexpr double kSub[kN] = {-1.0 / 3.0, 0.0, 1.0 / 3.0};
    constexpr double kNN = kN * kN;
    const double kSqrt2 = std::sqrt(2.0), kTwoOverSqrtPi = 2.0 / std::sqrt(3.14159265358979323846);
    // Squared residual sum at p, and (when JtJ is given) JᵀJ and Jᵀr.
    Eigen::VectorXd g(n);
    auto eval = [&](const Eigen::VectorXd& p, Eigen::MatrixXd* JtJ, Eigen::VectorXd* Jtr) {
        const double c1 = std::cos(p[2]), s1 = std::sin(p[2]), c2 = std::cos(p[3]), s2 = std::sin(p[3]);
        const double sigma = std::exp(p[4]), k = 1.0 / (kSqrt2 * sigma);
        double sum2 = 0;
        if (JtJ) JtJ->setZero(n, n), Jtr->setZero(n);
        for (const Sample& q : s) {
            const int o = 5 + 6 * q.group;  // this sample's levels and shading
            const double m = p[o], gx = p[o + 1], gy = p[o + 2], a = p[o + 3], hx = p[o + 4], hy = p[o + 5];
            double f = 0;
            g.setZero();
            for (int iv = 0; iv < kN; ++iv)
                for (int iu = 0; iu < kN; ++iu) {
                    const double px = q.u + kSub[iu] - p[0], py = q.v + kSub[iv] - p[1];
                    const double d1 = c1 * px + s1 * py, d2 = c2 * px + s2 * py;
                    const double e1 = std::erf(d1 * k), e2 = std::erf(d2 * k);
                    const double E = e1 * e2, L = 1 + hx * px + hy * py;
                    f += m + gx * px + gy * py + a * L * E;
                    if (!JtJ) continue;
                    const double de1 = kTwoOverSqrtPi * std::exp(-d1 * d1 * k * k) * k;  // d e1 / d d1
                    const double de2 = kTwoOverSqrtPi * std::exp(-d2 * d2 * k * k) * k;
                    const double aL = a * L;
                    g[0] += -gx - a * hx * E - aL * (de1 * c1 * e2 + e1 * de2 * c2);
                    g[1] += -gy - a * hy * E - aL * (de1 * s1 * e2 + e1 * de2 * s2);
                    g[2] += aL * de1 * (-s1 * px + c1 * py) * e2;
                    g[3] += aL * e1 * de2 * (-s2 * px + c2 * py);
                    g[4] += aL * (-d1 * de1 * e2 - e1 * d2 * de2);
                    g[o] += 1;
                    g[o + 1] += px;
                    g[o + 2] += py;
                    g[o + 3] += L * E;
                    g[o + 4] += a * px * E;
                    g[o + 5] += a * py * E;
                }
            const double r = f / kNN - q.luma;
            sum2 += r * r;
            if (JtJ) {
                g /= kNN;
                JtJ->selfadjointView<Eigen::Upper>().rankUpdate(g);
                *Jtr += g * r;
            }
        }
        if (JtJ) *JtJ = JtJ->selfadjointView<Eigen::Upper>();
        return sum2;
    };
    Eigen::MatrixXd A;
    Eigen::VectorXd b;
    double cost = eval(x, &A, &b);
    double lambda = 1e-3;
    const Eigen::Vector2d start(x[0], x[1]);
    for (int it = 0; it < 50; ++it) {
        Eigen::MatrixXd H = A;
        H.diagonal() += lambda * A.diagonal().cwiseMax(1e-9);
        const Eigen::VectorXd step = H.ldlt().solve(-b);
        if (!step.allFinite()) return false;
        const Eigen::VectorXd xn = x + step;
        const double cn = eval(xn, nullptr, nullptr);
        if (cn < cost) {
            x = xn;
            const bool done = std::hypot(step[0], step[1]) < 1e-6 && cost - cn < 1e-10 * cost;
            cost = eval(x, &A, &b);
            lambda = std::max(1e-9, lambda * 0.3);
            if (done) break;
        } else {
            lambda *= 10;
            if (lambda > 1e8) break;
        }
    }
    if (info) {
        // Information of the corner position with the other parameters marginalised: inverse of the 2 × 2 block of
        // (JᵀJ)⁻¹ (up to the noise variance).
        const Eigen::MatrixXd cov = A.ldlt().solve(Eigen::MatrixXd::Identity(n, n));
        *info = cov.topLeftCorner<2, 2>().inverse();
        if (!info->allFinite()) info->setZero();
    }
    bool levels_ok = true;
    for (int gi = 0; gi < groups; ++gi) levels_ok = levels_ok && std::abs(x[5 + 6 * gi + 3]) > 5.0;
    return x.allFinite() && std::hypot(x[0] - start.x(), x[1] - start.y()) < 1.5 && std::exp(x[4]) < 5.0 && levels_ok;
}

}  // namespace

int refine_board_corners(const std::vector<BoardImage>& images, int cols, int rows, std::vector<cv::Point2f>& corners,
                         std::vector<cv::Matx22d>* information) {
    if (information) information->assign(corners.size(), cv::Matx22d::zeros());
    if (static_cast<int>(corners.size()) != cols * rows || images.empty()) return 0;
    std::vector<cv::Point2f> out = corners;
    std::vector<cv::Matx22d> infos(corners.size(), cv::Matx22d::zeros());
    int refined = 0;
    std::vector<Sample> samples;
    for (int r = 0; r < rows; ++r)
        for (int c = 0; c < cols; ++c) {
            const size_t i = static_cast<size_t>(r * cols + c);
            // Directions along the board's row and column through this corner, from its neighbours.
            const cv::Point2f row_dir = corners[static_cast<size_t>(r * cols + std::min(c + 1, cols - 1))] -
                                        corners[static_cast<size_t>(r * cols + std::max(c - 1, 0))];
            const cv::Point2f col_dir = corners[static_cast<size_t>(std::min(r + 1, rows - 1) * cols + c)] -
                                        corners[static_cast<size_t>(std::max(r - 1, 0) * cols + c)];
            const double row_step = cv::norm(row_dir) / (c > 0 && c < cols - 1 ? 2.0 : 1.0);
            const double col_step = cv::norm(col_dir) / (r > 0 && r < rows - 1 ? 2.0 : 1.0);
            // Stay inside the four squares round the corner (their edges are the only ones in the window).
            const double w = std::clamp(0.4 * std::min(row_step, col_step), 3.0, 10.0);
            const double u0 = corners[i].x, v0 = corners[i].y;
            samples.clear();
            int groups = 0;
            for (const BoardImage& im : images) {
                if (im.group < 0 || im.group > 7) return 0;
                groups = std::max(groups, im.group + 1);
                const int y0 = std::max(0, static_cast<int>(std::ceil((v0 - w - im.row_offset) / im.row_scale)));
                const int y1 = std::min(im.luma.rows - 1, static_cast<int>(std::floor((v0 + w - im.row_offset) / im.row_scale)));
                const int x0 = std::max(0, static_cast<int>(std::ceil(u0 - w)));
                const int x1 = std::min(im.luma.cols - 1, static_cast<int>(std::floor(u0 + w)));
                for (int y = y0; y <= y1; ++y) {
                    const double v = static_cast<double>(im.row_scale) * y + im.row_offset;
                    const float* row = im.luma.ptr<float>(y);
                    for (int x = x0; x <= x1; ++x)
                        if ((x - u0) * (x - u0) + (v - v0) * (v - v0) <= w * w)
                            samples.push_back({double(x), v, double(row[x]), im.group});
                }
            }
            if (samples.size() < 24) continue;
            {
                // Only the groups with samples here, numbered from 0.
                int remap[8], present = 0;
                for (int gi = 0; gi < 8; ++gi) remap[gi] = -1;
                for (const Sample& q : samples)
                    if (remap[q.group] < 0) remap[q.group] = present++;
                for (Sample& q : samples) q.group = remap[q.group];
                groups = present;
            }
            Eigen::VectorXd x = Eigen::VectorXd::Zero(5 + 6 * groups);
            x[0] = u0;
            x[1] = v0;
            x[2] = std::atan2(row_dir.x, -row_dir.y);
            x[3] = std::atan2(col_dir.x, -col_dir.y);
            x[4] = std::log(0.6);
            // Levels of each group: linear least squares for m and a with the starting geometry.
            {
                const double k = 1.0 / (std::sqrt(2.0) * 0.6);
                std::vector<Eigen::Matrix2d> M(static_cast<size_t>(groups), Eigen::Matrix2d::Zero());
                std::vector<Eigen::Vector2d> y(static_cast<size_t>(groups), Eigen::Vector2d::Zero());
                for (const Sample& q : samples) {
                    const double px = q.u - u0, py = q.v - v0;
                    const double E = std::erf((std::cos(x[2]) * px + std::sin(x[2]) * py) * k) *
                                     std::erf((std::cos(x[3]) * px + std::sin(x[3]) * py) * k);
                    const Eigen::Vector2d a(1.0, E);
                    M[static_cast<size_t>(q.group)] += a * a.transpose();
                    y[static_cast<size_t>(q.group)] += a * q.luma;
                }
                for (int gi = 0; gi < groups; ++gi) {
                    if (!(M[static_cast<size_t>(gi)].determinant() > 0)) continue;  // a group with no sample here
                    const Eigen::Vector2d ma = M[static_cast<size_t>(gi)].ldlt().solve(y[static_cast<size_t>(gi)]);
                    x[5 + 6 * gi] = ma[0];
                    x[5 + 6 * gi + 3] = ma[1];
                }
            }
            Eigen::Matrix2d inf;
            if (!fit_corner(samples, groups, x, &inf)) continue;
            out[i] = cv::Point2f(static_cast<float>(x[0]), static_cast<float>(x[1]));
            infos[i] = cv::Matx22d(inf(0, 0), inf(0, 1), inf(1, 0), inf(1, 1));
            ++refined;
        }
    corners = out;
    if (information) *information = infos;
    return refined;
}

double monotonic_max_r2(const std::array<double, 5>& dist) {
    // d/dr [r (1 + k1 r² + k2 r⁴ + k3 r⁶)] = 1 + 3 k1 r² + 5 k2 r⁴ + 7 k3 r⁶ must stay positive.
    const double k1 = dist[0], k2 = dist[1], k3 = dist[4];
    double r2 = 0;
    for (; r2 < 2.0; r2 += 1e-3)
        if (1 + 3 * k1 * r2 + 5 * k2 * r2 * r2 + 7 * k3 * r2 * r2 * r2 <= 0) break;
    return 0.9 * std::min(r2, 2.0);
}

IntrinsicsError compare_intrinsics(const rig::CameraModel& est, const rig::CameraModel& truth) {
    IntrinsicsError e;
    e.fx_error_pct = (est.fx - truth.fx) / truth.fx * 100.0;
    e.fy_error_pct = (est.fy - truth.fy) / truth.fy * 100.0;
    e.cx_error_px = est.cx - truth.cx;
    e.cy_error_px = est.cy - truth.cy;
    double sum2 = 0;
    int n = 0;
    for (int v = 0; v < rig::kFrameHeight; v += 8)
        for (int u = 0; u < rig::kFrameWidth; u += 8) {
            const Eigen::Vector2d px(u, v);
            const auto q = truth.undistort_to_normalized(px);
            if (!q) continue;
            const Eigen::Vector2d d = est.distort_normalized(*q) - px;
            e.max_image_error_px = std::max(e.max_image_error_px, d.norm());
            sum2 += d.squaredNorm();
            ++n;
            // Distortion displacement of the same ray under each model (its own K).
            const Eigen::Vector2d lin_est(est.fx * q->x() + est.cx, est.fy * q->y() + est.cy);
            const Eigen::Vector2d lin_true(truth.fx * q->x() + truth.cx, truth.fy * q->y() + truth.cy);
            const Eigen::Vector2d dd = (est.distort_normalized(*q) - lin_est) - (px - lin_true);
            e.max_distortion_error_px = std::max(e.max_distortion_error_px, dd.norm());
        }
    e.rms_image_error_px = n ? std::sqrt(sum2 / n) : 0.0;
    return e;
}

IntrinsicsResult calibrate_intrinsics(rig::Recording& rec, int cam, const IntrinsicsOptions& opt,
                                      const Progress& progress) {
    if (cam < 0 || cam >= rec.camera_count())
        throw std::invalid_argument(fmt::format("camera: {} is not in the recording (0..{})", cam, rec.camera_count() - 1));
    if (opt.board_cols < 2 || opt.board_rows < 2 || opt.board_cols == opt.board_rows)
        throw std::invalid_argument(fmt::format("board: inner corners must be at least 2 × 2 and not square, got {} × {}",
                                                opt.board_cols, opt.board_rows));
    if (!(opt.square_mm > 0) || !std::isfinite(opt.square_mm))
        throw std::invalid_argument(fmt::format("board: square_mm must be positive, got {}", opt.square_mm));
    if (opt.field_step < 1) throw std::invalid_argument(fmt::format("field_step: must be >= 1, got {}", opt.field_step));
    if (opt.max_views < 3) throw std::invalid_argument(fmt::format("max_views: must be >= 3, got {}", opt.max_views));
    if (!(opt.still_px > 0)) throw std::invalid_argument(fmt::format("still_px: must be positive, got {}", opt.still_px));

    const rig::CameraModel& cam_in = rec.cameras()[static_cast<size_t>(cam)];
    const std::string& name = cam_in.name;
    int64_t fields = rec.field_count(cam);
    if (opt.max_fields >= 0) fields = std::min(fields, opt.max_fields);
    const int cols = opt.board_cols, rows = opt.board_rows;

    IntrinsicsResult res;
    // 1. Scan: find the board in single fields (woven: the first field of each frame; its corners are only the
    // starting point, the refinement below uses both fields).
    struct Scan {
        int64_t field;                     // field searched
        std::vector<cv::Point2f> corners;  // frame px; empty: board not found
    };
    std::vector<Scan> scans;
    std::vector<uint8_t> buf(rig::kFieldBytes);
    cv::Mat luma;
    const int64_t step = opt.woven_frames ? 2 * static_cast<int64_t>(opt.field_step) : opt.field_step;
    ProgressInfo info;
    info.phase = ProgressInfo::Phase::kDetect;
    info.total = opt.woven_frames ? fields / step : (fields + step - 1) / step;
    info.samples_per_camera.assign(static_cast<size_t>(rec.camera_count()), 0);
    for (int64_t i = 0; i < fields; i += step) {
        if (opt.woven_frames && i + 1 >= fields) break;
        Scan sc{i, {}};
        rec.read_field(cam, i, buf.data());
        uyvy_luma(buf, luma);
        sc.corners = find_board_corners(luma, rec.field_parity(cam, i), cols, rows);
        if (!sc.corners.empty()) ++res.fields_seen;
        scans.push_back(std::move(sc));
        ++res.scans;
        if (progress) {
            info.done = res.scans;
            info.samples_per_camera[static_cast<size_t>(cam)] = res.fields_seen;
            progress(info);
        }
    }
    if (res.fields_seen == 0)
        throw CalibrationError(fmt::format("{}: the {} × {} checkerboard (inner corners) was not found in any of {} fields scanned",
                                           name, cols, rows, res.scans));

    // 2. Still scans, grouped into holds. A field is compared with the nearest scanned field of the same parity:
    // the two parities sample the board's edges at different rows, so their coarse corners differ by more than
    // noise even when the board is still.
    const size_t ns = scans.size();
    const size_t lag = !opt.woven_frames && (opt.field_step & 1) ? 2 : 1;
    // Every detection in the order of the previous one (the detector may number the board from either end).
    for (size_t k = 1; k < ns; ++k) align_to(scans[k - 1].corners, scans[k].corners);
    std::vector<double> move_to_next(ns, HUGE_VAL);  // [k]: scan k against scan k + lag
    for (size_t k = 0; k + lag < ns; ++k) move_to_next[k] = max_displacement(scans[k].corners, scans[k + lag].corners);
    struct Hold {
        std::vector<size_t> scans;  // still scans
    };
    std::vector<Hold> holds;
    // Still scans up to `lag` apart belong to one hold (the other parity's field between them may not have been
    // found, or not still by its own comparisons), when they agree with each other.
    size_t last_still = 0;
    bool any = false;
    for (size_t k = lag; k + lag < ns; ++k) {
        const bool still = move_to_next[k - lag] <= opt.still_px && move_to_next[k] <= opt.still_px;
        if (!still) continue;
        const bool joins = any && k - last_still <= lag &&
                           max_displacement(scans[last_still].corners, scans[k].corners) <= 2 * opt.still_px + 1.0;
        if (!joins) holds.emplace_back();
        holds.back().scans.push_back(k);
        last_still = k;
        any = true;
    }
    res.holds = static_cast<int>(holds.size());
    if (holds.size() < 3)
        throw CalibrationError(fmt::format(
            "{}: the board was found in {} fields but held still in only {} poses (need >= 3; hold it still for "
            "a quarter of a second at each pose)",
            name, res.fields_seen, holds.size()));
    // Coarse view of each hold: the mean of its scans (for the selection).
    std::vector<std::vector<cv::Point2f>> views;
    for (const Hold& h : holds) {
        std::vector<cv::Point2f> v(static_cast<size_t>(cols * rows), cv::Point2f(0, 0));
        for (size_t k : h.scans)
            for (size_t c = 0; c < v.size(); ++c) v[c] += scans[k].corners[c];
        for (auto& p : v) p *= 1.0f / static_cast<float>(h.scans.size());
        views.push_back(std::move(v));
        const int64_t last = scans[h.scans.back()].field + (opt.woven_frames ? 1 : 0);
        res.views.push_back({scans[h.scans.front()].field, last, static_cast<int>(h.scans.size()), 0.0, false});
    }

    // 3. Selection: greedy farthest point in descriptor space, from the view nearest the mean.
    std::vector<int> chosen;
    if (static_cast<int>(views.size()) <= opt.max_views) {
        for (size_t k = 0; k < views.size(); ++k) chosen.push_back(static_cast<int>(k));
    } else {
        std::vector<std::vector<double>> d;
        for (const auto& v : views) d.push_back(view_descriptor(v, cols, rows));
        auto dist2 = [&](size_t a, size_t b) {
            double s = 0;
            for (size_t j = 0; j < d[a].size(); ++j) s += (d[a][j] - d[b][j]) * (d[a][j] - d[b][j]);
            return s;
        };
        std::vector<double> mean(d[0].size(), 0.0);
        for (const auto& x : d)
            for (size_t j = 0; j < x.size(); ++j) mean[j] += x[j] / static_cast<double>(d.size());
        size_t first = 0;
        double best = HUGE_VAL;
        for (size_t k = 0; k < d.size(); ++k) {
            double s = 0;
            for (size_t j = 0; j < mean.size(); ++j) s += (d[k][j] - mean[j]) * (d[k][j] - mean[j]);
            if (s < best) best = s, first = k;
        }
        std::vector<double> near(d.size(), HUGE_VAL);
        size_t next = first;
        for (int n = 0; n < opt.max_views; ++n) {
            chosen.push_back(static_cast<int>(next));
            for (size_t k = 0; k < d.size(); ++k) near[k] = std::min(near[k], dist2(k, next));
            next = static_cast<size_t>(std::max_element(near.begin(), near.end()) - near.begin());
        }
        std::sort(chosen.begin(), chosen.end());
    }

    // Refinement of the chosen holds: each parity's still fields averaged (noise down by their number), the corner
    // model fitted per parity and the two results averaged (fields), or fitted to both parities at once (woven).
    if (progress) {
        info.phase = ProgressInfo::Phase::kSolve;
        info.stage = "corners";
        info.done = 0;
        info.total = static_cast<int64_t>(chosen.size());
        progress(info);
    }
    {
        std::vector<int> refined;
        const size_t tried = chosen.size();
        cv::Mat sum[2], luma_f;
        for (int id : chosen) {
            const Hold& h = holds[static_cast<size_t>(id)];
            int n[2] = {0, 0};
            for (int p = 0; p < 2; ++p) sum[p] = cv::Mat::zeros(rig::kFieldHeight, rig::kFieldWidth, CV_32F);
            // Every field from the hold's first still scan to its last (still at both ends, so in between).
            const int64_t f_end = scans[h.scans.back()].field + (opt.woven_frames ? 1 : 0);
            for (int64_t f = scans[h.scans.front()].field; f <= f_end; ++f) {
                rec.read_field(cam, f, buf.data());
                uyvy_luma(buf, luma);
                luma.convertTo(luma_f, CV_32F);
                const int p = rec.field_parity(cam, f);
                sum[p] += luma_f;
                ++n[p];
            }
            // Fields: each parity its own levels and shading (a field may be brighter than the other); woven: one.
            std::vector<BoardImage> images;
            for (int p = 0; p < 2; ++p)
                if (n[p] > 0) images.push_back({sum[p] / static_cast<double>(n[p]), 2, p, opt.woven_frames ? 0 : p});
            std::vector<cv::Point2f>& v = views[static_cast<size_t>(id)];
            const bool ok = refine_board_corners(images, cols, rows, v) == cols * rows;
            if (ok) refined.push_back(id);
            if (progress) {
                ++info.done;
                progress(info);
            }
        }
        chosen = refined;
        if (chosen.size() < 3)
            throw CalibrationError(fmt::format("{}: the corners could be refined in only {} of {} still poses (need >= 3)",
                                               name, chosen.size(), tried));
    }

    // 4. calibrateCamera (frame pixels), one round of dropping outlier views.
    std::vector<cv::Point3f> board;
    for (int r = 0; r < rows; ++r)
        for (int c = 0; c < cols; ++c)
            board.emplace_back(static_cast<float>(c * opt.square_mm), static_cast<float>(r * opt.square_mm), 0.f);
    cv::Mat K, D;
    std::vector<cv::Mat> rvecs, tvecs;
    std::vector<double> per_view;
    auto fit = [&](const std::vector<int>& ids) {
        std::vector<std::vector<cv::Point3f>> obj(ids.size(), board);
        std::vector<std::vector<cv::Point2f>> img;
        for (int id : ids) img.push_back(views[static_cast<size_t>(id)]);
        cv::Mat std_in, std_ex, errs;
        const double rms = cv::calibrateCamera(obj, img, cv::Size(rig::kFrameWidth, rig::kFrameHeight), K, D, rvecs, tvecs,
                                               std_in, std_ex, errs, 0,
                                               cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, DBL_EPSILON));
        per_view.assign(errs.begin<double>(), errs.end<double>());
        return rms;
    };
    if (progress) {
        info.stage = "intrinsics";
        info.done = 0;
        info.total = 2;
        progress(info);
    }
    double rms = fit(chosen);
    for (int round = 0; round < 2; ++round) {
        std::vector<double> sorted = per_view;
        std::sort(sorted.begin(), sorted.end());
        const double limit = std::max(kOutlierFloorPx, 3.0 * sorted[sorted.size() / 2]);
        std::vector<int> kept;
        for (size_t k = 0; k < chosen.size(); ++k)
            if (per_view[k] <= limit) kept.push_back(chosen[k]);
        if (kept.size() == chosen.size() || kept.size() < 3) break;
        chosen = kept;
        rms = fit(chosen);
    }
    if (progress) {
        info.done = 2;
        progress(info);
    }

    res.camera = cam_in;
    res.camera.fx = K.at<double>(0, 0);
    res.camera.fy = K.at<double>(1, 1);
    res.camera.cx = K.at<double>(0, 2);
    res.camera.cy = K.at<double>(1, 2);
    for (int k = 0; k < 5; ++k) res.camera.dist[static_cast<size_t>(k)] = D.at<double>(k);
    res.camera.max_r2 = monotonic_max_r2(res.camera.dist);
    res.rms_px = rms;
    res.views_used = static_cast<int>(chosen.size());
    res.board_rvecs = rvecs;
    res.board_tvecs = tvecs;
    std::vector<bool> grid(kCoverageCols * kCoverageRows, false);
    for (size_t k = 0; k < chosen.size(); ++k) {
        IntrinsicsView& v = res.views[static_cast<size_t>(chosen[k])];
        v.used = true;
        v.rms_px = per_view[k];
        res.corners_frame_px.push_back(views[static_cast<size_t>(chosen[k])]);
        for (const auto& p : res.corners_frame_px.back()) {
            const int gx = std::clamp(static_cast<int>(p.x / rig::kFrameWidth * kCoverageCols), 0, kCoverageCols - 1);
            const int gy = std::clamp(static_cast<int>(p.y / rig::kFrameHeight * kCoverageRows), 0, kCoverageRows - 1);
            grid[static_cast<size_t>(gy * kCoverageCols + gx)] = true;
        }
    }
    res.coverage = static_cast<double>(std::count(grid.begin(), grid.end(), true)) / static_cast<double>(grid.size());

    // 5. Coverage picture: each used view's outline (filled, translucent) and corners; unused holds in red.
    if (!opt.coverage_png.empty()) {
        cv::Mat pic(rig::kFrameHeight, rig::kFrameWidth, CV_8UC3, cv::Scalar(28, 28, 28));
        for (int gx = 1; gx < kCoverageCols; ++gx) {
            const int x = gx * rig::kFrameWidth / kCoverageCols;
            cv::line(pic, {x, 0}, {x, rig::kFrameHeight - 1}, cv::Scalar(48, 48, 48));
        }
        for (int gy = 1; gy < kCoverageRows; ++gy) {
            const int y = gy * rig::kFrameHeight / kCoverageRows;
            cv::line(pic, {0, y}, {rig::kFrameWidth - 1, y}, cv::Scalar(48, 48, 48));
        }
        for (size_t k = 0; k < views.size(); ++k) {
            const auto& c = views[k];
            const std::vector<cv::Point> quad = {c[0], c[static_cast<size_t>(cols - 1)], c.back(), c[static_cast<size_t>((rows - 1) * cols)]};
            const bool used = res.views[k].used;
            if (used) {
                cv::Mat overlay = pic.clone();
                cv::fillConvexPoly(overlay, quad, cv::Scalar(200, 140, 40));
                cv::addWeighted(overlay, 0.18, pic, 0.82, 0, pic);
            }
            cv::polylines(pic, std::vector<std::vector<cv::Point>>{quad}, true,
                          used ? cv::Scalar(230, 170, 60) : cv::Scalar(60, 60, 220), 1, cv::LINE_AA);
            for (const auto& p : c)
                cv::circle(pic, p, 1, used ? cv::Scalar(90, 230, 90) : cv::Scalar(60, 60, 220), cv::FILLED, cv::LINE_AA);
        }
        const std::string title = fmt::format("{}: {} views, RMS {:.3f} px, coverage {:.0f} %", name, res.views_used,
                                              res.rms_px, res.coverage * 100);
        cv::putText(pic, title, {10, 22}, cv::FONT_HERSHEY_SIMPLEX, 0.6, cv::Scalar(235, 235, 235), 1, cv::LINE_AA);
        bool ok = false;
        try {
            ok = cv::imwrite(opt.coverage_png, pic);
        } catch (const cv::Exception&) {
            ok = false;
        }
        if (!ok) throw CalibrationError(fmt::format("{}: file: cannot be written", opt.coverage_png));
        res.coverage_png = opt.coverage_png;
    }
    return res;
}

}  // namespace eyesim::calibration
