// Wand calibration, step 3: time offsets, initial relative poses and the Ceres bundle adjustment.
#include "eyesim/calibration/wand.hpp"

#include "eyesim/rig/pal.hpp"

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <ceres/manifold.h>
#include <ceres/product_manifold.h>
#include <ceres/sphere_manifold.h>
#include <fmt/format.h>
#include <opencv2/calib3d.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <numeric>

namespace eyesim::calibration {

namespace {

constexpr int kN = 3;  // markers on the wand the solver is built for
constexpr double kPeriodUs = rig::kFieldPeriodUs;
constexpr double kMedianToSigma = 1.0 / 1.1774;  // 2D Gaussian: median |r| = σ √(2 ln 2)

using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;

/// Cubic Lagrange weights on the nodes -1, 0, 1, 2 at u (exact for cubic motion; u in [0, 1)).
template <typename T>
void lagrange4(const T& u, T w[4]) {
    const T one(1.0), two(2.0);
    w[0] = -u * (u - one) * (u - two) / T(6.0);
    w[1] = (u + one) * (u - one) * (u - two) / T(2.0);
    w[2] = -(u + one) * u * (u - two) / T(2.0);
    w[3] = (u + one) * u * (u - one) / T(6.0);
}

/// OpenCV's 5-coefficient model on a normalised point, intrinsics (fx, fy, cx, cy, k1, k2, p1, p2, k3).
template <typename T>
void distort(const T* in, const T& x, const T& y, T& u, T& v) {
    const T r2 = x * x + y * y, r4 = r2 * r2, r6 = r4 * r2;
    const T radial = T(1.0) + in[4] * r2 + in[5] * r4 + in[8] * r6;
    const T xd = x * radial + in[6] * T(2.0) * x * y + in[7] * (r2 + T(2.0) * x * x);
    const T yd = y * radial + in[6] * (r2 + T(2.0) * y * y) + in[7] * T(2.0) * x * y;
    u = xd * in[0] + in[2];
    v = yd * in[1] + in[3];
}

/// One camera's view of one wand sample: its four fields around the sample's instant (the same point four times
/// when the instant is one of its own fields), marker image centres in frame px.
struct ViewData {
    std::array<std::array<Vec2, 4>, kN> px;  // [marker][node]
    std::array<double, kN> z_mm;             // marker positions along the rod, from the marker centroid
    double x0 = 0;                           // field-index position of the sample instant with zero offset, minus
                                             // the stencil's node 0 (u = x0 - delta / period)
};

/// Reprojection residual of one view, 2 per marker (field px: x frame columns, y field rows; projected − observed). Camera pose (angle-axis,
/// t), intrinsics and time offset are parameters when the flag says so, else constants held here; the wand
/// sample's centre and unit direction always are. Fewer parameters make autodiff's Jets shorter.
template <bool kPose, bool kIntr, bool kDelta>
struct ViewCost {
    ViewData d;
    std::array<double, 6> pose{};
    std::array<double, 9> intr{};
    double delta_us = 0;

