#include "eyesim/tracking/rigid_fit.hpp"

#include <Eigen/SVD>

#include <cmath>
#include <numbers>

namespace eyesim::tracking {

namespace {

/// Rotation R maximising Σ wᵢ mᵢᵀ R bᵢ from the cross-covariance C = Σ wᵢ mᵢ bᵢᵀ, with the reflection fix.
/// Returns false when C has rank < 2 (rotation undetermined).
bool rotation_from_covariance(const Eigen::Matrix3d& C, double scale, Eigen::Matrix3d& R) {
    if (!C.allFinite()) return false;
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(C, Eigen::ComputeFullU | Eigen::ComputeFullV);
    const Eigen::Vector3d s = svd.singularValues();
    // Rank test relative to the data scale: the second singular value must be well above round-off.
    if (!(s(1) > 1e-9 * std::max(scale, 1e-300))) return false;
    Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
    if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0) D(2, 2) = -1.0;
    R = svd.matrixU() * D * svd.matrixV().transpose();
    return R.allFinite();
}

double weight_at(std::span<const double> w, std::size_t i) { return w.empty() ? 1.0 : w[i]; }

}  // namespace

RigidFit fit_rigid(std::span<const Eigen::Vector3d> body_mm, std::span<const Eigen::Vector3d> measured_mm,
                   std::span<const double> weights) {
    RigidFit out;
    const std::size_t n = body_mm.size();
    if (n < 3 || measured_mm.size() != n || (!weights.empty() && weights.size() != n)) return out;
    double wsum = 0.0;
    Eigen::Vector3d cb = Eigen::Vector3d::Zero(), cm = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < n; ++i) {
        const double w = weight_at(weights, i);
        if (!(w >= 0.0) || !body_mm[i].allFinite() || !measured_mm[i].allFinite()) return out;
        wsum += w;
        cb += w * body_mm[i];
        cm += w * measured_mm[i];
    }
    if (!(wsum > 0.0)) return out;
    cb /= wsum;
    cm /= wsum;
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    double scale = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
        const double w = weight_at(weights, i);
        const Eigen::Vector3d b = body_mm[i] - cb;
        C.noalias() += w * (measured_mm[i] - cm) * b.transpose();
        scale += w * b.squaredNorm();
    }
    Eigen::Matrix3d R;
    if (!rotation_from_covariance(C, scale, R)) return out;
    out.R = R;
    out.t_mm = cm - R * cb;
    double ss = 0.0;
    for (std::size_t i = 0; i < n; ++i) ss += (R * body_mm[i] + out.t_mm - measured_mm[i]).squaredNorm();
    out.rms_mm = std::sqrt(ss / double(n));
    out.ok = true;
    return out;
}

RigidFit fit_rotation_about(const Eigen::Vector3d& centre_rig_mm, std::span<const Eigen::Vector3d> body_mm,
                            std::span<const Eigen::Vector3d> measured_mm, std::span<const double> weights) {
    RigidFit out;
    const std::size_t n = body_mm.size();
    if (n < 2 || measured_mm.size() != n || (!weights.empty() && weights.size() != n) ||
        !centre_rig_mm.allFinite())
        return out;
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    double scale = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
        const double w = weight_at(weights, i);
        if (!(w >= 0.0) || !body_mm[i].allFinite() || !measured_mm[i].allFinite()) return out;
        C.noalias() += w * (measured_mm[i] - centre_rig_mm) * body_mm[i].transpose();
        scale += w * body_mm[i].squaredNorm();
    }
    Eigen::Matrix3d R;
    if (!rotation_from_covariance(C, scale, R)) return out;
    out.R = R;
    out.t_mm = centre_rig_mm;
    double ss = 0.0;
    for (std::size_t i = 0; i < n; ++i) ss += (R * body_mm[i] + centre_rig_mm - measured_mm[i]).squaredNorm();
    out.rms_mm = std::sqrt(ss / double(n));
    out.ok = true;
    return out;
}

double rotation_angle_deg(const Eigen::Matrix3d& Ra, const Eigen::Matrix3d& Rb) {
    const Eigen::AngleAxisd aa(Eigen::Quaterniond(Ra * Rb.transpose()).normalized());
    double a = std::abs(aa.angle());
    if (a > std::numbers::pi) a = 2.0 * std::numbers::pi - a;
    return a * 180.0 / std::numbers::pi;
}

}  // namespace eyesim::tracking
