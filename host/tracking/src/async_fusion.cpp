#include "eyesim/tracking/async_fusion.hpp"

#include "eyesim/tracking/distortion.hpp"

namespace eyesim::tracking {

namespace detail {

Eigen::Vector2d to_pixel(const CameraGeometry& cam, const Eigen::Vector2d& xn) {
    const Eigen::Vector2d xd = distort_normalized(cam, xn);
    return {cam.fx * xd.x() + cam.cx, cam.fy * xd.y() + cam.cy};
}

Eigen::Quaterniond exp_rotation(const Eigen::Vector3d& theta) {
    const double a = theta.norm();
    if (a < 1e-12) return Eigen::Quaterniond(1.0, 0.5 * theta.x(), 0.5 * theta.y(), 0.5 * theta.z()).normalized();
    return Eigen::Quaterniond(Eigen::AngleAxisd(a, theta / a));
}

}  // namespace detail

double strip_centroid_shift(double rho, double w, double t0) {
    if (!(t0 < rho) || !(w > 0.0)) return 0.0;
    constexpr int kSteps = 16;
    const double dt = (rho - t0) / kSteps;
    double area = 0.0, moment = 0.0;
    for (int k = 0; k < kSteps; ++k) {
        const double t = t0 + (k + 0.5) * dt;
        const double half = std::min(w, std::sqrt(std::max(0.0, rho * rho - t * t)));
        area += 2.0 * half * dt;
        moment += t * 2.0 * half * dt;
    }
    const double disk = 3.141592653589793 * rho * rho;
    return -moment / std::max(disk - area, 1e-3 * disk);
}

Eigen::Vector2d shaft_occlusion_shift(const CameraGeometry& g, const Eigen::Vector3d& X, const Eigen::Vector3d& a,
                                      double marker_radius_mm, double shaft_radius_mm) {
    if (!(marker_radius_mm > 0.0) || !(shaft_radius_mm > 0.0)) return Eigen::Vector2d::Zero();
    const Eigen::Vector3d Xc = g.R_cam_rig * X + g.t_cam_rig_mm;
    const Eigen::Vector3d v = (g.centre_rig_mm() - X).normalized();           // towards the camera
    const Eigen::Vector3d e = a.dot(v) > 0.0 ? a : Eigen::Vector3d(-a);       // the half-shaft in front
    const double sin_t = (e - e.dot(v) * v).norm();
    if (!(sin_t > 1e-3) || !(Xc.z() > 0.0)) return Eigen::Vector2d::Zero();
    const Eigen::Vector3d Xe = g.R_cam_rig * (X + e) + g.t_cam_rig_mm;
    const Eigen::Vector2d u =
        (Eigen::Vector2d(Xe.x() / Xe.z(), Xe.y() / Xe.z()) - Eigen::Vector2d(Xc.x() / Xc.z(), Xc.y() / Xc.z()))
            .normalized();
    if (!u.allFinite()) return Eigen::Vector2d::Zero();
    const double rho = marker_radius_mm / Xc.z();
    return strip_centroid_shift(rho, shaft_radius_mm / Xc.z(), rho * sin_t) * u;
}

void RigidBodyFilter::configure_rigid(const Eigen::Vector3d& roll_axis_body, double ang_psd, double lin_psd) {
    rotation_only_ = false;
    roll_axis_body_ = roll_axis_body.norm() > 0.0 ? Eigen::Vector3d(roll_axis_body.normalized()) : Eigen::Vector3d::Zero();
    q_ang_ = ang_psd;
    q_lin_ = lin_psd;
    tracking_ = false;
}

void RigidBodyFilter::configure_rotation(const Eigen::Vector3d& centre_rig_mm, double ang_psd) {
    rotation_only_ = true;
    roll_axis_body_.setZero();
    t_ = centre_rig_mm;
    q_ang_ = ang_psd;
    q_lin_ = 0.0;
    tracking_ = false;
}

void RigidBodyFilter::set_jerk(double ang_jerk_psd, double lin_jerk_psd, double sigma_alpha0, double sigma_acc0,
                               double correlation_s) {
    qj_ang_ = std::max(0.0, ang_jerk_psd);
    qj_lin_ = rotation_only_ ? 0.0 : std::max(0.0, lin_jerk_psd);
    ca_ = qj_ang_ > 0.0 || qj_lin_ > 0.0;
    s_alpha0_ = ca_ ? std::max(0.0, sigma_alpha0) : 0.0;
    s_acc0_ = ca_ && !rotation_only_ ? std::max(0.0, sigma_acc0) : 0.0;
    tau_s_ = std::max(0.0, correlation_s);
}

void RigidBodyFilter::clear_acceleration() {
    alpha_.setZero();
    acc_.setZero();
    P_.middleRows<6>(12).setZero();
    P_.middleCols<6>(12).setZero();
}

void RigidBodyFilter::init(double t_us, const Eigen::Quaterniond& R, const Eigen::Vector3d& t,
                           const Eigen::Vector3d& omega, const Eigen::Vector3d& v, double s_rot, double s_pos,
                           double s_omega, double s_v) {
    time_us_ = t_us;
    R_ = R.normalized();
    w_ = omega;
    alpha_.setZero();
    acc_.setZero();
    P_.setZero();
    P_.block<3, 3>(12, 12).diagonal().setConstant(s_alpha0_ * s_alpha0_);
    P_.block<3, 3>(15, 15).diagonal().setConstant(s_acc0_ * s_acc0_);
    P_.block<3, 3>(0, 0).diagonal().setConstant(s_rot * s_rot);
    P_.block<3, 3>(6, 6).diagonal().setConstant(s_omega * s_omega);
    if (!rotation_only_) {
        t_ = t;
        v_ = v;
        P_.block<3, 3>(3, 3).diagonal().setConstant(s_pos * s_pos);
        P_.block<3, 3>(9, 9).diagonal().setConstant(s_v * s_v);
    } else {
        v_.setZero();
    }
    tracking_ = true;
    roll_pseudo_measurement();
}

void RigidBodyFilter::set_pivot(bool on, const Eigen::Vector3d& pivot_body_mm, const Eigen::Vector3d& axis_body,
                                double across_fraction) {
    const double n = axis_body.norm();
    pivot_ = on && n > 0.0 && pivot_body_mm.allFinite() && !rotation_only_;
    if (!pivot_) return;
    pivot_body_mm_ = pivot_body_mm;
    pivot_axis_body_ = axis_body / n;
    pivot_across_ = std::max(0.0, across_fraction);
}

void RigidBodyFilter::propagate(double dt, const Eigen::Vector3d& w, const Eigen::Vector3d& v,
                                const Eigen::Vector3d& alpha, const Eigen::Vector3d& acc, Eigen::Quaterniond& R,
                                Eigen::Vector3d& t, Eigen::Vector3d* v_end) const {
    const Eigen::Quaterniond D = detail::exp_rotation(w * dt + (0.5 * dt * dt) * alpha);
    R = (D * R_).normalized();
    if (pivot_) {
        // The origin = pivot + lever: the pivot moves with its own velocity, the lever turns with the body.
        const Eigen::Vector3d lever0 = -(R_ * pivot_body_mm_);
        const Eigen::Vector3d v_pivot = v - w.cross(lever0);
        const Eigen::Vector3d lever1 = D * lever0;
        t = t_ - lever0 + lever1 + v_pivot * dt + (0.5 * dt * dt) * acc;
        if (v_end) *v_end = v_pivot + dt * acc + (w + dt * alpha).cross(lever1);
        return;
    }
    t = t_ + v * dt + (0.5 * dt * dt) * acc;
    if (v_end) *v_end = v + dt * acc;
}

void RigidBodyFilter::pose_at(double t_us, Eigen::Quaterniond& R, Eigen::Vector3d& t) const {
    propagate((t_us - time_us_) * 1e-6, w_, v_, alpha_, acc_, R, t, nullptr);
}

void RigidBodyFilter::display_pose_at(double t_us, Eigen::Quaterniond& R, Eigen::Vector3d& t) const {
    const double dt = (t_us - time_us_) * 1e-6;
    auto shrink = [](const Eigen::Vector3d& v, double var) {
        const double v2 = v.squaredNorm();
        return v2 + var > 0.0 ? Eigen::Vector3d(v * (v2 / (v2 + var))) : Eigen::Vector3d::Zero();
    };
    const Eigen::Vector3d w = shrink(w_, std::max(0.0, P_.block<3, 3>(6, 6).trace()));
    const Eigen::Vector3d v = rotation_only_ ? v_ : shrink(v_, std::max(0.0, P_.block<3, 3>(9, 9).trace()));
    const Eigen::Vector3d al = shrink(alpha_, std::max(0.0, P_.block<3, 3>(12, 12).trace()));
    const Eigen::Vector3d ac = rotation_only_ ? acc_ : shrink(acc_, std::max(0.0, P_.block<3, 3>(15, 15).trace()));
    propagate(dt, w, v, al, ac, R, t, nullptr);
}

void RigidBodyFilter::predict_to(double t_us) {
    const double dt = (t_us - time_us_) * 1e-6;
    if (dt == 0.0) return;
    Eigen::Quaterniond R;
    Eigen::Vector3d t, v;
    propagate(dt, w_, v_, alpha_, acc_, R, t, &v);
    R_ = R;
    t_ = t;
    v_ = v;
    w_ += dt * alpha_;
    time_us_ = t_us;
    // δθ' = δθ + dt·δω (+ ½dt²·δα), δω' = δω + dt·δα, the same for δt, δv, δa; white acceleration noise, and
    // white jerk in a constant-acceleration model (their magnitude whichever way time runs).
    // P ← F·P·Fᵀ: rows then columns, each a block addition (the pose's rows first: they read the rates' old rows).
    const double h = 0.5 * dt * dt;
    if (ca_) {
        P_.middleRows<3>(0) += dt * P_.middleRows<3>(6) + h * P_.middleRows<3>(12);
        if (!rotation_only_) P_.middleRows<3>(3) += dt * P_.middleRows<3>(9) + h * P_.middleRows<3>(15);
        P_.middleRows<3>(6) += dt * P_.middleRows<3>(12);
        if (!rotation_only_) P_.middleRows<3>(9) += dt * P_.middleRows<3>(15);
        P_.middleCols<3>(0) += dt * P_.middleCols<3>(6) + h * P_.middleCols<3>(12);
        if (!rotation_only_) P_.middleCols<3>(3) += dt * P_.middleCols<3>(9) + h * P_.middleCols<3>(15);
        P_.middleCols<3>(6) += dt * P_.middleCols<3>(12);
        if (!rotation_only_) P_.middleCols<3>(9) += dt * P_.middleCols<3>(15);
    } else {  // the accelerations' rows and columns are zero: the leading 12 × 12 block alone
        P_.block<3, 12>(0, 0) += dt * P_.block<3, 12>(6, 0);
        if (!rotation_only_) P_.block<3, 12>(3, 0) += dt * P_.block<3, 12>(9, 0);
        P_.block<12, 3>(0, 0) += dt * P_.block<12, 3>(0, 6);
        if (!rotation_only_) P_.block<12, 3>(0, 3) += dt * P_.block<12, 3>(0, 9);
    }
    const double a = std::abs(dt);
    if (ca_) {
        if (tau_s_ > 0.0) {
            // A Singer model: the acceleration fades with its correlation time, so that a body that goes unseen
            // (or is seen by one camera alone) coasts at its velocity instead of bending away on an old one.
            const double k = std::exp(-a / tau_s_);
            alpha_ *= k;
            acc_ *= k;
            P_.middleRows<6>(12) *= k;
            P_.middleCols<6>(12) *= k;
        }
        // White jerk: per axis over (pose, rate, acceleration) q·[a⁵/20 a⁴/8 a³/6; a⁴/8 a³/3 a²/2; a³/6 a²/2 a].
        const double a2 = a * a, a3 = a2 * a;
        const double j[3][3] = {{a3 * a2 / 20.0, a3 * a / 8.0, a3 / 6.0}, {a3 * a / 8.0, a3 / 3.0, a2 / 2.0},
                                {a3 / 6.0, a2 / 2.0, a}};
        for (int i = 0; i < 3; ++i)
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 3; ++c) {
                    P_(6 * r + i, 6 * c + i) += qj_ang_ * j[r][c];
                    if (!rotation_only_) P_(6 * r + 3 + i, 6 * c + 3 + i) += qj_lin_ * j[r][c];
                }
    }
    const double q11 = a * a * a / 3.0, q12 = a * a / 2.0, q22 = a;
    if (pivot_) {
        // White angular acceleration ε and the pivot's white linear acceleration η: the rates move by (ε, η + ε ×
        // lever). Over (rotation, origin) the density is [q·I, q·[l]×; −q·[l]×, q·(|l|²I − l·lᵀ) + Q_pivot], l the
        // lever pivot → origin; Q_pivot the linear density along the axis and across_fraction of it across.
        const Eigen::Vector3d ax = R_ * pivot_axis_body_;
        const Eigen::Vector3d l = -(R_ * pivot_body_mm_);
        Eigen::Matrix3d lx;
        lx << 0.0, -l.z(), l.y(), l.z(), 0.0, -l.x(), -l.y(), l.x(), 0.0;
        const Eigen::Matrix3d across = Eigen::Matrix3d::Identity() - ax * ax.transpose();
        Eigen::Matrix<double, 6, 6> Qc;
        Qc.topLeftCorner<3, 3>() = q_ang_ * Eigen::Matrix3d::Identity();
        Qc.topRightCorner<3, 3>() = q_ang_ * lx;
        Qc.bottomLeftCorner<3, 3>() = -q_ang_ * lx;
        Qc.bottomRightCorner<3, 3>() = q_ang_ * (l.squaredNorm() * Eigen::Matrix3d::Identity() - l * l.transpose()) +
                                       q_lin_ * pivot_across_ * across + q_lin_ * (ax * ax.transpose());
        // Error-state order: δθ, δt (the pose), δω, δv (the rates).
        P_.block<6, 6>(0, 0) += q11 * Qc;
        P_.block<6, 6>(0, 6) += q12 * Qc;
        P_.block<6, 6>(6, 0) += q12 * Qc;
        P_.block<6, 6>(6, 6) += q22 * Qc;
    } else {
        for (int i = 0; i < 3; ++i) {
            P_(i, i) += q_ang_ * q11;
            P_(i, 6 + i) += q_ang_ * q12;
            P_(6 + i, i) += q_ang_ * q12;
            P_(6 + i, 6 + i) += q_ang_ * q22;
            if (rotation_only_) continue;
            P_(3 + i, 3 + i) += q_lin_ * q11;
            P_(3 + i, 9 + i) += q_lin_ * q12;
            P_(9 + i, 3 + i) += q_lin_ * q12;
            P_(9 + i, 9 + i) += q_lin_ * q22;
        }
    }
    roll_pseudo_measurement();
}

