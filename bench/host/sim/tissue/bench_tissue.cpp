// Tissue benchmark: step time on the paper's Table 3 meshes per integrator, and run time against error versus a
// double-precision RK4 reference with a tiny step. Prints markdown tables (docs/bench/tissue.md).
//
// Usage: bench_sim_tissue [--repeats N] [--quick]
#include "eyesim/sim/tissue/stability.hpp"
#include "eyesim/sim/tissue/tissue.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

using namespace eyesim::sim;
using namespace eyesim::sim::tissue;

namespace {

using Clock = std::chrono::steady_clock;

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.empty() ? 0.0 : v[v.size() / 2];
}

constexpr IntegratorKind kKinds[] = {IntegratorKind::kPaperEuler, IntegratorKind::kSymplecticEuler,
                                     IntegratorKind::kImplicitEuler, IntegratorKind::kXpbd};

// The membrane scene used throughout: 4 × 4 mm patch, rim fixed, 5 % pre-tension, a uniform pressure load.
MaterialParams scene_material() {
    MaterialParams m;
    m.edge_stiffness_nN_per_mm = 1000.0f;
    m.edge_damping_nN_s_per_mm = 0.02f;
    m.rest_length_scale = 0.95f;
    return m;
}
constexpr float kLoad_nN_per_mm2 = 2.0f;  // pressure on the membrane, −z

Tissue make_scene(PatchSize size, IntegratorKind kind, const TissueParams& p) {
    const TriangleMesh mesh = make_membrane_patch(4.0f, 4.0f, size.nx, size.ny);
    Tissue t(mesh, scene_material(), p, kind);
    t.fix_rim();
    // Pressure load: each node carries a third of its triangles' area.
    MassSpringSystem& s = t.system_mut();
    for (const auto& tri : mesh.triangles) {
        const float area = 0.5f * (mesh.vertices_mm[tri[1]] - mesh.vertices_mm[tri[0]])
                                      .cross(mesh.vertices_mm[tri[2]] - mesh.vertices_mm[tri[0]])
                                      .norm();
        for (uint32_t v : tri) s.ext_nN[v].z() -= kLoad_nN_per_mm2 * area / 3.0f;
    }
    return t;
}

// ---- Part 1: step time ----
struct StepTiming {
    double us_per_step;
    size_t springs;
};

StepTiming time_steps(PatchSize size, IntegratorKind kind, float dt, int repeats, int steps) {
    TissueParams p;
    p.a_max_mm_per_s2 = 1e6f;  // the paper's rules active (tearing check runs every step, never fires here)
    p.p_tear_percent = 50.0f;
    p.v_max_mm_per_s = 1e3f;
    Tissue t = make_scene(size, kind, p);
    // The extra load lives in ext_nN, so the Tissue's own injection copy must match: keep suction off.
    for (int i = 0; i < 200; ++i) t.step(dt, 1);  // warm-up (caches, solver buffers)
    std::vector<double> per;
    for (int r = 0; r < repeats; ++r) {
        const auto t0 = Clock::now();
        for (int i = 0; i < steps; ++i) t.step(dt, 1);
        per.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count() / steps);
    }
    return {median(per), t.system().spring_count()};
}

// ---- Part 2: RK4 reference in double precision (independent force code) ----
struct Rk4Reference {
    std::vector<Eigen::Vector3d> x, v, ext;
    std::vector<double> w;
    std::vector<Spring> springs;

