// Tissue benchmark: step time on the paper's Table 3 meshes per integrator, and run time against error versus a
// double-precision RK4 reference with a tiny step. Prints markdown tables (docs/bench/tissue.md).
//
// Usage: bench_sim_tissue [--repeats N] [--quick]
#include "eyesim/sim/tissue/stability.hpp"
#include "eyesim/sim/tissue/tissue.hpp"
#include "thread_cpu.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include <time.h>

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
MaterialParams scene_material(float k) {
    MaterialParams m;
    m.edge_stiffness_nN_per_mm = k;
    m.edge_damping_nN_s_per_mm = 2e-5f * k;
    m.rest_length_scale = 0.95f;
    return m;
}
constexpr float kLoad_nN_per_mm2 = 20.0f;  // pressure on the membrane (per 1000 nN/mm of stiffness), −z

Tissue make_scene(PatchSize size, IntegratorKind kind, const TissueParams& p, float k = 1000.0f) {
    const TriangleMesh mesh = make_membrane_patch(4.0f, 4.0f, size.nx, size.ny);
    Tissue t(mesh, scene_material(k), p, kind);
    const float load = kLoad_nN_per_mm2 * k / 1000.0f;  // same static shape for every stiffness
    t.fix_rim();
    // Pressure load: each node carries a third of its triangles' area.
    std::vector<Vec3f> f(mesh.vertex_count(), Vec3f::Zero());
    for (const auto& tri : mesh.triangles) {
        const float area = 0.5f * (mesh.vertices_mm[tri[1]] - mesh.vertices_mm[tri[0]])
                                      .cross(mesh.vertices_mm[tri[2]] - mesh.vertices_mm[tri[0]])
                                      .norm();
        for (uint32_t v : tri) f[v].z() -= load * area / 3.0f;
    }
    for (uint32_t v = 0; v < f.size(); ++v) t.set_constant_force(v, f[v]);
    return t;
}

// ---- Part 1: step time ----
struct StepTiming {
    double cpu_us_per_step;   // median over repeats, thread CPU time
    double wall_us_per_step;  // median over repeats, wall time
    size_t springs;
};

StepTiming time_steps(PatchSize size, IntegratorKind kind, float dt, int repeats, int steps) {
    TissueParams p;
    p.a_max_mm_per_s2 = 1e6f;  // the paper's rules active (tearing check runs every step, never fires here)
    p.p_tear_percent = 50.0f;
    p.v_max_mm_per_s = 1e3f;
    Tissue t = make_scene(size, kind, p);
    for (int i = 0; i < 200; ++i) t.step(dt, 1);  // warm-up (caches, solver buffers)
    std::vector<double> cpu, wall;
    for (int r = 0; r < repeats; ++r) {
        const auto t0 = Clock::now();
        const double c0 = eyesim::bench::thread_cpu_us();
        for (int i = 0; i < steps; ++i) t.step(dt, 1);
        cpu.push_back((eyesim::bench::thread_cpu_us() - c0) / steps);
        wall.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count() / steps);
    }
    return {median(cpu), median(wall), t.system().spring_count()};
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
    double dt_s, cpu_ms, err_um;
    bool finite;
};

std::string fmt3(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.3g", v);
    return buf;
}