bool RigidBodyFilter::correct(const Eigen::Vector2d& z0, const Jacobian& J,
                              const Eigen::Vector2d& px, double sx, double sy, double nis_gate, double* nis,
                              double age_us) {
    last_log_lik_ = std::numeric_limits<double>::quiet_NaN();
    const double a = std::max(0.0, age_us) * 1e-6;
    const Eigen::Vector2d r = px - z0;
    // The acceleration over the age moves the true pose away from the constant-velocity one: its pose part
    // (a³/3 times the spectral densities) joins the image noise.
    Eigen::Matrix2d Rn = Eigen::Matrix2d::Zero();
    Rn(0, 0) = sx * sx;
    Rn(1, 1) = sy * sy;
    if (a > 0.0) {
        Eigen::Matrix<double, 6, 6> Qp = Eigen::Matrix<double, 6, 6>::Zero();
        Qp.topLeftCorner<3, 3>().diagonal().setConstant(q_ang_ * a * a * a / 3.0);
        if (!rotation_only_) Qp.bottomRightCorner<3, 3>().diagonal().setConstant(q_lin_ * a * a * a / 3.0);
        Rn += J.leftCols<6>() * Qp * J.leftCols<6>().transpose();
    }
    const bool ok = ca_ ? correct_block<kDim>(J, r, Rn, nis_gate, nis) : correct_block<12>(J, r, Rn, nis_gate, nis);
    if (ok) roll_pseudo_measurement();
    return ok;
}

