// The scheduled spring-force kernel: its schedule (colouring), bitwise agreement of every implementation, and
// agreement with the plain one-spring-at-a-time reference in array order.
#include "tissue_test_util.hpp"

#include <catch2/catch.hpp>

#include <cstring>
#include <random>
#include <set>

using namespace tissue_test;

namespace {

MassSpringSystem random_membrane(uint32_t seed, bool bending) {
    MaterialParams m;
    m.bending_stiffness_nN_per_mm = bending ? 150.0f : 0.0f;
    m.bending_damping_nN_s_per_mm = bending ? 0.01f : 0.0f;
    m.rest_length_scale = 0.95f;
    MassSpringSystem s = MassSpringSystem::from_mesh(make_membrane_patch(4.0f, 4.0f, 22, 23), m);
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    for (size_t i = 0; i < s.node_count(); ++i) {
        s.x_mm[i] += 0.05f * Vec3f(u(rng), u(rng), u(rng));
        s.v_mm_per_s[i] = 20.0f * Vec3f(u(rng), u(rng), u(rng));
    }
    // Per-spring parameters over four decades, so every lane sees different numbers.
    for (Spring& sp : s.springs) {
        sp.stiffness_nN_per_mm *= std::pow(10.0f, 2.0f * u(rng));
        sp.damping_nN_s_per_mm = 0.02f * (1.0f + u(rng));
    }
    s.x_mm[7] = s.x_mm[8];  // one pair of coincident nodes (and any spring joining them has no direction)
    s.rebuild_incidence();
    return s;
}

std::vector<float> run_kernel(const MassSpringSystem& s, SpringKernel k) {
    PaddedVec3Array f(s.node_count(), Vec3f(0.5f, -0.25f, 1.0f));
    accumulate_scheduled_spring_forces(s.schedule, s.x_mm.lanes(), s.v_mm_per_s.lanes(), f.lanes(), k);
    std::vector<float> out(4 * s.node_count());
    std::memcpy(out.data(), f.lanes(), out.size() * sizeof(float));
    return out;
}

}  // namespace

TEST_CASE("spring schedule: every spring once, no shared node within a colour class", "[tissue][kernel]") {
    for (bool bending : {false, true}) {
        const MassSpringSystem s = random_membrane(1, bending);
        const SpringSchedule& sc = s.schedule;
        REQUIRE(sc.matches(s.springs));
        REQUIRE(sc.class_begin.size() == sc.colours + 1);
        REQUIRE(sc.class_begin.back() == s.spring_count());
        REQUIRE(sc.a.size() % 4 == 0);
        std::set<uint32_t> seen;
        uint32_t max_degree = 0;
        for (size_t v = 0; v < s.node_count(); ++v)
            max_degree = std::max(max_degree, s.node_spring_begin[v + 1] - s.node_spring_begin[v]);
        CHECK(sc.colours <= 2 * max_degree - 1);  // greedy edge colouring bound
        for (uint32_t c = 0; c < sc.colours; ++c) {
            std::set<uint32_t> nodes;
            for (uint32_t j = sc.class_begin[c]; j < sc.class_begin[c + 1]; ++j) {
                INFO("colour " << c << " slot " << j);
                CHECK(nodes.insert(sc.a[j]).second);
                CHECK(nodes.insert(sc.b[j]).second);
                CHECK(seen.insert(sc.spring[j]).second);
            }
        }
        CHECK(seen.size() == s.spring_count());
        for (size_t j = s.spring_count(); j < sc.a.size(); ++j) CHECK(sc.spring[j] == kNoIndex);
    }
}

TEST_CASE("spring kernels are bitwise equal to the portable one", "[tissue][kernel]") {
    INFO("best kernel on this CPU: " << to_string(best_spring_kernel()));
    for (uint32_t seed = 1; seed <= 5; ++seed) {
        const MassSpringSystem s = random_membrane(seed, seed % 2 == 0);
        const std::vector<float> portable = run_kernel(s, SpringKernel::kPortable);
        for (SpringKernel k : {SpringKernel::kSse2, SpringKernel::kAvx}) {
            if (!spring_kernel_available(k)) continue;
            const std::vector<float> simd = run_kernel(s, k);
            INFO("kernel " << to_string(k) << " seed " << seed);
            for (size_t i = 0; i < s.node_count(); ++i)  // the x, y, z lanes; the padding lane is not part of f
                REQUIRE(std::memcmp(&simd[4 * i], &portable[4 * i], 3 * sizeof(float)) == 0);
        }
    }
}

TEST_CASE("scheduled forces equal the array-order reference", "[tissue][kernel]") {
    for (uint32_t seed = 1; seed <= 4; ++seed) {
        MassSpringSystem s = random_membrane(seed, seed % 2 == 1);
        PaddedVec3Array ref(s.node_count(), Vec3f::Zero());
        accumulate_spring_forces(s.springs, s.x_mm, s.v_mm_per_s, ref);
        TissueParams p;  // no gravity, no drag: compute_forces is the springs plus ext (zero here)
        s.compute_forces(p);
        double scale = 0.0;
        for (size_t i = 0; i < s.node_count(); ++i) scale = std::max(scale, double(ref[i].norm()));
        REQUIRE(scale > 0.0);
        for (size_t i = 0; i < s.node_count(); ++i) {
            INFO("node " << i);
            // Only the summation order differs: a few float roundings of the largest force.
            REQUIRE((s.f_nN[i] - ref[i]).norm() <= 1e-5 * scale);
        }
    }
}

TEST_CASE("the schedule follows tearing and cutting", "[tissue][kernel]") {
    MassSpringSystem s = random_membrane(3, true);
    std::vector<uint32_t> torn;
    for (uint32_t k = 0; k < s.spring_count(); k += 7) torn.push_back(k);
    const std::vector<uint32_t> cut{100, 101, 150};
    s.remove(torn, cut);
    const char* why = "";
    const bool consistent = s.check_consistency(&why);  // includes schedule.matches(springs)
    INFO(why);
    REQUIRE(consistent);
    PaddedVec3Array ref(s.node_count(), Vec3f::Zero());
    accumulate_spring_forces(s.springs, s.x_mm, s.v_mm_per_s, ref);
    s.compute_forces(TissueParams{});
    double scale = 0.0;
    for (size_t i = 0; i < s.node_count(); ++i) scale = std::max(scale, double(ref[i].norm()));
    for (size_t i = 0; i < s.node_count(); ++i) REQUIRE((s.f_nN[i] - ref[i]).norm() <= 1e-5 * scale);
}

TEST_CASE("the padding lanes of x, v and f stay zero through every integrator", "[tissue][kernel]") {
    for (IntegratorKind kind : kAllIntegrators) {
        TissueParams p;
        p.gravity_mm_per_s2 = Vec3f(0, 0, -900.0f);
        p.a_max_mm_per_s2 = 5e4f;
        p.v_max_mm_per_s = 200.0f;
        p.container_radius_mm = 2.9f;
        p.container_centre_mm = Vec3f(2.0f, 2.0f, 0.0f);
        Tissue t(patch400(), MaterialParams{}, p, kind);
        t.fix_rim();
        for (int i = 0; i < 50; ++i) t.step(1e-3f, 4);
        const MassSpringSystem& s = t.system();
        INFO(to_string(kind));
        for (size_t i = 0; i < s.node_count(); ++i) {
            REQUIRE(s.x_mm.lanes()[i].v[3] == 0.0f);
            REQUIRE(s.v_mm_per_s.lanes()[i].v[3] == 0.0f);
        }
    }
}
