#include "eyesim/tracking/triangulate.hpp"

#include "eyesim/tracking/distortion.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include <cmath>

namespace eyesim::tracking {

bool triangulate_dlt(std::span<const CameraGeometry> cams, std::span<const Observation> obs,
                     Eigen::Vector3d& X_rig_mm) {
    // Each view gives two linear equations (u·r3 − r1)·X = t1 − u·t3 and (v·r3 − r2)·X = t2 − v·t3. The
    // rows are normalised so every view weighs alike; accumulate the 3×3 normal equations directly.
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    int n = 0;
    for (const Observation& o : obs) {
        if (o.camera < 0 || o.camera >= int(cams.size()) || !o.xn.allFinite()) continue;
        const CameraGeometry& c = cams[std::size_t(o.camera)];
        const Eigen::Matrix3d& R = c.R_cam_rig;
        const Eigen::Vector3d& t = c.t_cam_rig_mm;
        for (int k = 0; k < 2; ++k) {
            const double u = o.xn[k];
            const Eigen::Vector3d row = u * R.row(2).transpose() - R.row(k).transpose();
            const double rhs = t[k] - u * t[2];
            const double w = 1.0 / std::max(row.squaredNorm(), 1e-300);
            A.noalias() += w * row * row.transpose();
            b += w * rhs * row;
        }
        ++n;
    }
    if (n < 2) return false;
    Eigen::LDLT<Eigen::Matrix3d> ldlt(A);
    if (ldlt.info() != Eigen::Success) return false;
    const Eigen::Vector3d X = ldlt.solve(b);
    if (!X.allFinite()) return false;
    X_rig_mm = X;
    return true;
}

namespace {

/// Sum of squared normalised residuals, and the Gauss-Newton system, at X. Returns false when X is behind a
/// camera.
bool normal_equations(std::span<const CameraGeometry> cams, std::span<const Observation> obs,
                      const Eigen::Vector3d& X, Eigen::Matrix3d& H, Eigen::Vector3d& g, double& cost,
                      double& sum_sq_px) {
    H.setZero();
    g.setZero();
    cost = 0.0;
    sum_sq_px = 0.0;
    for (const Observation& o : obs) {
        const CameraGeometry& c = cams[std::size_t(o.camera)];
        Eigen::Vector2d px;
        Eigen::Matrix<double, 2, 3> J;
        if (!project_point(c, X, px, &J)) return false;
        const Eigen::Vector2d r = o.px - px;
        const double w = 1.0 / (o.sigma_px * o.sigma_px);
        H.noalias() += w * J.transpose() * J;
        g.noalias() += w * J.transpose() * r;
        cost += w * r.squaredNorm();
        sum_sq_px += r.squaredNorm();
    }
    return true;
}

}  // namespace

TriangulatedPoint triangulate(std::span<const CameraGeometry> cams, std::span<const Observation> obs,
                              const TriangulationOptions& opt) {
    TriangulatedPoint out;
    // Keep only well-formed observations; count them.
    std::array<Observation, kMaxCameras * 2> use{};
    int n = 0;
    for (const Observation& o : obs) {
        const bool idx_ok = o.camera >= 0 && o.camera < int(cams.size());
        if (!idx_ok || !o.px.allFinite() || !o.xn.allFinite() || !(o.sigma_px > 0.0) ||
            !std::isfinite(o.sigma_px) || !cams[std::size_t(o.camera)].R_cam_rig.allFinite()) {
            out.flags |= kTriNonFinite;
            continue;
        }
        if (n < int(use.size())) use[std::size_t(n++)] = o;
    }
    out.views = n;
    if (n < 2) {
        out.flags |= kTriTooFewViews;
        return out;
    }
    const std::span<const Observation> u(use.data(), std::size_t(n));
    Eigen::Vector3d X;
    if (!triangulate_dlt(cams, u, X)) {
        out.flags |= kTriDegenerate;
        return out;
    }
    Eigen::Matrix3d H;
    Eigen::Vector3d g;
    double cost = 0.0, ssq = 0.0;
    if (!normal_equations(cams, u, X, H, g, cost, ssq)) {
        out.flags |= kTriBehindCamera;
        out.X_rig_mm = X;
        return out;
    }
    if (opt.refine) {
        // Levenberg–Marquardt with Marquardt's diagonal scaling; 3 unknowns so each step is a 3×3 solve and one
        // evaluation. From the DLT start it is Gauss–Newton in practice (λ tiny): 1–3 evaluations.
        double lambda = 1e-9;
        bool converged = false;
        int it = 0;
        while (it < opt.max_iterations && !converged) {
            ++it;
            Eigen::Matrix3d A = H;
            A.diagonal() += lambda * H.diagonal();
            const Eigen::Vector3d dx = A.ldlt().solve(g);
            if (!dx.allFinite()) break;
            if (dx.norm() < opt.step_tolerance_mm) {
                converged = true;  // the next step would not move the point: at the minimum
                break;
            }
            const Eigen::Vector3d Xt = X + dx;
            Eigen::Matrix3d Ht;
            Eigen::Vector3d gt;
            double ct = 0.0, st = 0.0;
            if (normal_equations(cams, u, Xt, Ht, gt, ct, st) && ct <= cost) {
                const double decrease = cost - ct;
                X = Xt; H = Ht; g = gt; cost = ct; ssq = st;
                lambda = std::max(lambda * 0.1, 1e-12);
                if (decrease <= 1e-14 * (1.0 + cost)) converged = true;
            } else {
                lambda *= 100.0;
                if (lambda > 1e8) converged = true;  // no decrease in any direction: at the minimum
            }
        }
        out.iterations = it;
        if (!converged) out.flags |= kTriNotConverged;
    }
    out.X_rig_mm = X;
    out.rms_px = std::sqrt(ssq / double(n));
    // Covariance of the estimate: (JᵀWJ)⁻¹ with W = 1/σ² (closed-form 3×3 inverse). Its trace bounds the
    // largest axis from above, which tells how well the rays intersect.
    const double det = H.determinant();
    const Eigen::Matrix3d cov = H.inverse();
    const double tr = cov.trace();
    if (!(det > 0.0) || !std::isfinite(tr) || !(tr > 0.0) || tr > opt.max_sigma_mm * opt.max_sigma_mm) {
        out.flags |= kTriDegenerate;
        out.cov_mm2.setZero();
        if (!(det > 0.0) || !std::isfinite(tr)) return out;
    } else {
        out.cov_mm2 = cov;
    }
    if (out.rms_px > opt.max_rms_px) out.flags |= kTriHighResidual;
    return out;
}

}  // namespace eyesim::tracking