template <int N>
bool RigidBodyFilter::correct_block(const Jacobian& J, const Eigen::Vector2d& r, const Eigen::Matrix2d& Rn,
                                    double nis_gate, double* nis) {
    // N = 12 for a constant-velocity model: its accelerations' rows and columns of P are zero and stay so.
    // Products of these fixed sizes (N × N by N × 2) are below what a blocked GEMM pays off for: lazyProduct keeps
    // them coefficient-wise.
    auto P = P_.topLeftCorner<N, N>();
    const auto Jn = J.leftCols<N>();
    const Eigen::Matrix<double, N, 2> PHt = P.lazyProduct(Jn.transpose());
    const Eigen::Matrix2d S = Jn.lazyProduct(PHt) + Rn;
    const Eigen::Matrix2d Si = S.inverse();
    const double q = r.dot(Si * r);
    if (nis) *nis = q;
    const double det = S.determinant();
    if (std::isfinite(q) && det > 0.0) last_log_lik_ = -0.5 * (std::min(q, nis_gate) + std::log(det));
    if (!(q <= nis_gate) || !std::isfinite(q)) return false;
    // With the optimal gain the Joseph form equals P − K·S·Kᵀ = P − PH·Kᵀ (an N×2 product instead of two N×N
    // ones); symmetrised after.
    const Eigen::Matrix<double, N, 2> K = PHt * Si;
    State dx = State::Zero();
    dx.head<N>() = K * r;
    apply(dx);
    P -= K.lazyProduct(PHt.transpose());
    P = 0.5 * (P + P.transpose()).eval();
    return true;
}