    explicit Rk4Reference(const MassSpringSystem& s) {
        for (size_t i = 0; i < s.node_count(); ++i) {
            x.push_back(s.x_mm[i].cast<double>());
            v.push_back(s.v_mm_per_s[i].cast<double>());
            ext.push_back(s.ext_nN[i].cast<double>());
            w.push_back(s.w_per_mg[i]);
        }
        springs = s.springs;
    }
    void accel(const std::vector<Eigen::Vector3d>& xs, const std::vector<Eigen::Vector3d>& vs,
               std::vector<Eigen::Vector3d>& a) const {
        for (size_t i = 0; i < xs.size(); ++i) a[i] = ext[i];
        for (const Spring& sp : springs) {
            const Eigen::Vector3d d = xs[sp.b] - xs[sp.a];
            const double len = d.norm();
            const Eigen::Vector3d n = d / len;
            const Eigen::Vector3d f = (double(sp.stiffness_nN_per_mm) * (len - double(sp.rest_mm)) +
                                       double(sp.damping_nN_s_per_mm) * n.dot(vs[sp.b] - vs[sp.a])) * n;
            a[sp.a] += f;
            a[sp.b] -= f;
        }
        for (size_t i = 0; i < xs.size(); ++i) a[i] *= w[i];
    }
    void run(double dt, int steps) {
        const size_t n = x.size();
        std::vector<Eigen::Vector3d> k1v(n), k1x(n), k2v(n), k2x(n), k3v(n), k3x(n), k4v(n), k4x(n), xt(n), vt(n);
        for (int s = 0; s < steps; ++s) {
            accel(x, v, k1v);
            k1x = v;
            for (size_t i = 0; i < n; ++i) xt[i] = x[i] + 0.5 * dt * k1x[i], vt[i] = v[i] + 0.5 * dt * k1v[i];
            accel(xt, vt, k2v);
            k2x = vt;
            for (size_t i = 0; i < n; ++i) xt[i] = x[i] + 0.5 * dt * k2x[i], vt[i] = v[i] + 0.5 * dt * k2v[i];
            accel(xt, vt, k3v);
            k3x = vt;
            for (size_t i = 0; i < n; ++i) xt[i] = x[i] + dt * k3x[i], vt[i] = v[i] + dt * k3v[i];
            accel(xt, vt, k4v);
            k4x = vt;
            for (size_t i = 0; i < n; ++i) {
                x[i] += dt / 6.0 * (k1x[i] + 2.0 * k2x[i] + 2.0 * k3x[i] + k4x[i]);
                v[i] += dt / 6.0 * (k1v[i] + 2.0 * k2v[i] + 2.0 * k3v[i] + k4v[i]);
            }
        }
    }
};

double rms_error(const MassSpringSystem& s, const std::vector<Eigen::Vector3d>& ref) {
    double e = 0;
    size_t n = 0;
    for (size_t i = 0; i < ref.size(); ++i)
        if (is_dynamic(s.state[i])) e += (s.x_mm[i].cast<double>() - ref[i]).squaredNorm(), ++n;
    return std::sqrt(e / double(n));
}

struct ErrorPoint {
    IntegratorKind kind;
    double dt_s, wall_ms, err_um;
    bool finite;
};

}  // namespace

