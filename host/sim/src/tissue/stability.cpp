#include "eyesim/sim/tissue/stability.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>

namespace eyesim::sim::tissue {

StabilityEstimate estimate_stability(const MassSpringSystem& s, int iterations) {
    StabilityEstimate est;
    const size_t n = s.node_count();
    // Block Gershgorin on M⁻¹K: each spring block has 2-norm k·max(1, geo) = k, and a node's row holds its
    // diagonal block (Σ K_s) plus one off-diagonal block per spring to a dynamic neighbour.
    std::vector<double> row(n, 0.0);
    for (const Spring& sp : s.springs) {
        row[sp.a] += 2.0 * sp.stiffness_nN_per_mm;
        row[sp.b] += 2.0 * sp.stiffness_nN_per_mm;
    }
    double g = 0.0;
    for (size_t i = 0; i < n; ++i)
        if (s.w_per_mg[i] > 0.0f) g = std::max(g, double(s.w_per_mg[i]) * row[i]);
    est.omega_gershgorin = std::sqrt(g);

    // Power iteration on S = M^{-1/2} K M^{-1/2} (symmetric, same spectrum as M⁻¹K), kinematic nodes held.
    std::vector<Eigen::Matrix3d> Ks(s.springs.size());
    for (size_t k = 0; k < s.springs.size(); ++k) {
        const Spring& sp = s.springs[k];
        const Eigen::Vector3d d = (s.x_mm[sp.b] - s.x_mm[sp.a]).cast<double>();
        const double len = d.norm();
        if (!(len > 1e-12)) { Ks[k].setZero(); continue; }
        const Eigen::Vector3d nrm = d / len;
        const Eigen::Matrix3d nnT = nrm * nrm.transpose();
        const double geo = std::max(0.0, 1.0 - double(sp.rest_mm) / len);
        Ks[k] = double(sp.stiffness_nN_per_mm) * (nnT + geo * (Eigen::Matrix3d::Identity() - nnT));
    }
    std::vector<double> sw(n);
    for (size_t i = 0; i < n; ++i) sw[i] = std::sqrt(double(s.w_per_mg[i]));
    Eigen::VectorXd u(3 * n), y(3 * n);
    uint64_t seed = 0x9E3779B97F4A7C15ull;  // deterministic pseudo-random start
    for (Eigen::Index i = 0; i < u.size(); ++i) {
        seed ^= seed << 13, seed ^= seed >> 7, seed ^= seed << 17;
        u[i] = double(seed % 2001) / 1000.0 - 1.0;
    }
    for (size_t i = 0; i < n; ++i) if (sw[i] == 0.0) u.segment<3>(3 * i).setZero();
    double lambda = 0.0;
    for (int it = 0; it < iterations; ++it) {
        const double un = u.norm();
        if (!(un > 0.0)) break;
        u /= un;
        y.setZero();
        for (size_t k = 0; k < s.springs.size(); ++k) {
            const Spring& sp = s.springs[k];
            const Eigen::Vector3d ua = sw[sp.a] * u.segment<3>(3 * sp.a), ub = sw[sp.b] * u.segment<3>(3 * sp.b);
            const Eigen::Vector3d t = Ks[k] * (ua - ub);
            y.segment<3>(3 * sp.a) += sw[sp.a] * t;
            y.segment<3>(3 * sp.b) -= sw[sp.b] * t;
        }
        lambda = u.dot(y);  // Rayleigh quotient
        u = y;
    }
    est.omega_power = std::sqrt(std::max(lambda, 0.0));
    return est;
}

}  // namespace eyesim::sim::tissue