    template <typename T>
    bool run(const T* const* p, T* res) const {
        int k = 0;
        T pose_c[6], intr_c[9], delta_c[1];
        const T* P = pose_c;
        const T* I = intr_c;
        const T* D = delta_c;
        if constexpr (kPose) P = p[k++];
        else for (int i = 0; i < 6; ++i) pose_c[i] = T(pose[static_cast<size_t>(i)]);
        if constexpr (kIntr) I = p[k++];
        else for (int i = 0; i < 9; ++i) intr_c[i] = T(intr[static_cast<size_t>(i)]);
        if constexpr (kDelta) D = p[k++];
        else delta_c[0] = T(delta_us);
        const T* centre = p[k];  // the wand sample: centre (3), unit direction (3)
        const T* dir = p[k] + 3;
        T w[4];
        lagrange4(T(d.x0) - D[0] / T(kPeriodUs), w);
        for (int m = 0; m < kN; ++m) {
            const T X[3] = {centre[0] + T(d.z_mm[m]) * dir[0], centre[1] + T(d.z_mm[m]) * dir[1],
                            centre[2] + T(d.z_mm[m]) * dir[2]};
            T Xc[3];
            ceres::AngleAxisRotatePoint(P, X, Xc);
            Xc[0] += P[3];
            Xc[1] += P[4];
            Xc[2] += P[5];
            T u, v;
            distort(I, Xc[0] / Xc[2], Xc[1] / Xc[2], u, v);
            T ou(0.0), ov(0.0);
            for (int n = 0; n < 4; ++n) {
                ou += w[n] * T(d.px[m][n].x());
                ov += w[n] * T(d.px[m][n].y());
            }
            // Field pixels (the rows the camera delivers, in which its centroid noise is about isotropic): a frame
            // row is half a field row.
            res[2 * m] = u - ou;
            res[2 * m + 1] = (v - ov) / T(2.0);
        }
        return true;
    }
    template <typename T>
    bool operator()(const T* a, T* r) const {
        const T* p[] = {a};
        return run(p, r);
    }
    template <typename T>
    bool operator()(const T* a, const T* b, T* r) const {
        const T* p[] = {a, b};
        return run(p, r);
    }
    template <typename T>
    bool operator()(const T* a, const T* b, const T* c, T* r) const {
        const T* p[] = {a, b, c};
        return run(p, r);
    }
    template <typename T>
    bool operator()(const T* a, const T* b, const T* c, const T* e, T* r) const {
        const T* p[] = {a, b, c, e};
        return run(p, r);
    }
};

/// Residuals of a view in plain doubles (every block given).
void view_residuals(const ViewData& d, const double* pose, const double* intr, const double* delta, const double* wand,
                    double* res) {
    ViewCost<true, true, true> c{d, {}, {}, 0};
    c(pose, intr, delta, wand, res);
}

/// The cost function of a view with the given blocks free; `blocks` gets the parameter blocks in order.
template <bool kPose, bool kIntr, bool kDelta>
ceres::CostFunction* make_view_cost(const ViewData& d, double* pose, double* intr, double* delta, double* wand,
                                    std::vector<double*>& blocks) {
    auto* f = new ViewCost<kPose, kIntr, kDelta>{d, {}, {}, delta[0]};
    std::copy(pose, pose + 6, f->pose.begin());
    std::copy(intr, intr + 9, f->intr.begin());
    blocks.clear();
    if constexpr (kPose) blocks.push_back(pose);
    if constexpr (kIntr) blocks.push_back(intr);
    if constexpr (kDelta) blocks.push_back(delta);
    blocks.push_back(wand);
    constexpr int kR = 2 * kN;
    if constexpr (kPose && kIntr && kDelta) return new ceres::AutoDiffCostFunction<ViewCost<kPose, kIntr, kDelta>, kR, 6, 9, 1, 6>(f);
    else if constexpr (kPose && kIntr) return new ceres::AutoDiffCostFunction<ViewCost<kPose, kIntr, kDelta>, kR, 6, 9, 6>(f);
    else if constexpr (kPose && kDelta) return new ceres::AutoDiffCostFunction<ViewCost<kPose, kIntr, kDelta>, kR, 6, 1, 6>(f);
    else if constexpr (kPose) return new ceres::AutoDiffCostFunction<ViewCost<kPose, kIntr, kDelta>, kR, 6, 6>(f);
    else if constexpr (kIntr) return new ceres::AutoDiffCostFunction<ViewCost<kPose, kIntr, kDelta>, kR, 9, 6>(f);
    else return new ceres::AutoDiffCostFunction<ViewCost<kPose, kIntr, kDelta>, kR, 6>(f);
}

/// Per camera and field: the ordered view in frame px and undistorted normalised coordinates.
struct Track {
    std::vector<bool> valid;
    std::vector<std::array<Vec2, kN>> px, nq;
};

/// Drops views that jump off the smooth track (ends swapped, a marker half hidden, a stray blob): each view is
/// compared with the cubic through the two views before and the two after it (weights -1/6, 2/3, 2/3, -1/6; at
/// hand speed the track's own curvature gives < 0.01 px); the worst beyond max(0.5 px, 8 robust sigmas) goes
/// first, then its neighbours are judged again. Returns how many were dropped.
int64_t drop_jumps(Track& tr) {
    const int64_t n = static_cast<int64_t>(tr.valid.size());
    auto deviation = [&](int64_t j) {
        if (j < 2 || j + 2 >= n) return -1.0;
        for (int64_t k = j - 2; k <= j + 2; ++k)
            if (!tr.valid[static_cast<size_t>(k)]) return -1.0;
        double worst = 0;
        for (int m = 0; m < kN; ++m) {
            const Vec2 pred = (-tr.px[static_cast<size_t>(j - 2)][m] + 4.0 * tr.px[static_cast<size_t>(j - 1)][m] +
                               4.0 * tr.px[static_cast<size_t>(j + 1)][m] - tr.px[static_cast<size_t>(j + 2)][m]) /
                              6.0;
            worst = std::max(worst, (tr.px[static_cast<size_t>(j)][m] - pred).norm());
        }
        return worst;
    };
    std::vector<double> dev(static_cast<size_t>(n));
    std::vector<double> all;
    for (int64_t j = 0; j < n; ++j) {
        dev[static_cast<size_t>(j)] = deviation(j);
        if (dev[static_cast<size_t>(j)] >= 0) all.push_back(dev[static_cast<size_t>(j)]);
    }
    if (all.empty()) return 0;
    std::nth_element(all.begin(), all.begin() + static_cast<std::ptrdiff_t>(all.size() / 2), all.end());
    // The worst of kN markers' deviations: its median is about 1.6 σ of one coordinate's prediction error.
    const double bound = std::max(0.5, 8.0 * all[all.size() / 2] / 1.6);
    int64_t dropped = 0;
    for (;;) {
        int64_t worst = -1;
        for (int64_t j = 0; j < n; ++j)
            if (dev[static_cast<size_t>(j)] > bound && (worst < 0 || dev[static_cast<size_t>(j)] > dev[static_cast<size_t>(worst)]))
                worst = j;
        if (worst < 0) break;
        tr.valid[static_cast<size_t>(worst)] = false;
        ++dropped;
        for (int64_t j = std::max<int64_t>(0, worst - 2); j <= std::min(n - 1, worst + 2); ++j)
            dev[static_cast<size_t>(j)] = deviation(j);
    }
    return dropped;
}

/// Where camera `cam`'s track is at fractional field position x: the stencil start j (node 0) and u; false when
/// the fields it needs are missing. `exact` when x is (within 1e-9) a field of its own and `allow_exact` (the
/// camera's time offset is not being solved): then only that field is needed.
bool stencil(const Track& tr, double x, int64_t& j, double& u, bool& exact, bool allow_exact = true) {
    const int64_t n = static_cast<int64_t>(tr.valid.size());
    const double r = std::round(x);
    if (allow_exact && std::fabs(x - r) < 1e-9) {
        j = static_cast<int64_t>(r);
        u = 0;
        exact = true;
        return j >= 0 && j < n && tr.valid[static_cast<size_t>(j)];
    }
    exact = false;
    j = static_cast<int64_t>(std::floor(x));
    u = x - static_cast<double>(j);
    if (j - 1 < 0 || j + 2 >= n) return false;
    for (int64_t k = j - 1; k <= j + 2; ++k)
        if (!tr.valid[static_cast<size_t>(k)]) return false;
    return true;
}

/// The track interpolated at x (normalised or px); false when it cannot be.
bool interpolate(const Track& tr, double x, bool normalised, std::array<Vec2, kN>& out) {
    int64_t j = 0;
    double u = 0;
    bool exact = false;
    if (!stencil(tr, x, j, u, exact)) return false;
    const auto& src = normalised ? tr.nq : tr.px;
    if (exact) {
        out = src[static_cast<size_t>(j)];
        return true;
    }
    double w[4];
    lagrange4(u, w);
    for (int m = 0; m < kN; ++m) {
        out[m].setZero();
        for (int k = 0; k < 4; ++k) out[m] += w[k] * src[static_cast<size_t>(j - 1 + k)][m];
    }
    return true;
}

/// Least-squares intersection of rays (centres C, unit directions d).
Vec3 intersect(const std::vector<Vec3>& C, const std::vector<Vec3>& d) {
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    Vec3 b = Vec3::Zero();
    for (size_t i = 0; i < C.size(); ++i) {
        const Eigen::Matrix3d P = Eigen::Matrix3d::Identity() - d[i] * d[i].transpose();
        A += P;
        b += P * C[i];
    }
    return A.ldlt().solve(b);
}

/// Camera pose in camera 0's frame: x_cam = R x_cam0 + t.
struct Pose {
    Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
    Vec3 t = Vec3::Zero();
    Vec3 centre() const { return -R.transpose() * t; }
    Vec3 ray(const Vec2& q) const { return (R.transpose() * Vec3(q.x(), q.y(), 1.0)).normalized(); }
};

/// Result of fitting an essential matrix to camera 0 and camera c at one time offset.
struct PairFit {
    double score_px = 1e30;   // median Sampson distance, px
    int points = 0;
    cv::Mat E;
    std::vector<cv::Point2d> p0, pc;
};

PairFit fit_pair(const Track& t0, const Track& tc, double delta_us, double f_px, int64_t fields, size_t max_samples) {
    PairFit out;
    std::vector<int64_t> idx;
    std::array<Vec2, kN> a, b;
    for (int64_t i = 0; i < fields; ++i) {
        if (!t0.valid[static_cast<size_t>(i)]) continue;
        if (!interpolate(tc, static_cast<double>(i) - delta_us / kPeriodUs, true, b)) continue;
        idx.push_back(i);
    }
    if (idx.size() < 12) return out;
    const size_t step = std::max<size_t>(1, idx.size() / max_samples);
    for (size_t k = 0; k < idx.size(); k += step) {
        a = t0.nq[static_cast<size_t>(idx[k])];
        interpolate(tc, static_cast<double>(idx[k]) - delta_us / kPeriodUs, true, b);
        for (int m = 0; m < kN; ++m) {
            out.p0.emplace_back(a[m].x(), a[m].y());
            out.pc.emplace_back(b[m].x(), b[m].y());
        }
    }
    out.points = static_cast<int>(out.p0.size());
    cv::Mat mask;
    out.E = cv::findEssentialMat(out.p0, out.pc, 1.0, cv::Point2d(0, 0), cv::RANSAC, 0.999, 1.5 / f_px, mask);
    if (out.E.rows != 3 || out.E.cols != 3) {  // several solutions stacked: take the first
        if (out.E.rows >= 3 && out.E.cols == 3) out.E = out.E.rowRange(0, 3).clone();
        else return out;
    }
    Eigen::Matrix3d E;
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) E(r, c) = out.E.at<double>(r, c);
    std::vector<double> d;
    for (size_t k = 0; k < out.p0.size(); ++k) {
        const Vec3 x0(out.p0[k].x, out.p0[k].y, 1.0), x1(out.pc[k].x, out.pc[k].y, 1.0);
        const Vec3 Ex0 = E * x0, Etx1 = E.transpose() * x1;
        const double num = x1.dot(Ex0);
        const double den = Ex0.head<2>().squaredNorm() + Etx1.head<2>().squaredNorm();
        d.push_back(den > 0 ? std::fabs(num) / std::sqrt(den) * f_px : 1e30);
    }
    std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2), d.end());
    out.score_px = d[d.size() / 2];
    return out;
}