int main(int argc, char** argv) {
    int repeats = 7;
    bool quick = false;
    for (int i = 1; i < argc; ++i) {
        if (!std::strcmp(argv[i], "--repeats") && i + 1 < argc) repeats = std::max(1, std::atoi(argv[++i]));
        else if (!std::strcmp(argv[i], "--quick")) quick = true;
        else {
            std::fprintf(stderr, "usage: bench_sim_tissue [--repeats N] [--quick]\n");
            return 2;
        }
    }
    if (quick) repeats = std::min(repeats, 3);

    // ---- Part 1 ----
    struct Row { const char* name; PatchSize size; double paper_ms; };
    const Row rows[] = {{"400 triangles", kPatch400, 0.5}, {"1k triangles", kPatch1k, 1.5},
                        {"3k triangles", kPatch3k, 4.0}};
    std::printf("## Step time (median of %d repeats; machine shared and busy)\n\n", repeats);
    std::printf("| mesh | springs | paper Table 3 | paper-euler µs | symplectic µs | implicit µs | xpbd µs | "
                "paper-euler vs Table 3 | implicit / paper-euler | xpbd / paper-euler |\n");
    std::printf("|---|---|---|---|---|---|---|---|---|---|\n");
    for (const Row& r : rows) {
        double us[4];
        size_t springs = 0;
        for (int k = 0; k < 4; ++k) {
            const int steps = kKinds[k] == IntegratorKind::kImplicitEuler ? (quick ? 50 : 200) : (quick ? 500 : 2000);
            const StepTiming st = time_steps(r.size, kKinds[k], 1e-4f, repeats, steps);
            us[k] = st.us_per_step;
            springs = st.springs;
        }
        std::printf("| %s | %zu | %.1f ms | %.1f | %.1f | %.0f | %.0f | %.0f× faster | %.1f× | %.1f× |\n", r.name,
                    springs, r.paper_ms, us[0], us[1], us[2], us[3], r.paper_ms * 1000.0 / us[0], us[2] / us[0],
                    us[3] / us[0]);
        std::fflush(stdout);
    }

    // ---- Part 2 ----
    const PatchSize size = kPatch400;
    const double T = 0.05;  // simulated time, s
    Tissue probe = make_scene(size, IntegratorKind::kSymplecticEuler, TissueParams{});
    const double dt_crit = estimate_stability(probe.system(), 3000).dt_critical_s();
    // Reference: RK4, double, step dt_crit/100; its own convergence is checked against dt_crit/200.
    const int ref_steps = int(std::ceil(T / (dt_crit / 100)));
    Rk4Reference ref(probe.system()), ref2(probe.system());
    ref.run(T / ref_steps, ref_steps);
    ref2.run(T / (2 * ref_steps), 2 * ref_steps);
    double ref_diff = 0;
    for (size_t i = 0; i < ref.x.size(); ++i) ref_diff = std::max(ref_diff, (ref.x[i] - ref2.x[i]).norm());
    double deflection = 0;
    for (size_t i = 0; i < ref2.x.size(); ++i) deflection = std::max(deflection, std::abs(ref2.x[i].z()));

    std::printf("\n## Run time against error (400-triangle membrane, %.0f ms simulated)\n\n", T * 1e3);
    std::printf("Explicit limit (power iteration): dt_crit = 2/ω_max = %.3f ms. Reference: RK4 in double, %d steps; "
                "it differs from RK4 at half its step by %.2g µm (max); peak deflection %.3f mm.\n\n",
                dt_crit * 1e3, 2 * ref_steps, ref_diff * 1e3, deflection);
    std::printf("| integrator | dt (ms) | dt / dt_crit | wall per simulated 50 ms (ms) | RMS error (µm) |\n");
    std::printf("|---|---|---|---|---|\n");
    std::vector<ErrorPoint> pts;
    const double ladder_explicit[] = {0.9, 0.5, 0.25, 0.1, 0.05};
    const double ladder_implicit[] = {20, 10, 4, 2, 1, 0.5, 0.25, 0.1};
    for (IntegratorKind kind : kKinds) {
        const bool expl = kind == IntegratorKind::kPaperEuler || kind == IntegratorKind::kSymplecticEuler;
        std::vector<double> ladder = expl ? std::vector<double>(std::begin(ladder_explicit), std::end(ladder_explicit))
                                          : std::vector<double>(std::begin(ladder_implicit), std::end(ladder_implicit));
        for (double r : ladder) {
            const int steps = std::max(1, int(std::lround(T / (r * dt_crit))));
            const float dt = float(T / steps);
            std::vector<double> walls;
            double err = 0;
            bool finite = true;
            for (int rep = 0; rep < std::min(repeats, 3); ++rep) {
                Tissue t = make_scene(size, kind, TissueParams{});
                const auto t0 = Clock::now();
                for (int s = 0; s < steps; ++s) t.step(dt, 1);
                walls.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
                err = rms_error(t.system(), ref2.x);
                finite = std::isfinite(err);
            }
            pts.push_back({kind, double(dt), median(walls), err * 1e3, finite});
            std::printf("| %s | %.4f | %.2f | %.2f | %s |\n", std::string(to_string(kind)).c_str(), dt * 1e3,
                        double(dt) / dt_crit, median(walls),
                        finite ? (std::to_string(int(std::lround(err * 1e6)) / 1000.0)).c_str() : "diverged");
            std::fflush(stdout);
        }
    }
    // Equal wall time: the best error each integrator reaches within a budget.
    std::printf("\n## Equal wall time: best RMS error (µm) within a wall budget per simulated 50 ms\n\n");
    std::printf("| budget (ms) | paper-euler | symplectic-euler | implicit-euler | xpbd |\n|---|---|---|---|---|\n");
    for (double budget : {0.5, 1.0, 2.0, 5.0, 20.0}) {
        std::printf("| %.1f |", budget);
        for (IntegratorKind kind : kKinds) {
            double best = INFINITY;
            for (const ErrorPoint& p : pts)
                if (p.kind == kind && p.finite && p.wall_ms <= budget) best = std::min(best, p.err_um);
            if (std::isfinite(best)) std::printf(" %.3g |", best);
            else std::printf(" — |");
        }
        std::printf("\n");
    }
    return 0;
}
