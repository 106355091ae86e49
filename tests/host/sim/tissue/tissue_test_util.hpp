#pragma once
// Small scene builders shared by the tissue tests.

#include "eyesim/sim/tissue/tissue.hpp"

#include <vector>

namespace tissue_test {

using namespace eyesim::sim;
using namespace eyesim::sim::tissue;

/// A fixed anchor at the origin and one free node at (x0, 0, 0) joined by one spring.
inline MassSpringSystem single_spring(float mass_mg, float k, float c, float rest_mm, float x0_mm) {
    const std::vector<Vec3f> x{Vec3f::Zero(), Vec3f(x0_mm, 0, 0)};
    const std::vector<float> m{mass_mg, mass_mg};
    const std::vector<Spring> s{{0, 1, rest_mm, k, c}};
    MassSpringSystem sys = MassSpringSystem::from_springs(x, m, s);
    sys.set_state(0, NodeState::kFixed);
    return sys;
}

/// Membrane patch (400-triangle Table-3 size, 4 × 4 mm) with default material.
inline TriangleMesh patch400() { return make_membrane_patch(4.0f, 4.0f, kPatch400.nx, kPatch400.ny); }

inline constexpr IntegratorKind kAllIntegrators[] = {IntegratorKind::kPaperEuler, IntegratorKind::kSymplecticEuler,
                                                    IntegratorKind::kImplicitEuler, IntegratorKind::kXpbd};

}  // namespace tissue_test
