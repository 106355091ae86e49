// Hanging chain: the static shape against the exact discrete solution.
#include "tissue_test_util.hpp"

#include <Eigen/Core>
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <vector>

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

TEST_CASE("chain hung between two supports matches the elastic discrete catenary", "[tissue][analytic]") {
    // N segments between fixed ends (0,0,0) and (span,0,0), interior nodes of mass m, gravity −z.
    // Independent solution by shooting: with horizontal tension H and, by symmetry, vertical support force
    // V0 = (N−1)·m·g/2, segment j (from node j to j+1) carries tension along (H, j·m·g − V0) (z up),
    // has length L + |T_j|/k along T_j/|T_j|; H is found by bisection so that the chain ends at x = span.
    constexpr int N = 16;
    const double m = 0.5, k = 2000.0, L = 0.25, g = 9810.0, span = 0.8 * N * L;
    const double V0 = (N - 1) * m * g / 2;
    auto shoot = [&](double H, std::vector<Eigen::Vector2d>* pts) {
        Eigen::Vector2d p(0, 0);
        if (pts) pts->assign(1, p);
        for (int j = 0; j < N; ++j) {
            const Eigen::Vector2d T(H, j * m * g - V0);  // left half descends, right half climbs
            p += (L + T.norm() / k) * T.normalized();
            if (pts) pts->push_back(p);
        }
        return p.x();
    };
    double lo = 1e-6, hi = 1e6;  // end x grows with H
    for (int i = 0; i < 200; ++i) {
        const double mid = std::sqrt(lo * hi);
        (shoot(mid, nullptr) < span ? lo : hi) = mid;
    }
    std::vector<Eigen::Vector2d> truth;
    shoot(std::sqrt(lo * hi), &truth);
    REQUIRE(std::abs(truth.back().x() - span) < 1e-9);
    REQUIRE(std::abs(truth.back().y()) < 1e-6);  // symmetric: the right end lands at the same height

    // Simulation: start on a sagging parabola, relax with implicit Euler and fluid drag.
    std::vector<Vec3f> x;
    std::vector<float> mass(N + 1, float(m));
    std::vector<Spring> springs;
    for (int i = 0; i <= N; ++i) {
        const double s = double(i) / N;
        x.emplace_back(float(span * s), 0.0f, float(-span * s * (1 - s)));
    }
    for (int i = 1; i <= N; ++i) springs.push_back({uint32_t(i - 1), uint32_t(i), float(L), float(k), 1.0f});
    MassSpringSystem sys = MassSpringSystem::from_springs(x, mass, springs);
    sys.set_state(0, NodeState::kFixed);
    sys.set_state(N, NodeState::kFixed);
    TissueParams p;
    p.gravity_mm_per_s2 = Vec3f(0, 0, float(-g));
    p.drag_per_s = 10.0f;
    Tissue t(std::move(sys), p, IntegratorKind::kImplicitEuler);
    for (int i = 0; i < 3000; ++i) t.step(0.01f, 1);
    double sag = 0;
    for (const auto& q : truth) sag = std::max(sag, -q.y());
    for (int i = 0; i <= N; ++i) {
        INFO("node " << i << " sim (" << t.system().x_mm[i].x() << ", " << t.system().x_mm[i].z() << ") truth ("
                     << truth[i].x() << ", " << truth[i].y() << ")");
        CHECK(std::abs(t.system().x_mm[i].x() - truth[i].x()) < 1e-4 * sag);
        CHECK(std::abs(t.system().x_mm[i].z() - truth[i].y()) < 1e-4 * sag);
    }
}
