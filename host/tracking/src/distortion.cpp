#include "eyesim/tracking/distortion.hpp"

#include <Eigen/LU>

#include <cmath>

namespace eyesim::tracking {

bool CameraGeometry::valid() const {
    if (!(std::isfinite(fx) && std::isfinite(fy) && std::isfinite(cx) && std::isfinite(cy))) return false;
    if (!(fx > 0.0 && fy > 0.0)) return false;
    for (double d : dist)
        if (!std::isfinite(d)) return false;
    if (!R_cam_rig.allFinite() || !t_cam_rig_mm.allFinite()) return false;
    const double orth = (R_cam_rig * R_cam_rig.transpose() - Eigen::Matrix3d::Identity()).norm();
    return orth < 1e-6 && std::abs(R_cam_rig.determinant() - 1.0) < 1e-6;
}

Eigen::Vector2d distort_normalized(const CameraGeometry& cam, const Eigen::Vector2d& xn, Eigen::Matrix2d* J) {
    const auto& d = cam.dist;
    const double x = xn.x(), y = xn.y();
    const double r2 = x * x + y * y, r4 = r2 * r2, r6 = r4 * r2;
    const double num = 1.0 + d[0] * r2 + d[1] * r4 + d[4] * r6;
    const double den = 1.0 + d[5] * r2 + d[6] * r4 + d[7] * r6;
    const double radial = num / den;
    const double xd = x * radial + 2.0 * d[2] * x * y + d[3] * (r2 + 2.0 * x * x);
    const double yd = y * radial + d[2] * (r2 + 2.0 * y * y) + 2.0 * d[3] * x * y;
    if (J) {
        // d(radial)/d(r2) by the quotient rule, then chain through r2 = x² + y².
        const double dnum = d[0] + 2.0 * d[1] * r2 + 3.0 * d[4] * r4;
        const double dden = d[5] + 2.0 * d[6] * r2 + 3.0 * d[7] * r4;
        const double drad = (dnum * den - num * dden) / (den * den);
        const double drx = drad * 2.0 * x, dry = drad * 2.0 * y;
        (*J)(0, 0) = radial + x * drx + 2.0 * d[2] * y + 6.0 * d[3] * x;
        (*J)(0, 1) = x * dry + 2.0 * d[2] * x + 2.0 * d[3] * y;
        (*J)(1, 0) = y * drx + 2.0 * d[2] * x + 2.0 * d[3] * y;
        (*J)(1, 1) = radial + y * dry + 6.0 * d[2] * y + 2.0 * d[3] * x;
    }
    return {xd, yd};
}

Undistorted undistort_pixel(const CameraGeometry& cam, const Eigen::Vector2d& px, const UndistortOptions& opt) {
    Undistorted out;
    if (!px.allFinite()) return out;
    const Eigen::Vector2d target((px.x() - cam.cx) / cam.fx, (px.y() - cam.cy) / cam.fy);
    // Tolerance in the normalised plane per axis (pixel tolerance divided by focal length).
    const Eigen::Vector2d scale(cam.fx, cam.fy);
    Eigen::Vector2d x = target;  // the undistorted point is close to the distorted one: a good start
    Eigen::Matrix2d J;
    Eigen::Vector2d f = distort_normalized(cam, x, &J) - target;
    double err_px = f.cwiseProduct(scale).norm();
    int it = 0;
    while (err_px > opt.tolerance_px && it < opt.max_iterations) {
        ++it;
        const double det = J.determinant();
        if (!std::isfinite(det) || std::abs(det) < 1e-12) break;  // fold of the distortion: no unique inverse
        Eigen::Vector2d step = J.inverse() * f;
        // Damping: halve the step until the residual decreases (guards against overshoot at strong distortion).
        double lambda = 1.0;
        bool improved = false;
        for (int k = 0; k < 30; ++k) {
            const Eigen::Vector2d xt = x - lambda * step;
            Eigen::Matrix2d Jt;
            const Eigen::Vector2d ft = distort_normalized(cam, xt, &Jt) - target;
            const double et = ft.cwiseProduct(scale).norm();
            if (std::isfinite(et) && et < err_px) {
                x = xt; f = ft; J = Jt; err_px = et; improved = true;
                break;
            }
            lambda *= 0.5;
        }
        if (!improved) break;
    }
    out.xn = x;
    out.iterations = it;
    out.residual_px = err_px;
    out.converged = std::isfinite(err_px) && err_px <= opt.tolerance_px;
    return out;
}

bool project_point(const CameraGeometry& cam, const Eigen::Vector3d& X_rig_mm, Eigen::Vector2d& px,
                   Eigen::Matrix<double, 2, 3>* J) {
    const Eigen::Vector3d Xc = cam.R_cam_rig * X_rig_mm + cam.t_cam_rig_mm;
    if (!Xc.allFinite() || !(Xc.z() > 1e-9)) return false;
    const double iz = 1.0 / Xc.z();
    const Eigen::Vector2d xn(Xc.x() * iz, Xc.y() * iz);
    Eigen::Matrix2d Jd;
    const Eigen::Vector2d xd = distort_normalized(cam, xn, J ? &Jd : nullptr);
    px = Eigen::Vector2d(cam.fx * xd.x() + cam.cx, cam.fy * xd.y() + cam.cy);
    if (J) {
        Eigen::Matrix<double, 2, 3> Jn;  // ∂xn/∂Xc
        Jn << iz, 0.0, -Xc.x() * iz * iz, 0.0, iz, -Xc.y() * iz * iz;
        Eigen::Matrix2d Kf = Eigen::Vector2d(cam.fx, cam.fy).asDiagonal();
        *J = Kf * Jd * Jn * cam.R_cam_rig;
    }
    return true;
}

}  // namespace eyesim::tracking
