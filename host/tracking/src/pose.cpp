#include "eyesim/tracking/pose.hpp"

#include "eyesim/tracking/rigid_fit.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>

namespace eyesim::tracking {

bool InstrumentModel::markers_on_axis(double tol_mm) const {
    const Eigen::Vector3d a = axis_body.normalized();
    for (int i = 0; i < marker_count; ++i) {
        const Eigen::Vector3d d = markers[std::size_t(i)].pos_body_mm - tip_body_mm;
        if ((d - d.dot(a) * a).norm() > tol_mm) return false;
    }
    return true;
}

namespace {

/// Depth-first search for the assignment of measured markers to one body's markers that keeps the most markers
/// with all pairwise distances consistent with the model (rigid-body constraint), then the smallest distance
/// error. Bodies carry at most kMaxBodyMarkers markers, so the search is tiny.
struct AssignmentSearch {
    const BodyMarker* model = nullptr;
    int model_count = 0;
    const CorrespondenceResult* found = nullptr;
    const std::array<bool, kMaxMarkersPerFrame>* claimed = nullptr;
    double tol_mm = 0.4;
    // Optional per-marker check (eye: distance from the fixed centre).
    const Eigen::Vector3d* centre = nullptr;
    double radius_tol_mm = 0.6;

    std::array<int, kMaxBodyMarkers> current{};
    std::array<int, kMaxBodyMarkers> best{};
    int best_count = 0;
    double best_err = 0.0;
    int visits = 0;

    void run() {
        current.fill(-1);
        best.fill(-1);
        best_count = 0;
        best_err = 0.0;
        visits = 0;
        recurse(0, 0, 0.0);
    }

