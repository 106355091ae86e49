// Extended position-based dynamics (Macklin, Müller, Chentanez 2016) with one distance constraint per spring.
#include "eyesim/sim/tissue/integrator.hpp"
#include "node_limits.hpp"

#include <cmath>

namespace eyesim::sim::tissue {

namespace {

/// Predict with external forces, then Gauss–Seidel sweeps over springs with compliance α = 1/k and the XPBD
/// damping term γ = c/(k·h), then v = (x − x_prev)/h. Spring order is the (deterministic) array order.
class Xpbd final : public Integrator {
public:
    IntegratorKind kind() const override { return IntegratorKind::kXpbd; }

    void advance(MassSpringSystem& s, const TissueParams& p, float h) override {
        const size_t n = s.node_count();
        x_prev_.resize(n);
        lambda_.assign(s.spring_count(), 0.0f);
        PaddedVec3Array& x = s.x_mm;
        PaddedVec3Array& v = s.v_mm_per_s;
        const float* w = s.w_per_mg.data();
        // 1. Prediction from external loads only (spring forces become constraints).
        for (size_t i = 0; i < n; ++i) {
            if (w[i] == 0.0f) {
                x_prev_[i] = x[i] - h * v[i];  // kinematic nodes were already moved to their end-of-step place
                continue;
            }
            x_prev_[i] = x[i];
            const Vec3f a = w[i] * s.ext_nN[i] + p.gravity_mm_per_s2 - p.drag_per_s * v[i];
            v[i] += h * a;
            x[i] += h * v[i];
        }
        // 2. Constraint projection.
        const float inv_h2 = 1.0f / (h * h);
        for (int it = 0; it < p.xpbd_iterations; ++it) {
            for (size_t k = 0; k < s.springs.size(); ++k) {
                const Spring& sp = s.springs[k];
                const float wa = w[sp.a], wb = w[sp.b];
                if (wa + wb == 0.0f || !(sp.stiffness_nN_per_mm > 0.0f)) continue;
                const Vec3f d = x[sp.b] - x[sp.a];
                const float len2 = d.squaredNorm();
                if (!(len2 > 1e-24f)) continue;
                const float len = std::sqrt(len2);
                const Vec3f nrm = d / len;
                const float alpha = inv_h2 / sp.stiffness_nN_per_mm;
                const float gamma = sp.damping_nN_s_per_mm / (sp.stiffness_nN_per_mm * h);
                const float rel = nrm.dot((x[sp.b] - x_prev_[sp.b]) - (x[sp.a] - x_prev_[sp.a]));
                const float dl = (-(len - sp.rest_mm) - alpha * lambda_[k] - gamma * rel) /
                                 ((1.0f + gamma) * (wa + wb) + alpha);
                lambda_[k] += dl;
                x[sp.a] -= (wa * dl) * nrm;
                x[sp.b] += (wb * dl) * nrm;
            }
        }
        // 3. Velocities from positions.
        const float inv_h = 1.0f / h;
        const detail::EndOfStep end(p);
        for (size_t i = 0; i < n; ++i) {
            if (w[i] == 0.0f) continue;
            Vec3f xi = x[i];
            Vec3f vi = (xi - x_prev_[i]) * inv_h;
            end.apply(xi, vi);
            x[i] = xi;
            v[i] = vi;
        }
    }

private:
    std::vector<Vec3f> x_prev_;
    std::vector<float> lambda_;
};

}  // namespace

std::unique_ptr<Integrator> make_xpbd() { return std::make_unique<Xpbd>(); }

}  // namespace eyesim::sim::tissue
