#pragma once
/// \file
/// Time integrators behind one interface, chosen per scene.

#include "eyesim/sim/tissue/mass_spring.hpp"
#include "eyesim/sim/tissue/tissue_params.hpp"

#include <memory>
#include <string_view>

namespace eyesim::sim::tissue {

/// The available integrators.
enum class IntegratorKind : uint8_t {
    kPaperEuler = 0,       ///< paper §4.5: explicit Euler with a_max and v_max clamps
    kSymplecticEuler = 1,  ///< the same update without the a_max clamp (v ← v + a·dt, x ← x + v·dt)
    kImplicitEuler = 2,    ///< Baraff–Witkin: one Newton step of backward Euler, Eigen conjugate gradient
    kXpbd = 3,             ///< extended position-based dynamics, one constraint per spring (compliance 1/k)
};

/// Short name ("paper-euler", "symplectic-euler", "implicit-euler", "xpbd").
std::string_view to_string(IntegratorKind kind);
/// Parses a short name; false if unknown.
bool parse_integrator(std::string_view name, IntegratorKind& out);

/// One integrator. Implementations keep their work buffers between steps (no allocation per step once warm,
/// except inside Eigen's CG solve) and rebuild them when `MassSpringSystem::topology_version` changes.
class Integrator {
public:
    virtual ~Integrator() = default;
    /// Which integrator this is.
    virtual IntegratorKind kind() const = 0;
    /// Advances dynamic nodes by dt_s. On entry `sys.f_nN` holds the forces at the current state (compute_forces
    /// ran and the tearing rule was applied). Every integrator finally clamps the kept speed to v_max and keeps
    /// nodes inside the container sphere; kinematic nodes are not touched.
    virtual void advance(MassSpringSystem& sys, const TissueParams& params, float dt_s) = 0;
};

/// Creates an integrator.
std::unique_ptr<Integrator> make_integrator(IntegratorKind kind);

}  // namespace eyesim::sim::tissue