    void recurse(int i, int count, double err) {
        if (++visits > 20000) return;  // bound on pathological inputs (many same-coloured markers)
        if (i == model_count) {
            if (count > best_count || (count == best_count && count > 0 && err < best_err)) {
                best = current;
                best_count = count;
                best_err = err;
            }
            return;
        }
        // Not enough markers left to beat the best: prune.
        if (count + (model_count - i) < best_count) return;
        const BodyMarker& bm = model[i];
        for (int k = 0; k < found->count; ++k) {
            const MatchedMarker& m = found->markers[std::size_t(k)];
            if ((*claimed)[std::size_t(k)] || m.colour_class != bm.colour_class || !m.point.usable()) continue;
            bool taken = false;
            for (int j = 0; j < i; ++j)
                if (current[std::size_t(j)] == k) taken = true;
            if (taken) continue;
            if (centre) {
                const double r = (m.point.X_rig_mm - *centre).norm();
                if (std::abs(r - bm.pos_body_mm.norm()) > radius_tol_mm) continue;
            }
            double e = err;
            bool ok = true;
            for (int j = 0; j < i && ok; ++j) {
                const int kj = current[std::size_t(j)];
                if (kj < 0) continue;
                const double dm = (m.point.X_rig_mm - found->markers[std::size_t(kj)].point.X_rig_mm).norm();
                const double db = (bm.pos_body_mm - model[j].pos_body_mm).norm();
                const double de = dm - db;
                if (std::abs(de) > tol_mm) ok = false;
                e += de * de;
            }
            if (!ok) continue;
            current[std::size_t(i)] = k;
            recurse(i + 1, count + 1, e);
            current[std::size_t(i)] = -1;
        }
        recurse(i + 1, count, err);
    }
};

// 1 / the point's variance; a flagged marker's (MatchedMarker::occluded) with its bias's `occluded_var_mm2` added.
double weight_of(const MatchedMarker& m, double occluded_var_mm2) {
    double var = m.point.cov_mm2.trace() / 3.0;
    if (!(var > 0.0) || !std::isfinite(var)) var = 1.0;
    if (m.occluded) var += occluded_var_mm2;
    return 1.0 / var;
}

}  // namespace

bool fit_instrument(const InstrumentModel& model, std::span<const Eigen::Vector3d> measured_rig_mm,
                    std::span<const int> which, std::span<const double> weights, InstrumentPose& pose,
                    const Eigen::Vector3d* trocar_rig_mm, double trocar_weight) {
    const std::size_t n = measured_rig_mm.size();
    if (n < 2 || which.size() != n || n > std::size_t(kMaxBodyMarkers)) return false;
    std::array<Eigen::Vector3d, kMaxBodyMarkers> body{};
    for (std::size_t k = 0; k < n; ++k) {
        if (which[k] < 0 || which[k] >= model.marker_count) return false;
        body[k] = model.markers[std::size_t(which[k])].pos_body_mm;
    }
    const std::span<const Eigen::Vector3d> b(body.data(), n);
    const Eigen::Vector3d a_body = model.axis_body.normalized();
    // Are the used markers (with the tip) on one line? Then only tip and axis are observable.
    bool collinear = true;
    for (std::size_t k = 0; k < n; ++k) {
        const Eigen::Vector3d d = b[k] - model.tip_body_mm;
        if ((d - d.dot(a_body) * a_body).norm() > 1e-6) collinear = false;
    }
    if (!collinear && n >= 3) {
        const RigidFit f = fit_rigid(b, measured_rig_mm, weights);
        if (f.ok) {
            pose.tip_rig_mm = f.R * model.tip_body_mm + f.t_mm;
            pose.axis_rig = (f.R * a_body).normalized();
            pose.rotation_body_to_rig = Eigen::Quaterniond(f.R).normalized();
            pose.fit_rms_mm = f.rms_mm;
            pose.markers_used = int(n);
            pose.flags = kPoseOk;
            return true;
        }
    }
    // Constrained line fit: m_k ≈ T + s_k·A with s_k the known distance from the tip along the shaft and |A| = 1.
    // The unit A minimising Σ w‖m̃ − s̃A‖² is normalise(Σ w s̃ m̃) (weighted-centred quantities); T = m̄ − s̄A.
    // A trocar point p joins as one more point at the unknown s_p = (p − T)·A (block coordinate descent on
    // Σ w‖m − T − sA‖² + w_p·dist²(p, line), a few rounds).
    std::array<double, kMaxBodyMarkers + 1> s{};
    std::array<double, kMaxBodyMarkers + 1> wt{};
    std::array<Eigen::Vector3d, kMaxBodyMarkers + 1> m{};
    for (std::size_t k = 0; k < n; ++k) {
        s[k] = (b[k] - model.tip_body_mm).dot(a_body);
        wt[k] = weights.empty() ? 1.0 : weights[k];
        m[k] = measured_rig_mm[k];
    }
    Eigen::Vector3d A = Eigen::Vector3d::Zero(), T = Eigen::Vector3d::Zero();
    auto solve = [&](std::size_t count) -> bool {
        double wsum = 0.0, sbar = 0.0;
        Eigen::Vector3d mbar = Eigen::Vector3d::Zero();
        for (std::size_t k = 0; k < count; ++k) {
            wsum += wt[k];
            sbar += wt[k] * s[k];
            mbar += wt[k] * m[k];
        }
        if (!(wsum > 0.0)) return false;
        sbar /= wsum;
        mbar /= wsum;
        Eigen::Vector3d a = Eigen::Vector3d::Zero();
        double spread = 0.0;
        for (std::size_t k = 0; k < count; ++k) {
            a += wt[k] * (s[k] - sbar) * (m[k] - mbar);
            spread += wt[k] * (s[k] - sbar) * (s[k] - sbar);
        }
        if (!(spread > 1e-9 * wsum) || !(a.norm() > 0.0) || !a.allFinite()) return false;  // one point twice
        A = a.normalized();
        T = mbar - sbar * A;
        return true;
    };
    if (!solve(n)) return false;
    std::size_t used = n;
    if (trocar_rig_mm && trocar_weight > 0.0 && trocar_rig_mm->allFinite()) {
        m[n] = *trocar_rig_mm;
        wt[n] = trocar_weight;
        used = n + 1;
        for (int round = 0; round < 8; ++round) {
            s[n] = (m[n] - T).dot(A);
            if (!solve(used)) return false;
        }
    }
    pose.axis_rig = A;
    pose.tip_rig_mm = T;
    pose.rotation_body_to_rig = Eigen::Quaterniond::FromTwoVectors(a_body, A).normalized();
    double ss = 0.0;
    for (std::size_t k = 0; k < n; ++k) ss += (T + s[k] * A - m[k]).squaredNorm();
    pose.fit_rms_mm = std::sqrt(ss / double(n));
    pose.markers_used = int(n);
    pose.flags = kPoseNoRoll;
    return true;
}

bool fit_instrument_images(std::span<const ShaftImage> images, const InstrumentModel& model,
                           const Eigen::Vector3d& trocar_rig_mm, const InstrumentPose& start, InstrumentPose& pose,
                           double& rms_px) {
    constexpr std::size_t kMax = kMaxShaftImages;
    const std::size_t n = images.size();
    if (n < 3 || n > kMax || !trocar_rig_mm.allFinite()) return false;
    const Eigen::Vector3d a_body = model.axis_body.normalized();
    std::array<double, kMax> s{};  // each image's marker's distance from the tip along the shaft
    for (std::size_t k = 0; k < n; ++k) {
        const ShaftImage& im = images[k];
        if (!im.camera || im.marker < 0 || im.marker >= model.marker_count || !im.xn.allFinite()) return false;
        s[k] = (model.markers[std::size_t(im.marker)].pos_body_mm - model.tip_body_mm).dot(a_body);
    }
    // Marker k at P + (s_k − d)·A: A the unit axis (tip → handle), d the tip's depth behind the trocar P.
    Eigen::Vector3d A = start.axis_rig.normalized();
    double d = (trocar_rig_mm - start.tip_rig_mm).dot(A);
    if (!A.allFinite() || !std::isfinite(d)) return false;
    // Residuals (px) and, with J, their derivatives by (u, v, d), A moved to normalise(A + u·e1 + v·e2).
    using Residuals = Eigen::Matrix<double, 2 * kMax, 1>;
    using Jacobian = Eigen::Matrix<double, 2 * kMax, 3>;
    auto residuals = [&](const Eigen::Vector3d& axis, double depth, Residuals& r, Jacobian* J, const Eigen::Vector3d& e1,
                         const Eigen::Vector3d& e2) -> bool {
        for (std::size_t k = 0; k < n; ++k) {
            const CameraGeometry& cam = *images[k].camera;
            const Eigen::Vector2d& xn = images[k].xn;
            const double f = cam.mean_focal_px();
            const Eigen::Vector3d X = trocar_rig_mm + (s[k] - depth) * axis;
            const Eigen::Vector3d c = cam.R_cam_rig * X + cam.t_cam_rig_mm;
            if (!(c.z() > 1e-6)) return false;
            const double iz = 1.0 / c.z();
            r(Eigen::Index(2 * k)) = f * (c.x() * iz - xn.x());
            r(Eigen::Index(2 * k + 1)) = f * (c.y() * iz - xn.y());
            if (!J) continue;
            Eigen::Matrix<double, 2, 3> dp;
            dp << iz, 0.0, -c.x() * iz * iz, 0.0, iz, -c.y() * iz * iz;
            const Eigen::Matrix<double, 2, 3> dpx = f * dp * cam.R_cam_rig;  // ∂r/∂X
            J->block<2, 1>(Eigen::Index(2 * k), 0) = dpx * ((s[k] - depth) * e1);
            J->block<2, 1>(Eigen::Index(2 * k), 1) = dpx * ((s[k] - depth) * e2);
            J->block<2, 1>(Eigen::Index(2 * k), 2) = dpx * (-axis);
        }
        return true;
    };
    const Eigen::Index m = Eigen::Index(2 * n);
    Residuals r = Residuals::Zero(), r_try = r;
    Jacobian J = Jacobian::Zero();
    auto basis = [](const Eigen::Vector3d& a, Eigen::Vector3d& e1, Eigen::Vector3d& e2) {
        e1 = a.unitOrthogonal();
        e2 = a.cross(e1);
    };
    Eigen::Vector3d e1, e2;
    basis(A, e1, e2);
    if (!residuals(A, d, r, &J, e1, e2)) return false;
    double cost = r.head(m).squaredNorm(), lambda = 1e-3;
    bool converged = false;
    for (int it = 0; it < 30 && !converged; ++it) {
        const Eigen::Matrix3d H = J.topRows(m).transpose() * J.topRows(m);
        const Eigen::Vector3d g = J.topRows(m).transpose() * r.head(m);
        // The shaft along the line of sight leaves its direction unobservable.
        const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(H, Eigen::EigenvaluesOnly);
        if (!(eig.eigenvalues()(0) > 1e-9 * eig.eigenvalues()(2))) return false;
        bool stepped = false;
        for (int tries = 0; tries < 10 && !stepped; ++tries) {
            Eigen::Matrix3d Hd = H;
            Hd.diagonal() *= 1.0 + lambda;
            const Eigen::Vector3d step = Hd.ldlt().solve(-g);
            if (!step.allFinite()) return false;
            const Eigen::Vector3d A_try = (A + step(0) * e1 + step(1) * e2).normalized();
            const double d_try = d + step(2);
            if (residuals(A_try, d_try, r_try, nullptr, e1, e2) && r_try.head(m).squaredNorm() < cost) {
                converged = step.head<2>().norm() < 1e-10 && std::abs(step(2)) < 1e-8;
                A = A_try;
                d = d_try;
                cost = r_try.head(m).squaredNorm();
                lambda = std::max(lambda * 0.1, 1e-9);
                stepped = true;
            } else {
                lambda *= 10.0;
            }
        }
        if (!stepped) converged = true;  // no step lowers the cost: at the minimum to rounding
        basis(A, e1, e2);
        if (!residuals(A, d, r, &J, e1, e2)) return false;
    }
    rms_px = std::sqrt(cost / double(n));
    pose.axis_rig = A;
    pose.tip_rig_mm = trocar_rig_mm - d * A;
    pose.rotation_body_to_rig = Eigen::Quaterniond::FromTwoVectors(a_body, A).normalized();
    pose.fit_rms_mm = 0.0;
    pose.markers_used = int(n);
    pose.flags = kPoseNoRoll | kPoseSingleView;
    return std::isfinite(rms_px) && pose.tip_rig_mm.allFinite();
}

bool fit_instrument_one_view(const CameraGeometry& cam, const InstrumentModel& model, const Eigen::Vector3d& trocar_rig_mm,
                             std::span<const Eigen::Vector2d> xn, std::span<const int> which,
                             const InstrumentPose& start, InstrumentPose& pose, double& rms_px) {
    if (xn.size() != which.size() || xn.size() > std::size_t(kMaxBodyMarkers)) return false;
    std::array<ShaftImage, kMaxBodyMarkers> images{};
    for (std::size_t k = 0; k < xn.size(); ++k) images[k] = ShaftImage{&cam, xn[k], which[k]};
    return fit_instrument_images(std::span<const ShaftImage>(images.data(), xn.size()), model, trocar_rig_mm, start, pose,
                                 rms_px);
}

void instrument_in_eye(const InstrumentModel& model, const EyePose& eye, InstrumentPose& pose) {
    const Eigen::Matrix3d Re = eye.rotation_eye_to_rig.toRotationMatrix();
    pose.tip_eye_mm = Re.transpose() * (pose.tip_rig_mm - eye.centre_rig_mm);
    pose.axis_eye = (Re.transpose() * pose.axis_rig).normalized();
    pose.rotation_body_to_eye = (eye.rotation_eye_to_rig.conjugate() * pose.rotation_body_to_rig).normalized();
    // The axis points tip→handle, so a tip past the trocar (inside the eye) has a positive depth.
    pose.insertion_depth_mm = model.has_trocar ? (model.trocar_eye_mm - pose.tip_eye_mm).dot(pose.axis_eye) : 0.0;
    if (!eye.measured()) pose.flags |= kPoseNoEye;
}

namespace {

/// Gathers assigned markers (search.best) into contiguous arrays; returns the count.
int gather(const std::array<int, kMaxBodyMarkers>& best, int model_count, const CorrespondenceResult& found,
           std::array<Eigen::Vector3d, kMaxBodyMarkers>& meas, std::array<int, kMaxBodyMarkers>& which,
           std::array<double, kMaxBodyMarkers>& w, double occluded_var_mm2 = 0.0) {
    int n = 0;
    for (int i = 0; i < model_count; ++i) {
        const int k = best[std::size_t(i)];
        if (k < 0) continue;
        meas[std::size_t(n)] = found.markers[std::size_t(k)].point.X_rig_mm;
        which[std::size_t(n)] = i;
        w[std::size_t(n)] = weight_of(found.markers[std::size_t(k)], occluded_var_mm2);
        ++n;
    }
    return n;
}

/// Eye fit for one assignment; returns the fit (ok = false when undetermined).
RigidFit fit_eye(const EyeModel& model, const std::array<int, kMaxBodyMarkers>& best,
                 const CorrespondenceResult& found, int& n) {
    std::array<Eigen::Vector3d, kMaxBodyMarkers> meas{}, body{};
    std::array<int, kMaxBodyMarkers> which{};
    std::array<double, kMaxBodyMarkers> w{};
    n = gather(best, model.marker_count, found, meas, which, w);
    for (int k = 0; k < n; ++k) body[std::size_t(k)] = model.markers[std::size_t(which[std::size_t(k)])].pos_body_mm;
    if (n < 2) return {};
    return fit_rotation_about(model.centre_rig_mm, std::span(body.data(), std::size_t(n)),
                              std::span(meas.data(), std::size_t(n)), std::span(w.data(), std::size_t(n)));
}

}  // namespace

void fit_poses(const BodySet& bodies, const CorrespondenceResult& found, const PoseOptions& opt,
               const EyePose& previous_eye, std::span<const InstrumentPose> previous_instruments, EyePose& eye,
               std::span<InstrumentPose> instruments, MarkerAssignment& assignment) {
    assignment.body.fill(-1);
    assignment.marker.fill(-1);
    std::array<bool, kMaxMarkersPerFrame> claimed{};
    std::array<Eigen::Vector3d, kMaxBodyMarkers> meas{};
    std::array<double, kMaxBodyMarkers> w{};
    std::array<int, kMaxBodyMarkers> which{};

    // --- Eye: rotation about its fixed centre. First match each model marker to the nearest measured marker
    // of its class around its position predicted by the last eye rotation (the eye moves little per field);
    // if that leaves the fit poor, search assignments by rigid distances alone. ---
    eye = previous_eye;
    eye.centre_rig_mm = bodies.eye.centre_rig_mm;
    {
        const EyeModel& em = bodies.eye;
        std::array<int, kMaxBodyMarkers> prior{};
        prior.fill(-1);
        const Eigen::Matrix3d R0 = previous_eye.rotation_eye_to_rig.toRotationMatrix();
        for (int i = 0; i < em.marker_count; ++i) {
            const Eigen::Vector3d pred = R0 * em.markers[std::size_t(i)].pos_body_mm + em.centre_rig_mm;
            double bd = opt.eye_prior_gate_mm;
            for (int k = 0; k < found.count; ++k) {
                const MatchedMarker& mk = found.markers[std::size_t(k)];
                if (mk.colour_class != em.markers[std::size_t(i)].colour_class || !mk.point.usable() || mk.occluded)
                    continue;
                const double d = (mk.point.X_rig_mm - pred).norm();
                if (d < bd) { bd = d; prior[std::size_t(i)] = k; }
            }
        }
        // A measured marker claimed by two model markers keeps only the nearer one.
        for (int i = 0; i < em.marker_count; ++i)
            for (int j = i + 1; j < em.marker_count; ++j)
                if (prior[std::size_t(i)] >= 0 && prior[std::size_t(i)] == prior[std::size_t(j)]) {
                    prior[std::size_t(i)] = -1;
                    prior[std::size_t(j)] = -1;
                }
        int n_prior = 0;
        RigidFit f = fit_eye(em, prior, found, n_prior);
        std::array<int, kMaxBodyMarkers> chosen = prior;
        int n = n_prior;
        if (!f.ok || f.rms_mm > opt.max_fit_rms_mm || n_prior < 3) {
            AssignmentSearch search;
            search.model = em.markers.data();
            search.model_count = em.marker_count;
            search.found = &found;
            search.claimed = &claimed;
            search.tol_mm = opt.distance_tol_mm;
            search.centre = &em.centre_rig_mm;
            search.radius_tol_mm = opt.eye_radius_tol_mm;
            search.run();
            int n_search = 0;
            const RigidFit fs = fit_eye(em, search.best, found, n_search);
            const bool better = fs.ok && (!f.ok || n_search > n || (n_search == n && fs.rms_mm < f.rms_mm));
            if (better) { f = fs; chosen = search.best; n = n_search; }
        }
        if (f.ok) {
            eye.rotation_eye_to_rig = Eigen::Quaterniond(f.R).normalized();
            eye.fit_rms_mm = f.rms_mm;
            eye.markers_used = n;
            eye.flags = f.rms_mm > opt.max_fit_rms_mm ? kPoseHighResidual : kPoseOk;
            for (int i = 0; i < em.marker_count; ++i) {
                const int k = chosen[std::size_t(i)];
                if (k < 0) continue;
                claimed[std::size_t(k)] = true;
                assignment.body[std::size_t(k)] = 0;
                assignment.marker[std::size_t(k)] = std::int8_t(i);
            }
        } else {
            eye.flags = kPoseTooFewMarkers | kPoseHeld;
            eye.markers_used = n;
        }
    }

    // --- Instruments: those measured in the last frame first (they keep their markers with fewer of them). ---
    std::array<int, kMaxInstruments> order{};
    int no = 0;
    for (int pass = 0; pass < 2; ++pass)
        for (int b = 0; b < bodies.instrument_count && b < int(instruments.size()); ++b) {
            const bool was = std::size_t(b) < previous_instruments.size() && previous_instruments[std::size_t(b)].measured();
            if ((pass == 0) == was) order[std::size_t(no++)] = b;
        }
    const Eigen::Matrix3d Re = eye.rotation_eye_to_rig.toRotationMatrix();
    for (int oi = 0; oi < no; ++oi) {
        const int b = order[std::size_t(oi)];
        const InstrumentModel& model = bodies.instruments[std::size_t(b)];
        InstrumentPose& pose = instruments[std::size_t(b)];
        const double opening = pose.opening;  // set by the caller from the pedal; keep it
        const bool was = std::size_t(b) < previous_instruments.size() && previous_instruments[std::size_t(b)].measured();
        AssignmentSearch search;
        search.model = model.markers.data();
        search.model_count = model.marker_count;
        search.found = &found;
        search.claimed = &claimed;
        search.tol_mm = opt.distance_tol_mm;
        search.run();
        const int n = gather(search.best, model.marker_count, found, meas, which, w,
                             opt.occluded_sigma_mm * opt.occluded_sigma_mm);
        const int need = was ? opt.min_markers_keep : std::min(opt.min_markers_acquire, model.marker_count);
        InstrumentPose fitted = pose;
        const std::span<const Eigen::Vector3d> ms(meas.data(), std::size_t(n));
        const std::span<const int> ws(which.data(), std::size_t(n));
        const std::span<const double> wts(w.data(), std::size_t(n));
        // Fewer markers than `need` (a shaft deep in the eye hides its distal marker behind the eye) are enough
        // when the trocar confirms them: two markers and the trocar are three points on one line.
        bool ok = n >= 2 && fit_instrument(model, ms, ws, wts, fitted);
        bool through_trocar = false;
        if (ok && opt.trocar_constraint && model.has_trocar && eye.measured()) {
            // Through the trocar only when the tip is inside the eye and the markers agree with the trocar.
            const Eigen::Vector3d p = Re * model.trocar_eye_mm + eye.centre_rig_mm;
            const Eigen::Vector3d d = p - fitted.tip_rig_mm;
            const double depth = d.dot(fitted.axis_rig);
            const double off_line = (d - depth * fitted.axis_rig).norm();
            if (depth > 0.0 && off_line < opt.trocar_gate_mm) {
                InstrumentPose through = fitted;
                if (fit_instrument(model, ms, ws, wts, through, &p,
                                   1.0 / (opt.trocar_sigma_mm * opt.trocar_sigma_mm))) {
                    fitted = through;
                    through_trocar = true;
                }
            }
        }
        ok = ok && (n >= need || through_trocar);
        int single = -1;  // a lone marker that kept the instrument (below)
        if (!ok && was && opt.trocar_constraint && model.has_trocar && eye.measured()) {
            // One marker and the trocar still give the shaft's line: keep an instrument measured last frame when a
            // marker of the right class lies where its last pose puts one of its markers (a needle deep in the eye
            // shows only its proximal marker). Never used to acquire.
            const InstrumentPose& last = previous_instruments[std::size_t(b)];
            const Eigen::Vector3d p = Re * model.trocar_eye_mm + eye.centre_rig_mm;
            const Eigen::Vector3d a_body = model.axis_body.normalized();
            double best = opt.single_marker_gate_mm;
            int best_i = -1;
            for (int i = 0; i < model.marker_count; ++i) {
                const double si = (model.markers[std::size_t(i)].pos_body_mm - model.tip_body_mm).dot(a_body);
                const Eigen::Vector3d pred = last.tip_rig_mm + si * last.axis_rig;
                for (int k = 0; k < found.count; ++k) {
                    const MatchedMarker& mk = found.markers[std::size_t(k)];
                    if (claimed[std::size_t(k)] || mk.colour_class != model.markers[std::size_t(i)].colour_class ||
                        !mk.point.usable())
                        continue;
                    const double d = (mk.point.X_rig_mm - pred).norm();
                    if (d < best) { best = d; best_i = i; single = k; }
                }
            }
            if (single >= 0) {
                const Eigen::Vector3d m = found.markers[std::size_t(single)].point.X_rig_mm;
                const double si = (model.markers[std::size_t(best_i)].pos_body_mm - model.tip_body_mm).dot(a_body);
                const Eigen::Vector3d A = (m - p).normalized();  // tip → handle: the marker is outside the trocar
                fitted = last;
                fitted.axis_rig = A;
                fitted.tip_rig_mm = m - si * A;
                fitted.rotation_body_to_rig = Eigen::Quaterniond::FromTwoVectors(a_body, A).normalized();
                fitted.fit_rms_mm = 0.0;
                fitted.markers_used = 1;
                fitted.flags = kPoseNoRoll | kPoseSingleMarker;
                ok = (m - p).norm() > 1.0 && (m - p).dot(last.axis_rig) > 0.0 && si > (m - p).norm();
                if (ok) search.best.fill(-1), search.best[std::size_t(best_i)] = single;
            }
        }
        bool jumped = false;
        if (ok && was && (fitted.tip_rig_mm - previous_instruments[std::size_t(b)].tip_rig_mm).norm() > opt.max_tip_jump_mm) {
            ok = false;  // markers of another instrument fitted by chance (crossing shafts): do not report it
            jumped = true;
        }
        if (ok) {
            if (fitted.fit_rms_mm > opt.max_fit_rms_mm) fitted.flags |= kPoseHighResidual;
            pose = fitted;
            for (int i = 0; i < model.marker_count; ++i) {
                const int k = search.best[std::size_t(i)];
                if (k < 0) continue;
                claimed[std::size_t(k)] = true;
                assignment.body[std::size_t(k)] = std::int8_t(1 + b);
                assignment.marker[std::size_t(k)] = std::int8_t(i);
            }
        } else {
            if (std::size_t(b) < previous_instruments.size()) pose = previous_instruments[std::size_t(b)];
            pose.flags = (pose.flags & kPoseNoRoll) | kPoseTooFewMarkers | kPoseHeld | (jumped ? kPoseJumpRejected : 0u);
            pose.markers_used = n;
        }
        pose.opening = opening;
        instrument_in_eye(model, eye, pose);
    }
}

}  // namespace eyesim::tracking