void RigidBodyFilter::apply(const State& dx) {
    R_ = (detail::exp_rotation(dx.segment<3>(0)) * R_).normalized();
    w_ += dx.segment<3>(6);
    alpha_ += dx.segment<3>(12);
    if (!rotation_only_) {
        t_ += dx.segment<3>(3);
        v_ += dx.segment<3>(9);
        acc_ += dx.segment<3>(15);
    }
}

void RigidBodyFilter::roll_pseudo_measurement() {
    // The roll about a line of markers is unobservable: observe "no roll error, no roll rate" with a small σ so
    // that its variance stays bounded (the roll itself stays what initialisation gave).
    if (roll_axis_body_.isZero()) return;
    const Eigen::Vector3d a = R_ * roll_axis_body_;
    constexpr double kSigma = 1e-3;
    // A constant-velocity model's accelerations' rows and columns are zero: its leading 12 × 12 block alone.
    const int n = ca_ ? kDim : 12;
    for (int block : {0, 6, 12}) {
        if (block >= n) break;
        // H = a on `block`: P·H and Hᵀ·P·H from P's three columns there.
        const State PH = P_.middleCols<3>(block) * a;
        const double s = a.dot(PH.segment<3>(block)) + kSigma * kSigma;
        P_.topLeftCorner(n, n).noalias() -= (PH.head(n) / s) * PH.head(n).transpose();
    }
    P_.topLeftCorner(n, n) = 0.5 * (P_.topLeftCorner(n, n) + P_.topLeftCorner(n, n).transpose()).eval();
}

