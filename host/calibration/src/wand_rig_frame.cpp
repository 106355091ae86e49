// Wand calibration, step 4: the rig frame from the mechanical eye at rest (eye frame = rig frame).
#include "eyesim/calibration/wand.hpp"

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <fmt/format.h>

#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <limits>

namespace eyesim::calibration {

namespace {

using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;

/// Epipolar / reprojection gate for eye-marker images, frame px.
constexpr double kGatePx = 1.5;
constexpr double kPi = 3.14159265358979323846;
/// Distance tolerance when matching triangulated markers to bodies.json, mm.
constexpr double kMatchMm = 0.5;

/// Rigid transform (R, t) minimising Σ |R a + t - b|² (Kabsch, no scale).
void kabsch(const std::vector<Vec3>& a, const std::vector<Vec3>& b, Eigen::Matrix3d& R, Vec3& t) {
    Vec3 ma = Vec3::Zero(), mb = Vec3::Zero();
    for (size_t i = 0; i < a.size(); ++i) {
        ma += a[i];
        mb += b[i];
    }
    ma /= static_cast<double>(a.size());
    mb /= static_cast<double>(b.size());
    Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
    for (size_t i = 0; i < a.size(); ++i) H += (a[i] - ma) * (b[i] - mb).transpose();
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
    D(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1.0 : 1.0;
    R = svd.matrixV() * D * svd.matrixU().transpose();
    t = mb - R * ma;
}

/// One eye marker seen by several cameras: image index per camera (-1 none) and its triangulated position.
struct Point {
    std::vector<int> image;
    Vec3 X = Vec3::Zero();
    int views = 0;
};

struct Ray {
    Vec3 C, d;
};

Ray ray_of(const rig::CameraModel& cam, const Vec2& q) {
    const Eigen::Matrix3d Rt = cam.R_cam_rig.transpose();
    return {-Rt * cam.t_cam_rig_mm, (Rt * Vec3(q.x(), q.y(), 1.0)).normalized()};
}

Vec3 intersect(const std::vector<Ray>& rays) {
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    Vec3 b = Vec3::Zero();
    for (const Ray& r : rays) {
        const Eigen::Matrix3d P = Eigen::Matrix3d::Identity() - r.d * r.d.transpose();
        A += P;
        b += P * r.C;
    }
    return A.ldlt().solve(b);
}

/// Reprojection of a fixed camera's view of an eye marker given the rig pose in camera 0's frame.
struct EyeResidual {
    rig::CameraModel cam;
    Vec3 marker_rig_mm;
    Vec2 px;
    template <typename T>
    bool operator()(const T* pose, T* res) const {
        const T M[3] = {T(marker_rig_mm.x()), T(marker_rig_mm.y()), T(marker_rig_mm.z())};
        T X0[3];  // camera 0's frame: x_cam0 = R x_rig + t
        ceres::AngleAxisRotatePoint(pose, M, X0);
        for (int k = 0; k < 3; ++k) X0[k] += pose[3 + k];
        T Xc[3];
        for (int r = 0; r < 3; ++r)
            Xc[r] = T(cam.R_cam_rig(r, 0)) * X0[0] + T(cam.R_cam_rig(r, 1)) * X0[1] + T(cam.R_cam_rig(r, 2)) * X0[2] +
                    T(cam.t_cam_rig_mm(r));
        const T x = Xc[0] / Xc[2], y = Xc[1] / Xc[2];
        const T r2 = x * x + y * y;
        const auto& d = cam.dist;
        const T radial = T(1.0) + T(d[0]) * r2 + T(d[1]) * r2 * r2 + T(d[4]) * r2 * r2 * r2;
        const T xd = x * radial + T(2.0 * d[2]) * x * y + T(d[3]) * (r2 + T(2.0) * x * x);
        const T yd = y * radial + T(d[2]) * (r2 + T(2.0) * y * y) + T(2.0 * d[3]) * x * y;
        res[0] = xd * T(cam.fx) + T(cam.cx) - T(px.x());
        res[1] = (yd * T(cam.fy) + T(cam.cy) - T(px.y())) / T(2.0);  // field px, as the wand solve
        return true;
    }
};

}  // namespace

RigFrameFit fit_rig_frame(const EyeImages& eye, const std::vector<rig::CameraModel>& cams, const rig::EyeBody& body) {
    const size_t nc = cams.size();
    if (eye.px.size() != nc) throw CalibrationError("eye images and cameras differ in count");
    // Undistorted images.
    std::vector<std::vector<Vec2>> q(nc);
    for (size_t c = 0; c < nc; ++c)
        for (const Vec2& p : eye.px[c]) {
            const auto u = cams[c].undistort_to_normalized(p);
            q[c].push_back(u ? *u : Vec2(1e9, 1e9));
        }
    auto reproj_px = [&](size_t c, const Vec3& X, const Vec2& px) {
        const auto p = cams[c].project_frame(X);
        return p ? (*p - px).norm() : 1e30;
    };

    // Candidates: every pair of images in two cameras whose rays meet within the gate; extended by the nearest
    // image of each other camera that agrees; taken best first (lowest reprojection), each image used once.
    struct Cand {
        Point p;
        double err;
    };
    std::vector<Cand> cands;
    for (size_t a = 0; a < nc; ++a)
        for (size_t b = a + 1; b < nc; ++b)
            for (size_t i = 0; i < q[a].size(); ++i)
                for (size_t j = 0; j < q[b].size(); ++j) {
                    std::vector<Ray> rays{ray_of(cams[a], q[a][i]), ray_of(cams[b], q[b][j])};
                    Vec3 X = intersect(rays);
                    if (!X.allFinite()) continue;
                    if (std::max(reproj_px(a, X, eye.px[a][i]), reproj_px(b, X, eye.px[b][j])) > kGatePx) continue;
                    Point p;
                    p.image.assign(nc, -1);
                    p.image[a] = static_cast<int>(i);
                    p.image[b] = static_cast<int>(j);
                    for (size_t c = 0; c < nc; ++c) {
                        if (c == a || c == b) continue;
                        double best = kGatePx;
                        for (size_t k = 0; k < q[c].size(); ++k) {
                            const double e = reproj_px(c, X, eye.px[c][k]);
                            if (e < best) {
                                best = e;
                                p.image[c] = static_cast<int>(k);
                            }
                        }
                        if (p.image[c] >= 0) rays.push_back(ray_of(cams[c], q[c][static_cast<size_t>(p.image[c])]));
                    }
                    p.X = intersect(rays);
                    p.views = static_cast<int>(rays.size());
                    double worst = 0;
                    for (size_t c = 0; c < nc; ++c)
                        if (p.image[c] >= 0)
                            worst = std::max(worst, reproj_px(c, p.X, eye.px[c][static_cast<size_t>(p.image[c])]));
                    if (worst <= kGatePx) cands.push_back({p, worst - 10.0 * p.views});  // more views first
                }
    std::sort(cands.begin(), cands.end(), [](const Cand& x, const Cand& y) { return x.err < y.err; });
    std::vector<std::vector<bool>> used(nc);
    for (size_t c = 0; c < nc; ++c) used[c].assign(q[c].size(), false);
    std::vector<Point> pts;
    for (const Cand& cd : cands) {
        bool free = true;
        for (size_t c = 0; c < nc; ++c)
            if (cd.p.image[c] >= 0 && used[c][static_cast<size_t>(cd.p.image[c])]) free = false;
        if (!free) continue;
        for (size_t c = 0; c < nc; ++c)
            if (cd.p.image[c] >= 0) used[c][static_cast<size_t>(cd.p.image[c])] = true;
        pts.push_back(cd.p);
    }
    if (pts.size() < 3)
        throw CalibrationError(fmt::format("rig frame: {} eye markers seen still by two cameras, at least 3 needed "
                                           "(is the eye in view and at rest?)",
                                           pts.size()));

    // Match to bodies.json by distances: every triple of points against every ordered triple of markers, the
    // rigid fit of the triple, then the points it brings within kMatchMm of a marker; most matches, then least RMS.
    std::vector<Vec3> model;
    for (const auto& m : body.markers) model.push_back(body.center_rig_mm + m.position_eye_mm);
    const size_t np = pts.size(), nm = model.size();
    std::vector<int> best_match;
    double best_rms = std::numeric_limits<double>::infinity();
    int best_count = 0;
    for (size_t i = 0; i < np; ++i)
        for (size_t j = i + 1; j < np; ++j)
            for (size_t k = j + 1; k < np; ++k) {
                const double dij = (pts[i].X - pts[j].X).norm(), dik = (pts[i].X - pts[k].X).norm(),
                             djk = (pts[j].X - pts[k].X).norm();
                for (size_t a = 0; a < nm; ++a)
                    for (size_t b = 0; b < nm; ++b)
                        for (size_t c = 0; c < nm; ++c) {
                            if (a == b || a == c || b == c) continue;
                            if (std::fabs((model[a] - model[b]).norm() - dij) > kMatchMm ||
                                std::fabs((model[a] - model[c]).norm() - dik) > kMatchMm ||
                                std::fabs((model[b] - model[c]).norm() - djk) > kMatchMm)
                                continue;
                            Eigen::Matrix3d R;
                            Vec3 t;
                            kabsch({pts[i].X, pts[j].X, pts[k].X}, {model[a], model[b], model[c]}, R, t);
                            std::vector<int> match(np, -1);
                            std::vector<bool> taken(nm, false);
                            int count = 0;
                            double se = 0;
                            for (size_t p = 0; p < np; ++p) {
                                const Vec3 y = R * pts[p].X + t;
                                int bm = -1;
                                double bd = kMatchMm;
                                for (size_t m = 0; m < nm; ++m)
                                    if (!taken[m] && (model[m] - y).norm() < bd) {
                                        bd = (model[m] - y).norm();
                                        bm = static_cast<int>(m);
                                    }
                                if (bm >= 0) {
                                    match[p] = bm;
                                    taken[static_cast<size_t>(bm)] = true;
                                    ++count;
                                    se += bd * bd;
                                }
                            }
                            const double rms = std::sqrt(se / count);
                            if (count > best_count || (count == best_count && rms < best_rms)) {
                                best_count = count;
                                best_rms = rms;
                                best_match = match;
                            }
                        }
            }
    if (best_count < 3)
        throw CalibrationError(fmt::format("rig frame: the {} triangulated eye markers do not match bodies.json (best: "
                                           "{} within {} mm)",
                                           np, best_count, kMatchMm));

    RigFrameFit fit;
    std::vector<Vec3> a, b;
    for (size_t p = 0; p < np; ++p)
        if (best_match[p] >= 0) {
            a.push_back(pts[p].X);
            b.push_back(model[static_cast<size_t>(best_match[p])]);
            fit.marker_ids.push_back(body.markers[static_cast<size_t>(best_match[p])].id);
        }
    fit.markers = static_cast<int>(a.size());
    kabsch(a, b, fit.R_rig_cam0, fit.t_rig_cam0_mm);
    double se = 0;

    // Refinement on the images: the rig pose in camera 0's frame that best reprojects the bodies.json markers
    // onto their averaged images (each view weighted alike; the cameras fixed). Partly hidden markers go first.
    struct View {
        size_t point;
        size_t cam;
        Vec3 model;
        Vec2 px;
        double fill = 0;  // blob area / a whole marker's at its distance (0: unknown)
        bool use = true;
    };
    std::vector<View> views;
    for (size_t p = 0; p < np; ++p) {
        if (best_match[p] < 0) continue;
        const auto& mk = body.markers[static_cast<size_t>(best_match[p])];
        for (size_t c = 0; c < nc; ++c) {
            if (pts[p].image[c] < 0) continue;
            const size_t k = static_cast<size_t>(pts[p].image[c]);
            View v{p, c, model[static_cast<size_t>(best_match[p])], eye.px[c][k]};
            const double z = (cams[c].R_cam_rig * pts[p].X + cams[c].t_cam_rig_mm).z();
            // Field pixels: half the frame rows.
            const double whole = kPi * (cams[c].fx * mk.radius_mm / z) * (cams[c].fy * mk.radius_mm / z) / 2.0;
            const double area = c < eye.area_px.size() && k < eye.area_px[c].size() ? eye.area_px[c][k] : 0.0;
            v.fill = area > 0 ? area / whole : 0.0;
            views.push_back(v);
        }
    }
    // Partly hidden: a fill below 75 % of the camera's median fill (the median marker is whole; the median, not
    // 1, because how far a blob reaches into a marker's rim depends on the camera and the video's chroma).
    for (size_t c = 0; c < nc; ++c) {
        std::vector<double> f;
        for (const View& v : views)
            if (v.cam == c && v.fill > 0) f.push_back(v.fill);
        if (f.empty()) continue;
        std::nth_element(f.begin(), f.begin() + static_cast<std::ptrdiff_t>(f.size() / 2), f.end());
        const double med = f[f.size() / 2];
        for (View& v : views)
            if (v.cam == c && v.fill > 0 && v.fill < 0.75 * med) {
                v.use = false;
                ++fit.views_dropped;
            }
    }
    const Eigen::Matrix3d R_c0_rig = fit.R_rig_cam0.transpose();
    const Vec3 t_c0_rig = -R_c0_rig * fit.t_rig_cam0_mm;
    double pose[6];
    ceres::RotationMatrixToAngleAxis(ceres::ColumnMajorAdapter3x3(R_c0_rig.data()), pose);
    for (int k = 0; k < 3; ++k) pose[3 + k] = t_c0_rig[k];
    auto refine = [&]() {
        ceres::Problem problem;
        int kept = 0;
        for (const View& v : views)
            if (v.use) {
                problem.AddResidualBlock(new ceres::AutoDiffCostFunction<EyeResidual, 2, 6>(new EyeResidual{cams[v.cam], v.model, v.px}),
                                         nullptr, pose);
                ++kept;
            }
        if (kept < 3) throw CalibrationError(fmt::format("rig frame: {} whole eye-marker images, at least 3 needed", kept));
        ceres::Solver::Options so;
        so.linear_solver_type = ceres::DENSE_QR;
        so.max_num_iterations = 50;
        so.function_tolerance = 1e-14;
        so.parameter_tolerance = 1e-14;
        ceres::Solver::Summary sum;
        ceres::Solve(so, &problem, &sum);
        if (sum.termination_type == ceres::FAILURE)
            throw CalibrationError("rig frame: the eye-marker refinement failed: " + sum.message);
        return kept;
    };
    auto residual = [&](const View& v) {
        double r[2];
        EyeResidual{cams[v.cam], v.model, v.px}(pose, r);
        return std::hypot(r[0], r[1]);
    };
    // Then the worst image, one at a time, while it is off by more than max(0.2 px, 4 × the median of the others)
    // and enough images are left (a marker's image half hidden by another body pulls the whole fit).
    fit.views = refine();
    while (fit.views > 4) {
        std::vector<double> e;
        View* worst = nullptr;
        for (View& v : views)
            if (v.use) {
                e.push_back(residual(v));
                if (!worst || e.back() > residual(*worst)) worst = &v;
            }
        const double w = residual(*worst);
        std::sort(e.begin(), e.end());
        e.pop_back();  // the worst itself
        if (!(w > std::max(0.2, 4.0 * e[e.size() / 2]))) break;
        worst->use = false;
        ++fit.views_dropped;
        fit.views = refine();
    }
    double se2 = 0;
    for (const View& v : views)
        if (v.use) se2 += residual(v) * residual(v);
    fit.residual_px_rms = std::sqrt(se2 / fit.views);
    double Rm[9];
    ceres::AngleAxisToRotationMatrix(pose, ceres::ColumnMajorAdapter3x3(Rm));
    const Eigen::Matrix3d R = Eigen::Map<const Eigen::Matrix3d>(Rm);
    fit.R_rig_cam0 = R.transpose();
    fit.t_rig_cam0_mm = -R.transpose() * Vec3(pose[3], pose[4], pose[5]);
    // 3D residual: each marker triangulated again from the images kept (two or more), against bodies.json.
    se = 0;
    int n3 = 0;
    for (size_t p = 0; p < np; ++p) {
        std::vector<Ray> rays;
        Vec3 m = Vec3::Zero();
        for (const View& v : views)
            if (v.point == p && v.use) {
                const auto u = cams[v.cam].undistort_to_normalized(v.px);
                if (u) rays.push_back(ray_of(cams[v.cam], *u));
                m = v.model;
            }
        if (rays.size() < 2) continue;
        se += (fit.R_rig_cam0 * intersect(rays) + fit.t_rig_cam0_mm - m).squaredNorm();
        ++n3;
    }
    fit.residual_mm_rms = n3 ? std::sqrt(se / n3) : 0.0;
    return fit;
}

std::vector<rig::CameraModel> to_rig_frame(const std::vector<rig::CameraModel>& cams, const RigFrameFit& fit) {
    // x_cam = R x_cam0 + t, x_cam0 = Rrᵀ (x_rig − tr)  ⇒  x_cam = R Rrᵀ x_rig + (t − R Rrᵀ tr).
    std::vector<rig::CameraModel> out = cams;
    for (rig::CameraModel& c : out) {
        const Eigen::Matrix3d R = c.R_cam_rig * fit.R_rig_cam0.transpose();
        c.t_cam_rig_mm = c.t_cam_rig_mm - R * fit.t_rig_cam0_mm;
        c.R_cam_rig = R;
    }
    return out;
}

}  // namespace eyesim::calibration
