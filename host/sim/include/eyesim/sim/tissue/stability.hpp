#pragma once
/// \file
/// Stability analysis of explicit integration: the largest angular frequency of the linearised system.

#include "eyesim/sim/tissue/mass_spring.hpp"

namespace eyesim::sim::tissue {

/// Bounds on ω_max (rad/s) of the dynamic nodes, linearised at the current positions:
/// ω_max² = λ_max(M⁻¹K) with K = Σ_s k_s [n nᵀ + max(0, 1 − L/ℓ)(I − n nᵀ)] (kinematic nodes held).
struct StabilityEstimate {
    double omega_gershgorin = 0.0;  ///< block-Gershgorin upper bound: ω² ≤ max_i (1/m_i) Σ_{s∋i} 2 k_s
    double omega_power = 0.0;       ///< power-iteration estimate (a lower bound converging to ω_max)
    /// Symplectic (and paper) Euler without damping is stable iff ω_max·dt < 2.
    double dt_critical_s() const { return omega_power > 0 ? 2.0 / omega_power : 0.0; }
};

/// Computes both estimates; `iterations` power-iteration steps (deterministic start vector).
StabilityEstimate estimate_stability(const MassSpringSystem& sys, int iterations = 500);

}  // namespace eyesim::sim::tissue
