// Micro-benchmark of the exact contact query (ExactContact: colliding set + deformation values) against the
// uniform-grid ExactNarrowPhase, on the collision benchmark's scenes (4 × 4 mm membranes of 1k and 3k
// triangles, the 2000-triangle forceps with jaws open 30°, the pose found as bench_collision finds it) with
// seeded random poses around each scene's contact. Thread-CPU time per query (median, p99); the sets of the
// two methods are compared pose by pose. A third timing moves the jaws (opening 30° ± 1°, alternating) with each
// pose, as the pedal does: that query rebuilds the articulated parts' structure, and its set is compared too.
//
// Usage: bench_contact [--poses N] [--seed S] [--json] [--no-grid]

#include "bench_util.hpp"
#include "eyesim/sim/collision/contact.hpp"
#include "eyesim/sim/collision/exact.hpp"
#include "eyesim/sim/collision/instrument.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <random>
#include <string>
#include <vector>

using namespace eyesim::sim;
using namespace eyesim::sim::collision;
using eyesim::sim::collision::bench::pose_at;
using eyesim::sim::collision::bench::thread_cpu_us;

namespace {

constexpr float kPi = 3.14159265358979f;



Eigen::Isometry3f scene_pose(float tilt_deg, float depth_mm) {
    const float a = tilt_deg * kPi / 180.0f;
    return pose_at(Vec3f(0.11f, 0.07f, -depth_mm), Vec3f(std::sin(a), 0.0f, -std::cos(a)));
}

std::vector<uint32_t> grid_set(ExactNarrowPhase& exact, const TriangleMesh& m, std::span<const Vec3f> verts,
                               const PosedInstrument& ins) {
    const MeshRef mr{verts, m.triangles, Eigen::Isometry3f::Identity()};
    const MeshRef tr{ins.vertices_local_mm(), ins.instrument().mesh.triangles, ins.instrument_to_eye()};
    ExactOptions opt;
    opt.vertex_triangle_begin = m.vertex_triangle_begin;
    opt.vertex_triangles = m.vertex_triangles;
    const auto s = exact.colliding_triangles(mr, tr, ins.instrument().part_triangle_begin, opt);
    return {s.begin(), s.end()};
}

/// bench_collision's pose search: smallest approach angle whose push reaches `target` colliding triangles,
/// then the depth by bisection.
Eigen::Isometry3f calibrate(const TriangleMesh& m, PosedInstrument& forceps, size_t target, float& tilt_out) {
    ExactNarrowPhase exact(m.triangle_count(), 4096);
    float found = -1.0f, tilt = 0.0f;
    for (float tl : {0.0f, 15.0f, 30.0f, 45.0f, 60.0f, 70.0f, 75.0f, 80.0f, 85.0f}) {
        tilt = tl;
        for (float d = 0.02f; d <= 1.5f && found < 0; d += 0.02f) {
            forceps.set_state(30.0f, scene_pose(tl, d));
            if (grid_set(exact, m, m.vertices_mm, forceps).size() >= target) found = d;
        }
        if (found >= 0) break;
    }
    if (found < 0) found = 1.5f;
    float lo = std::max(0.0f, found - 0.02f), hi = found;
    for (int it = 0; it < 20; ++it) {
        const float mid = 0.5f * (lo + hi);
        forceps.set_state(30.0f, scene_pose(tilt, mid));
        (grid_set(exact, m, m.vertices_mm, forceps).size() < target ? lo : hi) = mid;
    }
    tilt_out = tilt;
    return scene_pose(tilt, hi);
}

struct Stats {
    double p50 = 0, p99 = 0;
};
Stats stats(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    if (v.empty()) return {};
    return {v[v.size() / 2], v[std::min(v.size() - 1, size_t(double(v.size()) * 0.99))]};
}

}  // namespace

