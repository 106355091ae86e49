// Hanging chain: the static shape against the exact discrete solution.
#include "tissue_test_util.hpp"

#include <catch2/catch.hpp>

#include <cmath>

using namespace tissue_test;

namespace {

// Node 0 fixed at the origin, nodes 1..N below it, gravity −z. Spring j (joining j−1 and j) carries the weight of
// nodes j..N, so its length is L + (N − j + 1)·m·g / k, and z_i = −Σ_{j≤i} length_j.
constexpr int kN = 12;
constexpr float kMass = 0.5f, kK = 20000.0f, kRest = 0.25f, kG = 9810.0f;

MassSpringSystem chain(float c) {
    std::vector<Vec3f> x;
    std::vector<float> m(kN + 1, kMass);
    std::vector<Spring> s;
    for (int i = 0; i <= kN; ++i) x.emplace_back(0.0f, 0.0f, -kRest * float(i));
    for (int i = 1; i <= kN; ++i) s.push_back({uint32_t(i - 1), uint32_t(i), kRest, kK, c});
    MassSpringSystem sys = MassSpringSystem::from_springs(x, m, s);
    sys.set_state(0, NodeState::kFixed);
    return sys;
}

double analytic_z(int i) {
    double z = 0;
    for (int j = 1; j <= i; ++j) z -= kRest + double(kN - j + 1) * kMass * kG / kK;
    return z;
}

}  // namespace

TEST_CASE("hanging chain settles to the exact discrete static shape", "[tissue][analytic]") {
    TissueParams p;
    p.gravity_mm_per_s2 = Vec3f(0, 0, -kG);
    struct Case { IntegratorKind kind; float dt; int steps; float drag; float v_max; };
    // Paper Euler with v_max = 0 is a quasi-static (gradient-descent-like) relaxation; the others are damped by
    // fluid drag. ω_max ≈ 2√(k/m) = 400 rad/s, so every dt below is within the explicit limit.
    const Case cases[] = {{IntegratorKind::kPaperEuler, 0.002f, 20000, 0.0f, 0.0f},
                          {IntegratorKind::kSymplecticEuler, 0.002f, 20000, 5.0f, kUnlimited},
                          {IntegratorKind::kImplicitEuler, 0.05f, 2000, 5.0f, kUnlimited}};
    for (const Case& cs : cases) {
        INFO(to_string(cs.kind));
        p.drag_per_s = cs.drag;
        p.v_max_mm_per_s = cs.v_max;
        Tissue t(chain(1.0f), p, cs.kind);
        for (int i = 0; i < cs.steps; ++i) t.step(cs.dt, 1);
        const double total_ext = analytic_z(kN) + kRest * kN;  // total extension (negative)
        for (int i = 0; i <= kN; ++i) {
            INFO("node " << i);
            CHECK(std::abs(t.system().x_mm[i].z() - analytic_z(i)) < 1e-4 * std::abs(total_ext) + 1e-4);
            CHECK(std::abs(t.system().x_mm[i].x()) < 1e-6);
        }
    }
}

TEST_CASE("XPBD hanging chain approaches the static shape as iterations grow", "[tissue][analytic]") {
    // XPBD with a finite number of sweeps is known to under-converge stiff chains; more sweeps, less error.
    TissueParams p;
    p.gravity_mm_per_s2 = Vec3f(0, 0, -kG);
    p.drag_per_s = 5.0f;
    double prev_err = 1e30;
    for (int iters : {2, 8, 32}) {
        p.xpbd_iterations = iters;
        Tissue t(chain(1.0f), p, IntegratorKind::kXpbd);
        for (int i = 0; i < 3000; ++i) t.step(0.01f, 1);
        double err = 0;
        for (int i = 0; i <= kN; ++i) err = std::max(err, std::abs(t.system().x_mm[i].z() - analytic_z(i)));
        INFO("iterations " << iters << " max error " << err);
        CHECK(err < prev_err);
        prev_err = err;
    }
    CHECK(prev_err < 0.01 * std::abs(analytic_z(kN)));
}