// Run time against error for one stiffness: every integrator over a ladder of steps, RMS node error at T against
// a double-precision RK4 reference, run time = thread CPU time (median of repeats).
void error_table(float k, int repeats) {
    const PatchSize size = kPatch400;
    const double T = 0.05;  // simulated time, s
    Tissue probe = make_scene(size, IntegratorKind::kSymplecticEuler, TissueParams{}, k);
    const double dt_crit = estimate_stability(probe.system(), 3000).dt_critical_s();
    // Reference: RK4, double, step dt_crit/50; its own convergence is checked against half that step.
    const int ref_steps = int(std::ceil(T / (dt_crit / 50)));
    Rk4Reference ref(probe.system()), ref2(probe.system());
    ref.run(T / ref_steps, ref_steps);
    ref2.run(T / (2 * ref_steps), 2 * ref_steps);
    double ref_diff = 0, deflection = 0;
    for (size_t i = 0; i < ref.x.size(); ++i) {
        ref_diff = std::max(ref_diff, (ref.x[i] - ref2.x[i]).norm());
        deflection = std::max(deflection, std::abs(ref2.x[i].z()));
    }
    std::printf("\n## Run time against error: 400-triangle membrane, k = %.0f nN/mm, %.0f ms simulated\n\n", k,
                T * 1e3);
    std::printf("Explicit limit (power iteration): dt_crit = 2/ω_max = %.4f ms. Reference: RK4 in double, %d steps "
                "(max difference to RK4 at twice its step: %.2g µm); peak deflection at %.0f ms: %.3f mm. "
                "CPU = thread CPU time per simulated %.0f ms, median of %d.\n\n",
                dt_crit * 1e3, 2 * ref_steps, ref_diff * 1e3, T * 1e3, deflection, T * 1e3, std::min(repeats, 5));
    std::printf("| integrator | dt (ms) | dt / dt_crit | CPU (ms) | RMS error (µm) | error / deflection |\n");
    std::printf("|---|---|---|---|---|---|\n");
    std::vector<ErrorPoint> pts;
    const double ladder_explicit[] = {0.9, 0.5, 0.25, 0.1};
    const double ladder_implicit[] = {20, 10, 4, 2, 1, 0.5, 0.25, 0.1};
    for (IntegratorKind kind : kKinds) {
        const bool expl = kind == IntegratorKind::kPaperEuler || kind == IntegratorKind::kSymplecticEuler;
        std::vector<double> ladder = expl ? std::vector<double>(std::begin(ladder_explicit), std::end(ladder_explicit))
                                          : std::vector<double>(std::begin(ladder_implicit), std::end(ladder_implicit));
        for (double r : ladder) {
            const int steps = std::max(1, int(std::lround(T / (r * dt_crit))));
            const float dt = float(T / steps);
            std::vector<double> cpu;
            double err = 0;
            for (int rep = 0; rep < std::min(repeats, 5); ++rep) {
                Tissue t = make_scene(size, kind, TissueParams{}, k);
                const double c0 = eyesim::bench::thread_cpu_us();
                for (int s = 0; s < steps; ++s) t.step(dt, 1);
                cpu.push_back((eyesim::bench::thread_cpu_us() - c0) * 1e-3);
                err = rms_error(t.system(), ref2.x);
            }
            const bool finite = std::isfinite(err);
            pts.push_back({kind, double(dt), median(cpu), err * 1e3, finite});
            std::printf("| %s | %.4g | %.2f | %.3g | %s | %s |\n", std::string(to_string(kind)).c_str(), dt * 1e3,
                        double(dt) / dt_crit, median(cpu), finite ? fmt3(err * 1e3).c_str() : "diverged",
                        finite ? fmt3(err / deflection).c_str() : "—");
            std::fflush(stdout);
        }
    }
    // Equal run time: the best error each integrator reaches within a CPU budget.
    std::printf("\n**Equal run time** (k = %.0f nN/mm): best RMS error (µm) within a CPU budget per simulated 50 ms "
                "(— = no step size fits the budget; explicit steps cannot exceed dt_crit)\n\n", k);
    std::printf("| budget (ms) | paper-euler | symplectic-euler | implicit-euler | xpbd |\n|---|---|---|---|---|\n");
    for (double budget : {0.3, 1.0, 3.0, 10.0, 30.0}) {
        std::printf("| %.1f |", budget);
        for (IntegratorKind kind : kKinds) {
            double best = INFINITY;
            for (const ErrorPoint& p : pts)
                if (p.kind == kind && p.finite && p.cpu_ms <= budget) best = std::min(best, p.err_um);
            if (std::isfinite(best)) std::printf(" %s |", fmt3(best).c_str());
            else std::printf(" — |");
        }
        std::printf("\n");
    }
}

