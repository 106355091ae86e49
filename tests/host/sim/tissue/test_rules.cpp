// The paper's rules: tearing threshold, acceleration and velocity clamps, fixed nodes.
#include "tissue_test_util.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <random>

using namespace tissue_test;

TEST_CASE("tearing happens exactly when |a| exceeds a_max by p_tear percent, not before", "[tissue][rules]") {
    // One free node of mass m on a spring stretched by s: |a| = k·s/m. Threshold a_max·(1 + p/100).
    const float m = 2.0f, k = 50.0f, rest = 1.0f;
    TissueParams p;
    p.a_max_mm_per_s2 = 100.0f;
    p.p_tear_percent = 50.0f;
    const double thr = 150.0;                       // mm/s²
    const double s_at = thr * m / k;                // stretch at the threshold: 6 mm
    for (double rel : {0.999, 1.001}) {
        const float x0 = float(rest + s_at * rel);
        Tissue t(single_spring(m, k, 0.0f, rest, x0), p, IntegratorKind::kPaperEuler);
        t.step(1e-4f, 1);
        INFO("stretch / threshold stretch = " << rel);
        if (rel < 1) {
            CHECK(t.system().spring_count() == 1);
            CHECK(t.events().count(TissueEventKind::kSpringTorn) == 0);
            CHECK(t.damage().springs_torn == 0);
        } else {
            CHECK(t.system().spring_count() == 0);
            REQUIRE(t.events().count(TissueEventKind::kSpringTorn) == 1);
            CHECK(t.events()[0].node == 1);
            CHECK(t.events()[0].other == 0);
            CHECK(t.events()[0].value == Approx(k * s_at * rel / m).epsilon(1e-5));
            CHECK(t.damage().springs_torn == 1);
        }
    }
}

TEST_CASE("tearing deletes the spring pulling hardest on the overloaded node", "[tissue][rules]") {
    // Node 1 between anchors 0 (left) and 2 (right); the right spring is stretched more.
    const std::vector<Vec3f> x{Vec3f(0, 0, 0), Vec3f(0.5f, 0, 0), Vec3f(3, 0, 0)};
    const std::vector<float> m{1, 1, 1};
    const std::vector<Spring> s{{0, 1, 0.1f, 10, 0}, {1, 2, 0.1f, 10, 0}};
    MassSpringSystem sys = MassSpringSystem::from_springs(x, m, s);
    sys.set_state(0, NodeState::kFixed);
    sys.set_state(2, NodeState::kFixed);
    TissueParams p;
    p.a_max_mm_per_s2 = 1.0f;  // |a| = 10·(2.4 − 0.4) = 20 > 1.1
    p.p_tear_percent = 10.0f;
    Tissue t(std::move(sys), p, IntegratorKind::kPaperEuler);
    t.step(1e-3f, 1);
    REQUIRE(t.system().spring_count() == 1);
    CHECK(t.system().springs[0].a == 0);
    CHECK(t.system().springs[0].b == 1);
    // The node is now pulled left only, with the clamped acceleration a_max.
    CHECK(t.system().v_mm_per_s[1].x() == Approx(-1.0 * 1e-3).epsilon(1e-5));
}

TEST_CASE("paper Euler clamps acceleration to a_max and kept speed to v_max", "[tissue][rules]") {
    TissueParams p;
    p.a_max_mm_per_s2 = 10.0f;
    p.v_max_mm_per_s = 0.05f;
    Tissue t(single_spring(1.0f, 100.0f, 0.0f, 1.0f, 2.0f), p, IntegratorKind::kPaperEuler);  // |a| = 100
    t.step(1e-3f, 1);
    CHECK(t.system().v_mm_per_s[1].x() == Approx(-0.01).epsilon(1e-5));  // a_max·dt
    CHECK(t.system().x_mm[1].x() == Approx(2.0 - 1e-5).epsilon(1e-6));
    for (int i = 0; i < 20; ++i) t.step(1e-3f, 1);
    CHECK(t.system().v_mm_per_s[1].norm() <= 0.05f * (1 + 1e-6f));
}

TEST_CASE("v_max = 0 leaves no kinetic energy after any step, yet the tissue moves", "[tissue][rules]") {
    for (IntegratorKind kind : kAllIntegrators) {
        INFO(to_string(kind));
        TissueParams p;
        p.v_max_mm_per_s = 0.0f;
        p.gravity_mm_per_s2 = Vec3f(0, 0, -1000.0f);
        Tissue t(patch400(), MaterialParams{}, p, kind);
        t.fix_rim();
        const Vec3f start = t.system().x_mm[112];  // an interior node near the centre
        for (int i = 0; i < 200; ++i) {
            t.step(5e-4f, 1);
            REQUIRE(t.system().kinetic_energy() == 0.0);
        }
        CHECK(t.system().x_mm[112].z() < start.z() - 1e-4f);
    }
}

TEST_CASE("paper Euler without limits is bitwise symplectic Euler", "[tissue][rules]") {
    TissueParams p;
    p.gravity_mm_per_s2 = Vec3f(0, 0, -500.0f);
    Tissue a(patch400(), MaterialParams{}, p, IntegratorKind::kPaperEuler);
    Tissue b(patch400(), MaterialParams{}, p, IntegratorKind::kSymplecticEuler);
    a.fix_rim();
    b.fix_rim();
    for (int i = 0; i < 300; ++i) a.step(2e-4f, 1), b.step(2e-4f, 1);
    const std::vector<Vec3f> xa = a.system().x_mm, xb = b.system().x_mm;
    CHECK(std::memcmp(xa.data(), xb.data(), xa.size() * sizeof(Vec3f)) == 0);
}

TEST_CASE("fixed and attached nodes never move under any load or tool", "[tissue][rules]") {
    for (IntegratorKind kind : kAllIntegrators) {
        INFO(to_string(kind));
        TissueParams p;
        p.gravity_mm_per_s2 = Vec3f(0, 0, -2000.0f);
        p.a_max_mm_per_s2 = 1e5f;
        p.v_max_mm_per_s = 200.0f;
        p.p_tear_percent = 100.0f;
        Tissue t(patch400(), MaterialParams{}, p, kind);
        REQUIRE(t.fix_rim() == size_t(4 * 14));
        const std::vector<Vec3f> x0 = t.system().x_mm;
        std::mt19937 rng(7);
        std::uniform_int_distribution<uint32_t> node(0, uint32_t(x0.size() - 1));
        std::normal_distribution<float> g(0.0f, 0.3f);
        for (int frame = 0; frame < 100; ++frame) {
            std::vector<NodePush> pushes;
            for (int k = 0; k < 20; ++k) pushes.push_back({node(rng), Vec3f(g(rng), g(rng), g(rng))});
            t.push(pushes);  // pushes on rim nodes must be ignored
            SuctionInput s;
            s.on = frame % 3 == 0;
            s.apex_mm = Vec3f(0, 0, 0.5f);
            s.axis = Vec3f(0, 0, -1);
            s.strength_nN_mm = 5.0f;
            t.set_suction(s);
            t.step(2e-3f, 4);
        }
        for (uint32_t v = 0; v < x0.size(); ++v)
            if (t.system().state[v] == NodeState::kFixed) REQUIRE(t.system().x_mm[v] == x0[v]);
        const char* why = "";
        CHECK(t.system().check_consistency(&why));
        INFO(why);
    }
}