int main(int argc, char** argv) {
    int poses = 1000;
    unsigned seed = 1;
    bool json = false, grid_too = true;
    for (int i = 1; i < argc; ++i) {
        if (!std::strcmp(argv[i], "--poses") && i + 1 < argc) poses = std::max(1, std::atoi(argv[++i]));
        else if (!std::strcmp(argv[i], "--seed") && i + 1 < argc) seed = unsigned(std::atoi(argv[++i]));
        else if (!std::strcmp(argv[i], "--json")) json = true;
        else if (!std::strcmp(argv[i], "--no-grid")) grid_too = false;  // profile the contact query alone
        else {
            std::fprintf(stderr, "eyesim: error: usage: %s [--poses N] [--seed S] [--json] [--no-grid]\n", argv[0]);
            return 2;
        }
    }
    PosedInstrument forceps(make_forceps());
    struct SceneDef {
        const char* name;
        PatchSize patch;
        size_t target;
    };
    const SceneDef defs[] = {{"1k membrane, ~40 colliding", kPatch1k, 40},
                             {"3k membrane, ~40 colliding", kPatch3k, 40},
                             {"3k membrane, ~200 colliding (dense)", kPatch3k, 200}};
    nlohmann::json out = nlohmann::json::array();
    if (!json)
        std::printf("| scene | colliding (median) | exact contact p50 µs | p99 µs | set only p50 µs | p99 µs "
                    "| grid narrow phase p50 µs | p99 µs | jaws moved p50 µs | p99 µs | poses with equal sets (jaws moved) "
                    "| candidates | pair tests | parity tests | front triangles |\n"
                    "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (const SceneDef& d : defs) {
        const TriangleMesh m = make_membrane_patch(4.0f, 4.0f, d.patch.nx, d.patch.ny);
        float tilt = 0;
        const Eigen::Isometry3f base = calibrate(m, forceps, d.target, tilt);
        ExactContact contact(m);
        ExactNarrowPhase grid(m.triangle_count(), 4096);
        std::mt19937 rng(seed);
        std::uniform_real_distribution<float> lat(-0.05f, 0.05f), dep(-0.03f, 0.03f), ang(-3.0f, 3.0f),
            spin(-kPi, kPi);
        std::vector<double> t_contact, t_grid, t_set, t_jaw;
        std::vector<size_t> sizes, cands, pairs, insides, fronts;
        size_t equal = 0, equal_jaw = 0;
        for (int i = 0; i < poses; ++i) {
            // Around the contact: tip ±50 µm laterally, ±30 µm in depth, axis tilted ±3°, any roll.
            const Vec3f tip = base.translation() + Vec3f(lat(rng), lat(rng), dep(rng));
            const Eigen::Matrix3f rot = (Eigen::AngleAxisf(ang(rng) * kPi / 180.0f, Vec3f::UnitX()) *
                                         Eigen::AngleAxisf(ang(rng) * kPi / 180.0f, Vec3f::UnitY()))
                                            .toRotationMatrix() *
                                        base.linear() * Eigen::AngleAxisf(spin(rng), Vec3f::UnitZ()).toRotationMatrix();
            Eigen::Isometry3f pose = Eigen::Isometry3f::Identity();
            pose.linear() = rot;
            pose.translation() = tip;
            forceps.set_state(30.0f, pose);
            const Vec3f pi(0, 0, 1);
            contact.query(m.vertices_mm, forceps, pi);  // warm (the first pose builds the instrument grid)
            ContactOptions set_only;
            set_only.deformation = false;
            const double s0 = thread_cpu_us();
            contact.query(m.vertices_mm, forceps, pi, set_only);
            t_set.push_back(thread_cpu_us() - s0);
            const double c0 = thread_cpu_us();
            const ContactResult& r = contact.query(m.vertices_mm, forceps, pi);
            const double c1 = thread_cpu_us();
            const std::vector<uint32_t> a(r.colliding_triangles.begin(), r.colliding_triangles.end());
            cands.push_back(r.candidate_triangles);
            pairs.push_back(r.pair_tests);
            insides.push_back(r.inside_tests);
            fronts.push_back(r.front_triangles);
            const double g0 = thread_cpu_us();
            const std::vector<uint32_t> b = grid_too ? grid_set(grid, m, m.vertices_mm, forceps) : a;
            const double g1 = thread_cpu_us();
            t_contact.push_back(c1 - c0);
            t_grid.push_back(g1 - g0);
            sizes.push_back(a.size());
            equal += a == b;
            // The pedal moves the jaws with the pose: the query rebuilds what the opening moved.
            forceps.set_state(i % 2 ? 31.0f : 29.0f, pose);
            const double j0 = thread_cpu_us();
            const ContactResult& rj = contact.query(m.vertices_mm, forceps, pi);
            t_jaw.push_back(thread_cpu_us() - j0);
            const std::vector<uint32_t> aj(rj.colliding_triangles.begin(), rj.colliding_triangles.end());
            equal_jaw += aj == (grid_too ? grid_set(grid, m, m.vertices_mm, forceps) : aj);
        }
        auto median = [](std::vector<size_t> v) {
            std::sort(v.begin(), v.end());
            return v[v.size() / 2];
        };
        const Stats sc = stats(t_contact), sg = stats(t_grid), ss = stats(t_set), sj = stats(t_jaw);
        if (json) {
            out.push_back({{"name", d.name},
                           {"approach_deg", tilt},
                           {"colliding_median", median(sizes)},
                           {"candidates_median", median(cands)},
                           {"pair_tests_median", median(pairs)},
                           {"inside_tests_median", median(insides)},
                           {"front_triangles_median", median(fronts)},
                           {"set_only_us", {{"p50", ss.p50}, {"p99", ss.p99}}},
                           {"exact_contact_us", {{"p50", sc.p50}, {"p99", sc.p99}}},
                           {"grid_narrow_phase_us", {{"p50", sg.p50}, {"p99", sg.p99}}},
                           {"jaw_change_us", {{"p50", sj.p50}, {"p99", sj.p99}}},
                           {"poses", poses},
                           {"equal_sets", equal},
                           {"equal_sets_jaw_change", equal_jaw}});
        } else {
            std::printf("| %s | %zu | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f | %zu / %d (%zu / %d) | %zu | %zu "
                        "| %zu | %zu |\n",
                        d.name, median(sizes), sc.p50, sc.p99, ss.p50, ss.p99, sg.p50, sg.p99, sj.p50, sj.p99, equal,
                        poses, equal_jaw, poses, median(cands), median(pairs), median(insides), median(fronts));
            std::fflush(stdout);
        }
    }
    if (json) std::printf("%s\n", nlohmann::json{{"scenes", out}, {"seed", seed}}.dump().c_str());
    return 0;
}