void RigidBodyFilter::update_line_through(const Eigen::Vector3d& b, const Eigen::Vector3d& axis_body,
                                          const Eigen::Vector3d& p, double sigma_mm) {
    if (rotation_only_) return;
    const Eigen::Vector3d a0 = (R_ * axis_body).normalized();
    // Two fixed directions across the current line; residual = offset of p from the line along them.
    const Eigen::Vector3d e1 = a0.unitOrthogonal(), e2 = a0.cross(e1);
    auto h = [&](const Eigen::Matrix<double, 6, 1>& d) {
        const Eigen::Quaterniond R = detail::exp_rotation(d.head<3>()) * R_;
        const Eigen::Vector3d o = R * b + t_ + d.tail<3>();
        const Eigen::Vector3d a = (R * axis_body).normalized();
        const Eigen::Vector3d off = (p - o) - (p - o).dot(a) * a;
        return Eigen::Vector2d(e1.dot(off), e2.dot(off));
    };
    Eigen::Matrix<double, 6, 1> d = Eigen::Matrix<double, 6, 1>::Zero();
    const Eigen::Vector2d z0 = h(d);
    Eigen::Matrix<double, 2, 6> J;
    for (int i = 0; i < 6; ++i) {
        const double eps = i < 3 ? 1e-6 : 1e-4;
        d.setZero();
        d[i] = eps;
        const Eigen::Vector2d zp = h(d);
        d[i] = -eps;
        J.col(i) = (zp - h(d)) / (2.0 * eps);
    }
    const Eigen::Vector2d r = -z0;  // the line should pass through p: offset 0
    const Eigen::Matrix2d Rn = Eigen::Matrix2d::Identity() * (sigma_mm * sigma_mm);
    const Eigen::Matrix2d S = J * P_.topLeftCorner<6, 6>() * J.transpose() + Rn;
    const Eigen::Matrix<double, kDim, 2> PHt = P_.leftCols<6>() * J.transpose();
    const Eigen::Matrix<double, kDim, 2> K = PHt * S.inverse();
    apply(K * r);
    // = the Joseph form with the optimal gain (see correct); a constant-velocity model's accelerations' rows and
    // columns are zero (so are K's and PHt's there): its leading 12 × 12 block alone.
    if (ca_) {
        P_.noalias() -= K * PHt.transpose();
        P_ = 0.5 * (P_ + P_.transpose()).eval();
    } else {
        auto P = P_.topLeftCorner<12, 12>();
        P.noalias() -= K.topRows<12>() * PHt.topRows<12>().transpose();
        P = 0.5 * (P + P.transpose()).eval();
    }
    roll_pseudo_measurement();
}