/// Reports Ceres iterations as progress.
class IterationReporter : public ceres::IterationCallback {
public:
    IterationReporter(const Progress& p, std::string stage, int max_it) : progress_(p) {
        info_.phase = ProgressInfo::Phase::kSolve;
        info_.stage = std::move(stage);
        info_.total = max_it;
    }
    ceres::CallbackReturnType operator()(const ceres::IterationSummary& s) override {
        info_.done = s.iteration;
        info_.cost = s.cost;
        if (progress_) progress_(info_);
        return ceres::SOLVER_CONTINUE;
    }

private:
    const Progress& progress_;
    ProgressInfo info_;
};

double median_of(std::vector<double> v) {
    if (v.empty()) return 0;
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
}

}  // namespace

WandSolve solve_wand(const WandViews& views, const std::vector<rig::CameraModel>& cams, const rig::WandBody& wand,
                     const WandOptions& opt, const Progress& progress) {
    const auto t_start = std::chrono::steady_clock::now();
    if (wand.markers.size() != static_cast<size_t>(kN))
        throw CalibrationError(fmt::format("the wand has {} markers; the solver needs {}", wand.markers.size(), kN));
    const int nc = static_cast<int>(cams.size());
    if (nc < 2) throw CalibrationError("need at least 2 cameras");
    if (static_cast<int>(views.views.size()) != nc)
        throw CalibrationError(fmt::format("views of {} cameras for {} cameras", views.views.size(), nc));
    const int64_t fields = views.views.empty() ? 0 : static_cast<int64_t>(views.views[0].size());
    WandSolve out;
    out.cameras = cams;
    out.stats.resize(static_cast<size_t>(nc));

    // Tracks.
    std::vector<Track> tracks(static_cast<size_t>(nc));
    for (int c = 0; c < nc; ++c) {
        Track& tr = tracks[static_cast<size_t>(c)];
        tr.valid.assign(static_cast<size_t>(fields), false);
        tr.px.resize(static_cast<size_t>(fields));
        tr.nq.resize(static_cast<size_t>(fields));
        int64_t n = 0;
        for (int64_t i = 0; i < fields && i < static_cast<int64_t>(views.views[static_cast<size_t>(c)].size()); ++i) {
            const WandView& v = views.views[static_cast<size_t>(c)][static_cast<size_t>(i)];
            if (v.size() != static_cast<size_t>(kN)) continue;
            bool ok = true;
            for (int m = 0; m < kN && ok; ++m) {
                const auto q = cams[static_cast<size_t>(c)].undistort_to_normalized(v[static_cast<size_t>(m)]);
                ok = q.has_value();
                if (ok) {
                    tr.px[static_cast<size_t>(i)][m] = v[static_cast<size_t>(m)];
                    tr.nq[static_cast<size_t>(i)][m] = *q;
                }
            }
            tr.valid[static_cast<size_t>(i)] = ok;
            n += ok;
        }
        const int64_t jumps = drop_jumps(tr);
        out.stats[static_cast<size_t>(c)].views = n;
        out.stats[static_cast<size_t>(c)].jumps = jumps;
        n -= jumps;
        if (jumps > 0) out.notes.push_back(fmt::format("camera {}: {} views off the smooth wand track dropped", c, jumps));
        if (n < opt.min_samples_per_camera)
            throw CalibrationError(fmt::format("camera {}: {} wand views, at least {} needed (wave the wand where "
                                               "this camera sees all its markers)",
                                               c, n, opt.min_samples_per_camera));
    }

    // Time offsets (exposure mid-time of field i minus camera 0's) and initial poses, camera 0 with each other.
    std::vector<double> delta(static_cast<size_t>(nc), 0.0);
    std::vector<Pose> pose(static_cast<size_t>(nc));
    for (int c = 1; c < nc; ++c) {
        const double f = 0.5 * (cams[static_cast<size_t>(c)].fx + cams[static_cast<size_t>(c)].fy);
        PairFit best;
        double best_delta = 0;
        auto consider = [&](double d, size_t max_samples) {
            PairFit pf = fit_pair(tracks[0], tracks[static_cast<size_t>(c)], d, f, fields, max_samples);
            if (pf.score_px < best.score_px) {
                best = std::move(pf);
                best_delta = d;
            }
        };
        if (opt.synchronised) {
            consider(0.0, 400);
        } else if (!opt.estimate_time_offsets) {
            if (opt.time_offsets_us.size() != static_cast<size_t>(nc))
                throw CalibrationError("time offsets not estimated and not given for every camera");
            consider(opt.time_offsets_us[static_cast<size_t>(c)] - opt.time_offsets_us[0], 400);
        } else {
            // A coarse grid over ±one field period, then a fine one round the best; the solve refines it.
            for (double d = -kPeriodUs; d <= kPeriodUs + 1e-6; d += 1000.0) consider(d, 100);
            const double coarse = best_delta;
            best = PairFit{};
            for (double d = coarse - 1000.0; d <= coarse + 1000.0 + 1e-6; d += 100.0) consider(d, 300);
            out.notes.push_back(fmt::format("camera {}: time offset search: {:.0f} us (median Sampson distance "
                                            "{:.3f} px over {} points)",
                                            c, best_delta, best.score_px, best.points));
        }
        if (best.points < 5 * kN || best.E.empty())
            throw CalibrationError(fmt::format("camera {}: too few wand samples seen together with camera 0 ({} "
                                               "points) for an initial pose",
                                               c, best.points));
        delta[static_cast<size_t>(c)] = best_delta;
        cv::Mat R, t, mask;
        cv::recoverPose(best.E, best.p0, best.pc, cv::Mat::eye(3, 3, CV_64F), R, t, mask);
        Pose& p = pose[static_cast<size_t>(c)];
        for (int r = 0; r < 3; ++r) {
            for (int k = 0; k < 3; ++k) p.R(r, k) = R.at<double>(r, k);
            p.t(r) = t.at<double>(r, 0);
        }
        // Metric scale: the median wand length triangulated with a unit baseline.
        std::vector<double> len;
        for (size_t k = 0; k + kN <= best.p0.size(); k += kN) {
            Vec3 X[kN];
            for (int m = 0; m < kN; ++m) {
                const Vec2 q0(best.p0[k + static_cast<size_t>(m)].x, best.p0[k + static_cast<size_t>(m)].y);
                const Vec2 q1(best.pc[k + static_cast<size_t>(m)].x, best.pc[k + static_cast<size_t>(m)].y);
                X[m] = intersect({pose[0].centre(), p.centre()}, {pose[0].ray(q0), p.ray(q1)});
            }
            len.push_back((X[kN - 1] - X[0]).norm());
        }
        const double med = median_of(len);
        if (!(med > 0)) throw CalibrationError(fmt::format("camera {}: degenerate initial pose", c));
        p.t *= wand.length_mm() / med;
    }

    // Samples: camera 0's field instants seen by at least two cameras.
    double zbar = 0;
    for (const auto& m : wand.markers) zbar += m.distance_mm;
    zbar /= kN;
    std::array<double, kN> z_mm{};
    for (int m = 0; m < kN; ++m) z_mm[m] = wand.markers[static_cast<size_t>(m)].distance_mm - zbar;

    struct Obs {
        int cam;
        ViewData r;
        bool active = true;
    };
    struct Sample {
        int64_t field;
        std::vector<Obs> obs;
        double wand[6];  // centre (mm, camera 0's frame), unit direction marker 0 → last
    };
    std::vector<Sample> samples;
    for (int64_t i = 0; i < fields; ++i) {
        Sample s;
        s.field = i;
        for (int c = 0; c < nc; ++c) {
            const double x = static_cast<double>(i) - delta[static_cast<size_t>(c)] / kPeriodUs;
            int64_t j = 0;
            double u = 0;
            bool exact = false;
            const bool fixed_time = c == 0 || opt.synchronised || !opt.estimate_time_offsets;
            if (!stencil(tracks[static_cast<size_t>(c)], x, j, u, exact, fixed_time)) continue;
            Obs o;
            o.cam = c;
            o.r.z_mm = z_mm;
            const Track& tr = tracks[static_cast<size_t>(c)];
            for (int m = 0; m < kN; ++m)
                for (int k = 0; k < 4; ++k)
                    o.r.px[m][k] = exact ? tr.px[static_cast<size_t>(j)][m] : tr.px[static_cast<size_t>(j - 1 + k)][m];
            // u = x0 - delta/period with x0 = i - j (the delta in the solve replaces the one used here).
            o.r.x0 = exact ? 0.0 : static_cast<double>(i - j);
            s.obs.push_back(o);
        }
        if (s.obs.size() < 2) continue;
        // Initial wand pose: each marker triangulated from the initial poses.
        Vec3 X[kN];
        for (int m = 0; m < kN; ++m) {
            std::vector<Vec3> C, d;
            for (const Obs& o : s.obs) {
                std::array<Vec2, kN> q;
                interpolate(tracks[static_cast<size_t>(o.cam)],
                            static_cast<double>(i) - delta[static_cast<size_t>(o.cam)] / kPeriodUs, true, q);
                C.push_back(pose[static_cast<size_t>(o.cam)].centre());
                d.push_back(pose[static_cast<size_t>(o.cam)].ray(q[m]));
            }
            X[m] = intersect(C, d);
        }
        Vec3 centre = Vec3::Zero();
        for (int m = 0; m < kN; ++m) centre += X[m] / kN;
        const Vec3 dir = (X[kN - 1] - X[0]).normalized();
        if (!centre.allFinite() || !dir.allFinite()) continue;
        for (int k = 0; k < 3; ++k) {
            s.wand[k] = centre[k];
            s.wand[3 + k] = dir[k];
        }
        samples.push_back(std::move(s));
    }
    for (int c = 0; c < nc; ++c) {
        int64_t n = 0;
        for (const Sample& s : samples)
            for (const Obs& o : s.obs) n += o.cam == c;
        if (n < opt.min_samples_per_camera)
            throw CalibrationError(fmt::format("camera {}: {} wand samples shared with another camera, at least {} "
                                               "needed",
                                               c, n, opt.min_samples_per_camera));
    }

    // Parameter blocks.
    std::vector<std::array<double, 6>> pose_p(static_cast<size_t>(nc));
    std::vector<std::array<double, 9>> intr_p(static_cast<size_t>(nc));
    std::vector<std::array<double, 1>> delta_p(static_cast<size_t>(nc));
    for (int c = 0; c < nc; ++c) {
        const Pose& p = pose[static_cast<size_t>(c)];
        ceres::RotationMatrixToAngleAxis(ceres::ColumnMajorAdapter3x3(p.R.data()), pose_p[static_cast<size_t>(c)].data());
        for (int k = 0; k < 3; ++k) pose_p[static_cast<size_t>(c)][3 + static_cast<size_t>(k)] = p.t[k];
        const rig::CameraModel& cm = cams[static_cast<size_t>(c)];
        intr_p[static_cast<size_t>(c)] = {cm.fx, cm.fy, cm.cx, cm.cy, cm.dist[0], cm.dist[1], cm.dist[2], cm.dist[3], cm.dist[4]};
        delta_p[static_cast<size_t>(c)][0] = delta[static_cast<size_t>(c)];
    }

    // Robust scale of the residuals: median |r| → σ.
    auto residuals_of = [&](const Obs& o, const Sample& s, double r[2 * kN]) {
        view_residuals(o.r, pose_p[static_cast<size_t>(o.cam)].data(), intr_p[static_cast<size_t>(o.cam)].data(),
                       delta_p[static_cast<size_t>(o.cam)].data(), s.wand, r);
    };
    auto robust_sigma = [&]() {
        std::vector<double> e;
        double r[2 * kN];
        for (const Sample& s : samples)
            for (const Obs& o : s.obs) {
                if (!o.active) continue;
                residuals_of(o, s, r);
                for (int m = 0; m < kN; ++m) e.push_back(std::hypot(r[2 * m], r[2 * m + 1]));
            }
        return median_of(e) * kMedianToSigma;
    };

    const bool estimate_delta = !opt.synchronised && opt.estimate_time_offsets;
    std::vector<double*> blocks;
    auto solve = [&](double huber_px, const std::string& stage) {
        // Centre free, direction on the unit sphere; one block per sample so the Schur step eliminates samples.
        const auto wand_manifold = std::make_unique<ceres::ProductManifold<ceres::EuclideanManifold<3>, ceres::SphereManifold<3>>>();
        ceres::Problem::Options po;
        po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
        ceres::Problem problem(po);
        for (Sample& s : samples) {
            int active = 0;
            for (const Obs& o : s.obs) active += o.active;
            if (active < 2) continue;
            for (const Obs& o : s.obs) {
                if (!o.active) continue;
                const size_t c = static_cast<size_t>(o.cam);
                double* P = pose_p[c].data();
                double* I = intr_p[c].data();
                double* D = delta_p[c].data();
                ceres::CostFunction* cost = nullptr;
                // Camera 0's pose is the gauge; its time is the reference.
                const bool free_pose = o.cam != 0, free_delta = o.cam != 0 && estimate_delta;
                if (opt.refine_intrinsics) {
                    if (free_pose && free_delta) cost = make_view_cost<true, true, true>(o.r, P, I, D, s.wand, blocks);
                    else if (free_pose) cost = make_view_cost<true, true, false>(o.r, P, I, D, s.wand, blocks);
                    else cost = make_view_cost<false, true, false>(o.r, P, I, D, s.wand, blocks);
                } else {
                    if (free_pose && free_delta) cost = make_view_cost<true, false, true>(o.r, P, I, D, s.wand, blocks);
                    else if (free_pose) cost = make_view_cost<true, false, false>(o.r, P, I, D, s.wand, blocks);
                    else cost = make_view_cost<false, false, false>(o.r, P, I, D, s.wand, blocks);
                }
                problem.AddResidualBlock(cost, new ceres::HuberLoss(huber_px), blocks);
            }
            problem.SetManifold(s.wand, wand_manifold.get());
        }
        for (int c = 1; c < nc; ++c)
            if (!problem.HasParameterBlock(pose_p[static_cast<size_t>(c)].data()))
                throw CalibrationError(fmt::format("camera {}: no wand sample left after outliers", c));
        ceres::Solver::Options so;
        so.linear_solver_type = ceres::DENSE_SCHUR;
        so.num_threads = std::max(1, opt.threads);
        so.max_num_iterations = opt.max_iterations;
        // A relative cost change of 1e-9 moves the cameras by far less than a micrometre.
        so.function_tolerance = 1e-9;
        so.gradient_tolerance = 1e-12;
        so.parameter_tolerance = 1e-10;
        IterationReporter rep(progress, stage, opt.max_iterations);
        so.callbacks.push_back(&rep);
        ceres::Solver::Summary sum;
        ceres::Solve(so, &problem, &sum);
        out.iterations += static_cast<int>(sum.iterations.size());
        out.initial_cost = sum.initial_cost;
        out.final_cost = sum.final_cost;
        out.converged = sum.termination_type == ceres::CONVERGENCE;
        out.notes.push_back(fmt::format("{} solve: {} iterations, {:.2f} s, cost {:.4g} -> {:.4g}, {}", stage,
                                        sum.iterations.size(), sum.total_time_in_seconds, sum.initial_cost,
                                        sum.final_cost, sum.termination_type == ceres::CONVERGENCE ? "converged" : sum.message));
        if (sum.termination_type == ceres::FAILURE || !std::isfinite(sum.final_cost))
            throw CalibrationError(fmt::format("bundle adjustment ({}) failed: {}", stage, sum.message));
    };

    // Stage 1: wide Huber from the initial poses; then drop views whose worst marker is beyond the outlier bound
    // and solve again with the loss at two robust sigmas, twice.
    solve(2.0, "initial");
    for (int round = 0; round < 2; ++round) {
        const double sigma = std::max(robust_sigma(), 1e-4);
        const double bound = opt.outlier_sigmas * sigma;
        double r[2 * kN];
        int64_t dropped = 0;
        for (Sample& s : samples)
            for (Obs& o : s.obs) {
                if (!o.active) continue;
                residuals_of(o, s, r);
                double worst = 0;
                for (int m = 0; m < kN; ++m) worst = std::max(worst, std::hypot(r[2 * m], r[2 * m + 1]));
                if (worst > bound) {
                    o.active = false;
                    ++dropped;
                }
            }
        out.notes.push_back(fmt::format("round {}: robust sigma {:.4f} px, {} views beyond {:.3f} px dropped", round + 1,
                                        sigma, dropped, bound));
        // The first round always re-solves (the loss scale changes); the second only when it dropped views.
        if (round == 0 || dropped > 0) solve(std::max(opt.huber_sigmas * sigma, 1e-4), round == 0 ? "refined" : "final");
    }
    if (!out.converged)
        throw CalibrationError(fmt::format("bundle adjustment did not converge in {} iterations", opt.max_iterations));

    // Results.
    for (int c = 0; c < nc; ++c) {
        rig::CameraModel& cm = out.cameras[static_cast<size_t>(c)];
        const auto& ip = intr_p[static_cast<size_t>(c)];
        cm.fx = ip[0];
        cm.fy = ip[1];
        cm.cx = ip[2];
        cm.cy = ip[3];
        for (int k = 0; k < 5; ++k) cm.dist[static_cast<size_t>(k)] = ip[4 + static_cast<size_t>(k)];
        double R[9];
        ceres::AngleAxisToRotationMatrix(pose_p[static_cast<size_t>(c)].data(), ceres::ColumnMajorAdapter3x3(R));
        cm.R_cam_rig = Eigen::Map<const Eigen::Matrix3d>(R);
        cm.t_cam_rig_mm = Vec3(pose_p[static_cast<size_t>(c)][3], pose_p[static_cast<size_t>(c)][4],
                               pose_p[static_cast<size_t>(c)][5]);
        const double d = delta_p[static_cast<size_t>(c)][0];
        out.stats[static_cast<size_t>(c)].time_offset_us = d;
        // rig.yaml keeps field starts: mid = start - exposure / 2, camera 0's start at 0.
        cm.field_time_offset_us = d + 0.5 * (cm.exposure_us - cams[0].exposure_us);
    }
    out.cameras[0].field_time_offset_us = 0.0;

    constexpr int kGridX = 16, kGridY = 12;
    std::vector<std::vector<bool>> grid(static_cast<size_t>(nc), std::vector<bool>(kGridX * kGridY, false));
    std::vector<double> se(static_cast<size_t>(nc), 0.0), se_frame(static_cast<size_t>(nc), 0.0), we(static_cast<size_t>(nc), 0.0);
    double r[2 * kN];
    for (const Sample& s : samples) {
        int active = 0;
        for (const Obs& o : s.obs) active += o.active;
        for (const Obs& o : s.obs) {
            WandCameraStats& st = out.stats[static_cast<size_t>(o.cam)];
            if (!o.active || active < 2) {
                st.outliers += kN;
                continue;
            }
            ++st.samples;
            residuals_of(o, s, r);
            const rig::CameraModel& cm = out.cameras[static_cast<size_t>(o.cam)];
            for (int m = 0; m < kN; ++m) {
                const Vec2 res(r[2 * m], r[2 * m + 1]);  // field px
                const Vec2 res_frame(res.x(), 2.0 * res.y());
                // The observation (interpolated to the instant) = projection − residual.
                const Vec3 X = Vec3(s.wand[0], s.wand[1], s.wand[2]) + z_mm[m] * Vec3(s.wand[3], s.wand[4], s.wand[5]);
                const Vec3 Xc = cm.R_cam_rig * X + cm.t_cam_rig_mm;
                Vec2 proj;
                distort(intr_p[static_cast<size_t>(o.cam)].data(), Xc.x() / Xc.z(), Xc.y() / Xc.z(), proj.x(), proj.y());
                const Vec2 obs_px = proj - res_frame;
                st.observed_px.push_back(obs_px);
                st.residual_px.push_back(-res);
                ++st.observations;
                se[static_cast<size_t>(o.cam)] += res.squaredNorm();
                se_frame[static_cast<size_t>(o.cam)] += res_frame.squaredNorm();
                // World error: distance of the fitted marker from the camera's ray through the observation.
                if (const auto q = cm.undistort_to_normalized(obs_px)) {
                    const Vec3 ray = Vec3(q->x(), q->y(), 1.0).normalized();
                    we[static_cast<size_t>(o.cam)] += (Xc - Xc.dot(ray) * ray).squaredNorm();
                }
                const int gx = std::clamp(static_cast<int>(obs_px.x() / cm.image_width * kGridX), 0, kGridX - 1);
                const int gy = std::clamp(static_cast<int>(obs_px.y() / cm.image_height * kGridY), 0, kGridY - 1);
                grid[static_cast<size_t>(o.cam)][static_cast<size_t>(gy * kGridX + gx)] = true;
            }
        }
    }
    for (int c = 0; c < nc; ++c) {
        WandCameraStats& st = out.stats[static_cast<size_t>(c)];
        if (st.observations > 0) {
            st.image_error_px_rms = std::sqrt(se[static_cast<size_t>(c)] / static_cast<double>(st.observations));
            st.image_error_frame_px_rms = std::sqrt(se_frame[static_cast<size_t>(c)] / static_cast<double>(st.observations));
            st.world_error_mm = std::sqrt(we[static_cast<size_t>(c)] / static_cast<double>(st.observations));
        }
        st.coverage = static_cast<double>(std::count(grid[static_cast<size_t>(c)].begin(), grid[static_cast<size_t>(c)].end(), true)) /
                      (kGridX * kGridY);
    }

    // Wand length from free triangulation of the end markers with the solved cameras.
    std::vector<Pose> solved(static_cast<size_t>(nc));
    for (int c = 0; c < nc; ++c) {
        solved[static_cast<size_t>(c)].R = out.cameras[static_cast<size_t>(c)].R_cam_rig;
        solved[static_cast<size_t>(c)].t = out.cameras[static_cast<size_t>(c)].t_cam_rig_mm;
    }
    for (const Sample& s : samples) {
        std::vector<Vec3> C, d0, d1;
        for (const Obs& o : s.obs) {
            if (!o.active) continue;
            std::array<Vec2, kN> px;
            if (!interpolate(tracks[static_cast<size_t>(o.cam)],
                             static_cast<double>(s.field) - delta_p[static_cast<size_t>(o.cam)][0] / kPeriodUs, false, px))
                continue;
            const auto q0 = out.cameras[static_cast<size_t>(o.cam)].undistort_to_normalized(px[0]);
            const auto q1 = out.cameras[static_cast<size_t>(o.cam)].undistort_to_normalized(px[kN - 1]);
            if (!q0 || !q1) continue;
            C.push_back(solved[static_cast<size_t>(o.cam)].centre());
            d0.push_back(solved[static_cast<size_t>(o.cam)].ray(*q0));
            d1.push_back(solved[static_cast<size_t>(o.cam)].ray(*q1));
        }
        if (C.size() < 2) continue;
        out.wand_length_error_mm.push_back((intersect(C, d1) - intersect(C, d0)).norm() - wand.length_mm());
    }
    for (const Sample& s : samples) {
        int active = 0;
        for (const Obs& o : s.obs) active += o.active;
        out.samples += active >= 2;
    }
    out.solve_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
    return out;
}

}  // namespace eyesim::calibration
