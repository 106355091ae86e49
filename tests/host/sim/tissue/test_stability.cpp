// Stability: the explicit limit dt < 2/ω_max predicted and found by experiment; bounded energy and no NaN under
// abuse (short versions in the unit run, full versions tagged [stress]).
#include "tissue_test_util.hpp"

#include "eyesim/sim/tissue/stability.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <cstdio>
#include <random>
#include <string>

using namespace tissue_test;

namespace {

MaterialParams undamped(float k) {
    MaterialParams m;
    m.edge_stiffness_nN_per_mm = k;
    m.edge_damping_nN_s_per_mm = 0.0f;
    return m;
}

// Runs undamped symplectic Euler from a small random perturbation; returns max energy / initial energy.
double energy_growth(float dt, int steps, float k) {
    Tissue t(patch400(), undamped(k), TissueParams{}, IntegratorKind::kSymplecticEuler);
    t.fix_rim();
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(-1e-5f, 1e-5f);  // small: linear regime (see docs)
    for (uint32_t v = 0; v < t.system().node_count(); ++v)
        if (is_dynamic(t.system().state[v])) t.system_mut().x_mm[v] += Vec3f(u(rng), u(rng), 0.0f);
    const double e0 = t.system().elastic_energy();
    double emax = e0;
    for (int i = 0; i < steps; ++i) {
        t.step(dt, 1);
        const double e = t.system().elastic_energy() + t.system().kinetic_energy();
        if (!std::isfinite(e) || e > 1e12 * e0) return 1e12;
        emax = std::max(emax, e);
    }
    return emax / e0;
}

// The bound every abused run must respect: positions inside the container sphere of radius R, so every spring is
// at most 2R long and |ℓ − L| ≤ 2R: E_el ≤ Σ ½ k (2R)²; kept speeds ≤ v_max: E_kin ≤ ½ Σ m v_max².
struct Bound {
    double elastic, kinetic;
};
Bound energy_bound(const MassSpringSystem& s, const TissueParams& p) {
    Bound b{0, 0};
    const double two_r = 2.0 * p.container_radius_mm;
    for (const Spring& sp : s.springs) b.elastic += 0.5 * sp.stiffness_nN_per_mm * two_r * two_r;
    for (size_t i = 0; i < s.node_count(); ++i)
        if (s.inv_mass_per_mg[i] > 0) b.kinetic += 0.5 * p.v_max_mm_per_s * p.v_max_mm_per_s / s.inv_mass_per_mg[i];
    return b;
}

// Abuse: random large pushes, grabs yanked across the eye, suction and (every `cut_every` frames, 0 = never) cuts,
// for `frames` frames. The tearing limit a_max scales with stiffness (1e4·k mm/s² by default, a_max = 0) so that
// stiff tissue is abused as hard as soft tissue rather than torn apart in the first frames.
// Returns the fraction of springs still alive.
double abuse(IntegratorKind kind, float k, float dt, int frames, int substeps, uint32_t seed, int cut_every = 97,
             float a_max = 0.0f) {
    TissueParams p;
    p.container_radius_mm = 12.0f;
    p.v_max_mm_per_s = 2000.0f;
    p.a_max_mm_per_s2 = a_max > 0.0f ? a_max : 1e4f * k;
    p.p_tear_percent = 50.0f;
    p.gravity_mm_per_s2 = Vec3f(0, 0, -1000.0f);
    p.drag_per_s = 1.0f;
    MaterialParams mat = undamped(k);
    mat.edge_damping_nN_s_per_mm = 1e-4f * k;
    mat.bending_stiffness_nN_per_mm = 0.1f * k;
    Tissue t(patch400(), mat, p, kind);
    t.fix_rim();
    const Bound bound = energy_bound(t.system(), p);
    const double springs0 = double(t.system().spring_count());
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    std::uniform_int_distribution<uint32_t> node(0, uint32_t(t.system().node_count() - 1));
    for (int f = 0; f < frames; ++f) {
        if (f % 7 == 0) {
            std::vector<NodePush> pushes;
            for (int i = 0; i < 30; ++i) pushes.push_back({node(rng), 3.0f * Vec3f(u(rng), u(rng), u(rng))});
            t.push(pushes);
        }
        ForcepsInput fc;
        fc.closed = (f / 50) % 2 == 1;
        fc.tip_mm = 6.0f * Vec3f(u(rng), u(rng), u(rng));
        fc.grab_radius_mm = 0.5f;
        t.set_forceps(fc);
        SuctionInput su;
        su.on = f % 13 < 4;
        su.apex_mm = 2.0f * Vec3f(u(rng), u(rng), u(rng));
        su.strength_nN_mm = k;  // scales with stiffness like the tearing limit
        t.set_suction(su);
        CutterInput cu;
        cu.on = cut_every > 0 && f % cut_every == 0;
        cu.centre_mm = 2.0f * Vec3f(u(rng), u(rng), 0.0f);
        cu.radius_mm = 0.3f;
        t.set_cutter(cu);
        t.step(dt * float(substeps), substeps);
        const MassSpringSystem& s = t.system();
        const char* why = "";
        if (!s.check_consistency(&why)) FAIL(why << " at frame " << f);
        const double ee = s.elastic_energy(), ek = s.kinetic_energy();
        if (!(ee <= bound.elastic && ek <= bound.kinetic * (1 + 1e-5)))
            FAIL("energy bound broken at frame " << f << ": elastic " << ee << " / " << bound.elastic
                                                  << ", kinetic " << ek << " / " << bound.kinetic);
    }
    return double(t.system().spring_count()) / springs0;
}

}  // namespace