bool RigidBodyFilter::predict_pixel(const CameraGeometry& cam, const Eigen::Vector3d& b, Eigen::Vector2d& px,
                                    double age_us) const {
    Eigen::Quaterniond R = R_;
    Eigen::Vector3d t = t_;
    if (age_us > 0.0) pose_at(time_us_ - age_us, R, t);
    const Eigen::Vector3d Xc = cam.R_cam_rig * (R * b + t) + cam.t_cam_rig_mm;
    if (!(Xc.z() > 1e-6)) return false;
    px = detail::to_pixel(cam, Eigen::Vector2d(Xc.x() / Xc.z(), Xc.y() / Xc.z()));
    return px.allFinite();
}

void BodyFilter::configure_rigid(const Eigen::Vector3d& roll_axis_body, const double* ang_psd,
                                 const double* lin_psd, int models, double switch_per_s) {
    n_ = std::clamp(models, 1, kMaxModels);
    switch_per_s_ = std::max(0.0, switch_per_s);
    for (int j = 0; j < n_; ++j) m_[std::size_t(j)].configure_rigid(roll_axis_body, ang_psd[j], lin_psd[j]);
    dirty_ = true;
}

void BodyFilter::configure_rotation(const Eigen::Vector3d& centre_rig_mm, const double* ang_psd, int models,
                                    double switch_per_s) {
    n_ = std::clamp(models, 1, kMaxModels);
    switch_per_s_ = std::max(0.0, switch_per_s);
    for (int j = 0; j < n_; ++j) m_[std::size_t(j)].configure_rotation(centre_rig_mm, ang_psd[j]);
    dirty_ = true;
}

void BodyFilter::set_jerk(int model, double ang_jerk_psd, double lin_jerk_psd, double sigma_alpha0,
                          double sigma_acc0, double correlation_s) {
    if (model < 0 || model >= n_) return;
    m_[std::size_t(model)].set_jerk(ang_jerk_psd, lin_jerk_psd, sigma_alpha0, sigma_acc0, correlation_s);
    dirty_ = true;
}

void BodyFilter::init(double t_us, const Eigen::Quaterniond& R, const Eigen::Vector3d& t, const Eigen::Vector3d& w,
                      const Eigen::Vector3d& v, double s_rot, double s_pos, double s_w, double s_v) {
    // A body is acquired while it moves as often as at rest: no model preferred.
    for (int j = 0; j < n_; ++j) {
        m_[std::size_t(j)].init(t_us, R, t, w, v, s_rot, s_pos, s_w, s_v);
        mu_[std::size_t(j)] = 1.0 / n_;
    }
    dirty_ = true;
}

RigidBodyFilter::State BodyFilter::difference(const RigidBodyFilter& i, const RigidBodyFilter& j) {
    RigidBodyFilter::State d;
    const Eigen::AngleAxisd dr(i.R_ * j.R_.conjugate());  // the rotation vector, angle in [0, π]
    d.segment<3>(0) = dr.angle() * dr.axis();
    d.segment<3>(3) = i.t_ - j.t_;
    d.segment<3>(6) = i.w_ - j.w_;
    d.segment<3>(9) = i.v_ - j.v_;
    d.segment<3>(12) = i.alpha_ - j.alpha_;
    d.segment<3>(15) = i.acc_ - j.acc_;
    return d;
}

void BodyFilter::predict_to(double t_us) {
    const double dt_s = std::abs(t_us - m_[0].time_us()) * 1e-6;
    if (n_ > 1 && dt_s > 0.0 && switch_per_s_ > 0.0) {
        // Mixing (IMM): model j starts the step from Σ_i μ_i|j x_i, μ_i|j = Π_ij μ_i / c_j, where a switch to each
        // other model over the step has the chance p = (1 − exp(−rate·dt)) / (n − 1); its covariance takes the
        // spread of the means.
        const double p = (1.0 - std::exp(-switch_per_s_ * dt_s)) / (n_ - 1);
        auto Pi = [&](int i, int j) { return i == j ? 1.0 - (n_ - 1) * p : p; };
        std::array<RigidBodyFilter, kMaxModels> mixed;
        std::array<double, kMaxModels> c{};
        double sum_c = 0.0;
        for (int j = 0; j < n_; ++j) {
            for (int i = 0; i < n_; ++i) c[std::size_t(j)] += Pi(i, j) * mu_[std::size_t(i)];
            sum_c += c[std::size_t(j)];
            std::array<double, kMaxModels> w{};
            for (int i = 0; i < n_; ++i)
                w[std::size_t(i)] = c[std::size_t(j)] > 0.0 ? Pi(i, j) * mu_[std::size_t(i)] / c[std::size_t(j)]
                                                            : double(i == j);
            merge(w, j, mixed[std::size_t(j)]);
        }
        for (int j = 0; j < n_; ++j) {
            m_[std::size_t(j)] = mixed[std::size_t(j)];
            // A constant-velocity model takes the mixture's pose and rates, not the acceleration it cannot carry.
            if (!m_[std::size_t(j)].constant_acceleration()) m_[std::size_t(j)].clear_acceleration();
        }
        if (sum_c > 0.0)
            for (int j = 0; j < n_; ++j) mu_[std::size_t(j)] = c[std::size_t(j)] / sum_c;
    }
    for (int j = 0; j < n_; ++j) m_[std::size_t(j)].predict_to(t_us);
    dirty_ = true;
}

