// The paper's explicit Euler with clamps, and plain symplectic Euler.
#include "eyesim/sim/tissue/integrator.hpp"
#include "node_limits.hpp"

#include <cmath>

namespace eyesim::sim::tissue {

namespace {

using Lane4 = Eigen::Map<Eigen::Vector4f, Eigen::Aligned16>;
using ConstLane4 = Eigen::Map<const Eigen::Vector4f, Eigen::Aligned16>;

/// The explicit node update shared by both integrators: v += dt·a, x += dt·v (velocity first), then the
/// end-of-step rules. `clamp_acceleration`: the paper's a_max (scales a to at most a_max); without it the update
/// is plain symplectic Euler, bitwise.
void explicit_step(MassSpringSystem& s, const TissueParams& p, float dt, bool clamp_acceleration) {
    const size_t n = s.node_count();
    const float a_max = p.a_max_mm_per_s2;
    const float a_max2 = a_max * a_max;
    const detail::EndOfStep end(p);
    Float4* __restrict x = s.x_mm.lanes();
    Float4* __restrict v = s.v_mm_per_s.lanes();
    const Float4* __restrict f = s.f_nN.lanes();
    const float* __restrict w = s.w_per_mg.data();
    for (size_t i = 0; i < n; ++i) {
        if (w[i] == 0.0f) continue;  // kinematic or removed
        // Four lanes (the fourth is 0 and stays 0), register copies stored once.
        Eigen::Vector4f a = w[i] * ConstLane4(f[i].v);
        if (clamp_acceleration) {
            const float a2 = a.squaredNorm();
            if (a2 > a_max2) a *= a_max / std::sqrt(a2);
        }
        Eigen::Vector4f vi = ConstLane4(v[i].v) + dt * a;
        Eigen::Vector4f xi = ConstLane4(x[i].v) + dt * vi;
        end.apply(xi, vi);
        Lane4(v[i].v) = vi;
        Lane4(x[i].v) = xi;
    }
}

/// Paper §4.5. Velocity is updated first and the new velocity moves the node (the velocity-first form of
/// explicit Euler): with v_max = 0 a node still moves by a·dt² in a step, and keeps no kinetic energy after it,
/// as the paper describes. Acceleration is clamped to a_max, the kept velocity to v_max.
class PaperEuler final : public Integrator {
public:
    IntegratorKind kind() const override { return IntegratorKind::kPaperEuler; }
    void advance(MassSpringSystem& s, const TissueParams& p, float dt) override { explicit_step(s, p, dt, true); }
};

/// Symplectic (semi-implicit) Euler without clamps on acceleration; v_max and the container still apply.
class SymplecticEuler final : public Integrator {
public:
    IntegratorKind kind() const override { return IntegratorKind::kSymplecticEuler; }
    void advance(MassSpringSystem& s, const TissueParams& p, float dt) override { explicit_step(s, p, dt, false); }
};

}  // namespace

std::unique_ptr<Integrator> make_implicit_euler();
std::unique_ptr<Integrator> make_xpbd();

std::unique_ptr<Integrator> make_integrator(IntegratorKind kind) {
    switch (kind) {
        case IntegratorKind::kPaperEuler: return std::make_unique<PaperEuler>();
        case IntegratorKind::kSymplecticEuler: return std::make_unique<SymplecticEuler>();
        case IntegratorKind::kImplicitEuler: return make_implicit_euler();
        case IntegratorKind::kXpbd: return make_xpbd();
    }
    return std::make_unique<PaperEuler>();
}

std::string_view to_string(IntegratorKind kind) {
    switch (kind) {
        case IntegratorKind::kPaperEuler: return "paper-euler";
        case IntegratorKind::kSymplecticEuler: return "symplectic-euler";
        case IntegratorKind::kImplicitEuler: return "implicit-euler";
        case IntegratorKind::kXpbd: return "xpbd";
    }
    return "?";
}

bool parse_integrator(std::string_view name, IntegratorKind& out) {
    for (IntegratorKind k : {IntegratorKind::kPaperEuler, IntegratorKind::kSymplecticEuler,
                             IntegratorKind::kImplicitEuler, IntegratorKind::kXpbd})
        if (to_string(k) == name) {
            out = k;
            return true;
        }
    return false;
}

}  // namespace eyesim::sim::tissue