// ---- Part 1b: the force evaluation alone, per implementation ----
// The array-order reference loop (one spring at a time in mesh order: every update waits on the previous one
// through memory) against the coloured schedule with each kernel; error = largest force difference to the
// reference relative to the largest force (float rounding from the different summation order).
void kernel_table(int repeats, bool quick) {
    struct Row { const char* name; PatchSize size; };
    const Row rows[] = {{"400 triangles", kPatch400}, {"1k triangles", kPatch1k}, {"3k triangles", kPatch3k}};
    std::printf("\n## Spring forces alone (µs per evaluation, thread CPU time, median of %d repeats; best kernel "
                "on this CPU: %s)\n\n", repeats, to_string(best_spring_kernel()));
    std::printf("| mesh | springs | colours | array-order reference | portable scheduled | sse2 | avx | "
                "reference / best | max rel. difference |\n");
    std::printf("|---|---|---|---|---|---|---|---|---|\n");
    TissueParams p;
    for (const Row& r : rows) {
        Tissue t = make_scene(r.size, IntegratorKind::kPaperEuler, p);
        for (int i = 0; i < 200; ++i) t.step(1e-4f, 1);  // a deflected, moving membrane
        MassSpringSystem& s = t.system_mut();
        const int evals = quick ? 500 : 3000;
        PaddedVec3Array ref(s.node_count(), Vec3f::Zero()), f(s.node_count(), Vec3f::Zero());
        auto time = [&](auto&& body) {
            std::vector<double> cpu;
            for (int rep = 0; rep < repeats; ++rep) {
                const double c0 = eyesim::bench::thread_cpu_us();
                for (int i = 0; i < evals; ++i) body();
                cpu.push_back((eyesim::bench::thread_cpu_us() - c0) / evals);
            }
            return median(cpu);
        };
        const double t_ref = time([&] {
            ref.set_zero();
            accumulate_spring_forces(s.springs, s.x_mm, s.v_mm_per_s, ref);
        });
        double t_k[3] = {0, 0, 0}, max_diff = 0.0, max_f = 0.0;
        const SpringKernel kernels[3] = {SpringKernel::kPortable, SpringKernel::kSse2, SpringKernel::kAvx};
        for (int k = 0; k < 3; ++k) {
            if (!spring_kernel_available(kernels[k])) continue;
            t_k[k] = time([&] {
                f.set_zero();
                accumulate_scheduled_spring_forces(s.schedule, s.x_mm.lanes(), s.v_mm_per_s.lanes(), f.lanes(),
                                                   kernels[k]);
            });
            for (size_t i = 0; i < s.node_count(); ++i) {
                max_diff = std::max(max_diff, double((f[i] - ref[i]).norm()));
                max_f = std::max(max_f, double(ref[i].norm()));
            }
        }
        const double best = t_k[int(best_spring_kernel())];
        auto cell = [](double us) {
            char buf[32];
            std::snprintf(buf, sizeof buf, us > 0.0 ? "%.1f" : "n/a", us);
            return std::string(buf);
        };
        std::printf("| %s | %zu | %u | %.1f | %s | %s | %s | %.1f× | %.1e |\n", r.name, s.spring_count(),
                    s.schedule.colours, t_ref, cell(t_k[0]).c_str(), cell(t_k[1]).c_str(), cell(t_k[2]).c_str(),
                    t_ref / best, max_f > 0.0 ? max_diff / max_f : 0.0);
        std::fflush(stdout);
    }
}

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
    std::printf("## Step time per integrator (µs per step: thread CPU time, median of %d repeats; wall time in "
                "brackets; machine shared and busy)\n\n", repeats);
    std::printf("| mesh | springs | paper Table 3 | paper-euler | symplectic-euler | implicit-euler | xpbd | "
                "paper-euler vs Table 3 | implicit / paper-euler | xpbd / paper-euler |\n");
    std::printf("|---|---|---|---|---|---|---|---|---|---|\n");
    for (const Row& r : rows) {
        double us[4], wall[4];
        size_t springs = 0;
        for (int k = 0; k < 4; ++k) {
            const bool slow = kKinds[k] == IntegratorKind::kImplicitEuler || kKinds[k] == IntegratorKind::kXpbd;
            const int steps = slow ? (quick ? 50 : 200) : (quick ? 500 : 2000);
            const StepTiming st = time_steps(r.size, kKinds[k], 1e-4f, repeats, steps);
            us[k] = st.cpu_us_per_step;
            wall[k] = st.wall_us_per_step;
            springs = st.springs;
        }
        std::printf("| %s | %zu | %.1f ms | %.1f (%.1f) | %.1f (%.1f) | %.0f (%.0f) | %.0f (%.0f) | %.0f× faster | "
                    "%.1f× | %.1f× |\n",
                    r.name, springs, r.paper_ms, us[0], wall[0], us[1], wall[1], us[2], wall[2], us[3], wall[3],
                    r.paper_ms * 1000.0 / us[0], us[2] / us[0], us[3] / us[0]);
        std::fflush(stdout);
    }

    kernel_table(repeats, quick);

    // ---- Part 2: a soft and a 100× stiffer membrane ----
    error_table(1000.0f, repeats);
    error_table(100000.0f, repeats);
    return 0;
}