void BodyFilter::update_line_through(const Eigen::Vector3d& b, const Eigen::Vector3d& axis_body,
                                     const Eigen::Vector3d& p, double sigma_mm) {
    for (int j = 0; j < n_; ++j) m_[std::size_t(j)].update_line_through(b, axis_body, p, sigma_mm);
    dirty_ = true;
}

void BodyFilter::merge(const std::array<double, kMaxModels>& w, int ref, RigidBodyFilter& out) const {
    std::array<RigidBodyFilter::State, kMaxModels> d;
    RigidBodyFilter::State mean = RigidBodyFilter::State::Zero();
    double total = 0.0;
    for (int i = 0; i < n_; ++i) {
        d[std::size_t(i)] = difference(m_[std::size_t(i)], m_[std::size_t(ref)]);
        mean += w[std::size_t(i)] * d[std::size_t(i)];
        total += w[std::size_t(i)];
    }
    mean /= total;
    // Without an acceleration model the accelerations' rows and columns are zero: the leading 12 × 12 block
    // (fixed-size blocks: the mixing runs for every model at every prediction).
    bool any_ca = false;
    for (int i = 0; i < n_; ++i) any_ca = any_ca || m_[std::size_t(i)].constant_acceleration();
    out = m_[std::size_t(ref)];
    out.apply(mean);
    auto spread = [&]<int N>() {
        Eigen::Matrix<double, N, N> P = Eigen::Matrix<double, N, N>::Zero();
        for (int i = 0; i < n_; ++i) {
            const Eigen::Matrix<double, N, 1> e = (d[std::size_t(i)] - mean).template head<N>();
            P += (w[std::size_t(i)] / total) *
                 (m_[std::size_t(i)].P_.template topLeftCorner<N, N>() + e * e.transpose());
        }
        out.P_.setZero();
        out.P_.template topLeftCorner<N, N>() = 0.5 * (P + P.transpose());
    };
    if (any_ca)
        spread.template operator()<RigidBodyFilter::kDim>();
    else
        spread.template operator()<12>();
}