TEST_CASE("stability estimates: Gershgorin bounds the power iteration from above", "[tissue][stability]") {
    for (float k : {10.0f, 1e4f}) {
        Tissue t(patch400(), undamped(k), TissueParams{}, IntegratorKind::kSymplecticEuler);
        t.fix_rim();
        const StabilityEstimate a = estimate_stability(t.system(), 300), b = estimate_stability(t.system(), 3000);
        CHECK(a.omega_gershgorin >= b.omega_power);
        CHECK(b.omega_power >= a.omega_power * (1 - 1e-9));  // Rayleigh quotients increase toward λ_max
        CHECK(b.omega_power > 0.5 * a.omega_gershgorin);
        CHECK(std::abs(b.omega_power / a.omega_power - 1) < 0.01);
        // ω scales with √k.
        if (k > 100) {
            Tissue soft(patch400(), undamped(10.0f), TissueParams{}, IntegratorKind::kSymplecticEuler);
            soft.fix_rim();
            CHECK(b.omega_power == Approx(std::sqrt(1e3) * estimate_stability(soft.system(), 3000).omega_power));
        }
    }
}

TEST_CASE("explicit Euler is stable just below 2/ω_max and unstable just above", "[tissue][stability]") {
    const float k = 1000.0f;
    Tissue t(patch400(), undamped(k), TissueParams{}, IntegratorKind::kSymplecticEuler);
    t.fix_rim();
    const double dt_crit = estimate_stability(t.system(), 5000).dt_critical_s();
    INFO("predicted dt_crit = " << dt_crit << " s");
    CHECK(energy_growth(float(0.97 * dt_crit), 20000, k) < 100.0);
    CHECK(energy_growth(float(1.03 * dt_crit), 20000, k) > 1e6);
}

TEST_CASE("short abuse run: no NaN, energy within the bound, mesh consistent", "[tissue][stability]") {
    for (IntegratorKind kind : kAllIntegrators) {
        INFO(to_string(kind));
        const double alive = abuse(kind, 1000.0f, 1e-3f, 2500, 4, 11);  // 10⁴ substeps
        // Without cutting and with a high tearing limit the tissue must survive the impulses mostly intact.
        const double intact = abuse(kind, 1000.0f, 1e-3f, 2500, 4, 12, 0, 1e12f);
        std::printf("short abuse %s: %.0f %% of springs left (heavy), %.0f %% (no cutting)\n",
                    std::string(to_string(kind)).c_str(), 100 * alive, 100 * intact);
        CHECK(intact > 0.5);
    }
}

TEST_CASE("stress: stiffness over 10⁶×, dt up to 10 ms, random large tool impulses", "[tissue][stress]") {
    for (IntegratorKind kind : kAllIntegrators)
        for (float k : {10.0f, 1e3f, 1e5f, 1e7f})
            for (float dt : {1e-4f, 1e-3f, 1e-2f}) {
                INFO(to_string(kind) << " k = " << k << " dt = " << dt);
                const double alive = abuse(kind, k, dt, 2500, 4, uint32_t(k) ^ uint32_t(dt * 1e5f));
                std::printf("%s k=%g dt=%g: %.0f %% of springs left\n", std::string(to_string(kind)).c_str(), k, dt,
                            100 * alive);
            }
}

TEST_CASE("stress: 10⁶-step runs stay finite and bounded", "[tissue][stress]") {
    // Paper and symplectic Euler: 10⁶ substeps; implicit Euler and XPBD (≈10–20× the cost): 10⁵. No cutting and a
    // high tearing limit, so that most of the tissue survives and every step does full work (checked at the end).
    struct Run { IntegratorKind kind; int frames; };
    const Run runs[] = {{IntegratorKind::kPaperEuler, 250000}, {IntegratorKind::kSymplecticEuler, 250000},
                        {IntegratorKind::kImplicitEuler, 25000}, {IntegratorKind::kXpbd, 25000}};
    for (const Run& r : runs) {
        INFO(to_string(r.kind));
        const double alive = abuse(r.kind, 1e3f, 1e-3f, r.frames, 4, 1 + uint32_t(r.kind), 0, 1e12f);
        std::printf("%d substeps %s: %.0f %% of springs left\n", 4 * r.frames, std::string(to_string(r.kind)).c_str(),
                    100 * alive);
        CHECK(alive > 0.5);
    }
}

TEST_CASE("stress: the explicit stability limit found by bisection matches 2/ω_max", "[tissue][stress]") {
    for (float k : {10.0f, 1e3f, 1e5f, 1e7f}) {
        Tissue t(patch400(), undamped(k), TissueParams{}, IntegratorKind::kSymplecticEuler);
        t.fix_rim();
        const double predicted = estimate_stability(t.system(), 5000).dt_critical_s();
        double lo = 0.5 * predicted, hi = 1.5 * predicted;  // lo stable, hi unstable
        REQUIRE(energy_growth(float(lo), 20000, k) < 100.0);
        REQUIRE(energy_growth(float(hi), 20000, k) > 1e6);
        for (int i = 0; i < 8; ++i) {
            const double mid = 0.5 * (lo + hi);
            (energy_growth(float(mid), 20000, k) < 1e3 ? lo : hi) = mid;
        }
        const double found = 0.5 * (lo + hi);
        std::printf("k = %g nN/mm: predicted dt_crit %.4g s, found %.4g s (ratio %.4f)\n", k, predicted, found,
                    found / predicted);
        CHECK(std::abs(found / predicted - 1) < 0.02);
    }
}