void BodyFilter::smoothed_pose_at(const BodyFilter& then, double t_us, Eigen::Quaterniond& R,
                                  Eigen::Vector3d& t) const {
    using Cov = RigidBodyFilter::Cov;
    using State = RigidBodyFilter::State;
    const RigidBodyFilter& later = mix();
    const RigidBodyFilter& f = then.mix();
    const double t_next = later.time_us();
    if (!then.tracking() || !(t_next > f.time_us())) return later.pose_at(t_us, R, t);
    BodyFilter pred = then;
    pred.predict_to(t_next);
    const RigidBodyFilter& p = pred.mix();
    const State d = difference(later, p);
    // The error state's transition over the step (RigidBodyFilter::predict_to's F; a Singer model's accelerations
    // fade by k).
    const double dt = (t_next - f.time_us()) * 1e-6, h = 0.5 * dt * dt;
    double k = 1.0;
    for (int j = 0; j < then.n_; ++j) {
        const RigidBodyFilter& m = then.m_[std::size_t(j)];
        if (m.ca_ && m.tau_s_ > 0.0) k = std::exp(-dt / m.tau_s_);
    }
    Cov F = Cov::Identity();
    for (int i = 0; i < 3; ++i) {
        F(i, 6 + i) = dt;
        F(i, 12 + i) = h;
        F(6 + i, 12 + i) = dt;
        F(12 + i, 12 + i) = k;
        if (f.rotation_only_) continue;
        F(3 + i, 9 + i) = dt;
        F(3 + i, 15 + i) = h;
        F(9 + i, 15 + i) = dt;
        F(15 + i, 15 + i) = k;
    }
    // Over the components the prediction holds uncertain (a constant-velocity model's accelerations, the eye's
    // translation: none).
    std::array<int, RigidBodyFilter::kDim> idx{};
    int n = 0;
    const double scale = p.P_.diagonal().cwiseAbs().maxCoeff();
    for (int i = 0; i < RigidBodyFilter::kDim; ++i)
        if (p.P_(i, i) > 1e-12 * scale) idx[std::size_t(n++)] = i;
    using Sub = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, RigidBodyFilter::kDim, RigidBodyFilter::kDim>;
    using SubV = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, RigidBodyFilter::kDim, 1>;
    Sub Ps(n, n);
    SubV ds(n);
    for (int a = 0; a < n; ++a) {
        ds(a) = d(idx[std::size_t(a)]);
        for (int b = 0; b < n; ++b) Ps(a, b) = p.P_(idx[std::size_t(a)], idx[std::size_t(b)]);
    }
    // The roll about a line of markers is held by a pseudo-measurement inside each prediction (a tiny predicted
    // variance that the cross-covariance does not share): left out of the difference, as uninformative.
    if (!p.roll_axis_body_.isZero()) {
        const Eigen::Vector3d a = p.R_ * p.roll_axis_body_;
        const double big = 1e6 * scale;
        for (int blk : {0, 6, 12})
            for (int ia = 0; ia < n; ++ia)
                for (int ib = 0; ib < n; ++ib) {
                    const int ra = idx[std::size_t(ia)] - blk, rb = idx[std::size_t(ib)] - blk;
                    if (ra >= 0 && ra < 3 && rb >= 0 && rb < 3) Ps(ia, ib) += big * a(ra) * a(rb);
                }
    }
    const SubV x = Ps.ldlt().solve(ds);
    const Cov C = f.P_ * F.transpose();
    State dx = State::Zero();
    for (int a = 0; a < n; ++a) dx += C.col(idx[std::size_t(a)]) * x(a);
    if (!dx.allFinite()) return later.pose_at(t_us, R, t);
    RigidBodyFilter s = f;
    s.apply(dx);
    s.pose_at(t_us, R, t);
}

void BodyFilter::combine() const {
    dirty_ = false;
    if (n_ == 1) return;
    // The mixture, about the likeliest model's state.
    int r = 0;
    for (int j = 1; j < n_; ++j)
        if (mu_[std::size_t(j)] > mu_[std::size_t(r)]) r = j;
    merge(mu_, r, c_);
}

int motion_model_ladder(int models, double steady, double agile, double* out) {
    const int nm = std::clamp(models, 1, 3);
    if (nm == 1) out[0] = agile;
    else if (nm == 2) out[0] = steady, out[1] = agile;
    else out[0] = steady, out[1] = std::sqrt(steady * agile), out[2] = agile;
    return nm;
}

void configure_eye_filter(BodyFilter& f, const AsyncOptions& ao, const Eigen::Vector3d& centre_rig_mm) {
    // The acceleration model after the constant-velocity ones, its white acceleration the steady model's (the jerk
    // carries the rest).
    double psd[BodyFilter::kMaxModels] = {};
    const int nm = motion_model_ladder(ao.motion_models, ao.eye_steady_ang_accel_psd_rad2_s3,
                                       ao.eye_ang_accel_psd_rad2_s3, psd);
    const bool ca = ao.eye_acceleration_model;
    if (ca) psd[nm] = ao.eye_steady_ang_accel_psd_rad2_s3;
    f.configure_rotation(centre_rig_mm, psd, ca ? nm + 1 : nm, ao.model_switch_per_s);
    if (ca) f.set_jerk(nm, ao.eye_ang_jerk_psd_rad2_s5, 0.0, ao.ang_accel0_sigma_rad_s2, 0.0, ao.accel_correlation_s);
    // The steady model follows the eye's smooth turns with an acceleration of its own (one model: the agile).
    if (nm > 1 && ao.eye_steady_ang_jerk_psd_rad2_s5 > 0.0)
        f.set_jerk(0, ao.eye_steady_ang_jerk_psd_rad2_s5, 0.0, ao.ang_accel0_sigma_rad_s2, 0.0,
                   ao.eye_steady_accel_correlation_s);
}

}  // namespace eyesim::tracking
