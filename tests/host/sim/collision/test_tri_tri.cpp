#include "eyesim/sim/collision/tri_tri.hpp"

#include <catch2/catch.hpp>
#include <fcl/narrowphase/detail/traversal/collision/intersect.h>

#include <random>

using namespace eyesim::sim;
using namespace eyesim::sim::collision;

TEST_CASE("triangle-triangle test agrees with FCL's on random near-touching pairs", "[sim][collision]") {
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    int hits = 0, disagreements = 0;
    for (int i = 0; i < 20000; ++i) {
        Vec3f a[3], b[3];
        for (auto& p : a) p = Vec3f(u(rng), u(rng), u(rng));
        const Vec3f shift(u(rng), u(rng), u(rng));
        for (auto& p : b) p = Vec3f(u(rng), u(rng), u(rng)) * 0.8f + shift * 0.6f;
        const bool ours = triangles_intersect(a[0], a[1], a[2], b[0], b[1], b[2]);
        const bool theirs = fcl::detail::Intersect<double>::intersect_Triangle(
            a[0].cast<double>(), a[1].cast<double>(), a[2].cast<double>(), b[0].cast<double>(), b[1].cast<double>(),
            b[2].cast<double>());
        hits += ours;
        disagreements += ours != theirs;
    }
    CHECK(hits > 2000);          // the set exercises both answers
    CHECK(disagreements <= 2);   // FCL works in a different arithmetic; exact ties are measure-zero
}

TEST_CASE("triangle-triangle test: hand-made cases incl. coplanar and touching", "[sim][collision]") {
    const Vec3f a0(0, 0, 0), a1(1, 0, 0), a2(0, 1, 0);
    // Piercing.
    CHECK(triangles_intersect(a0, a1, a2, Vec3f(0.2f, 0.2f, -1), Vec3f(0.2f, 0.2f, 1), Vec3f(0.3f, 0.9f, 0.5f)));
    // Parallel planes.
    CHECK_FALSE(triangles_intersect(a0, a1, a2, Vec3f(0, 0, 0.1f), Vec3f(1, 0, 0.1f), Vec3f(0, 1, 0.1f)));
    // Coplanar overlapping, coplanar disjoint, coplanar contained.
    CHECK(triangles_intersect(a0, a1, a2, Vec3f(0.5f, 0.5f, 0), Vec3f(-0.5f, 0.2f, 0), Vec3f(0.2f, -0.5f, 0)));
    CHECK_FALSE(triangles_intersect(a0, a1, a2, Vec3f(2, 2, 0), Vec3f(3, 2, 0), Vec3f(2, 3, 0)));
    CHECK(triangles_intersect(a0, a1, a2, Vec3f(0.1f, 0.1f, 0), Vec3f(0.2f, 0.1f, 0), Vec3f(0.1f, 0.2f, 0)));
    // Touching at a vertex (closed triangles).
    CHECK(triangles_intersect(a0, a1, a2, Vec3f(1, 0, 0), Vec3f(2, 0, 1), Vec3f(2, 0, -1)));
    // Crossing planes but the line misses.
    CHECK_FALSE(triangles_intersect(a0, a1, a2, Vec3f(2, 2, -1), Vec3f(2, 2, 1), Vec3f(3, 2, 0)));
}

TEST_CASE("point in closed mesh by ray parity", "[sim][collision]") {
    // Unit cube.
    std::vector<Vec3f> v{{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}};
    std::vector<std::array<uint32_t, 3>> t{{0, 2, 1}, {0, 3, 2}, {4, 5, 6}, {4, 6, 7}, {0, 1, 5}, {0, 5, 4},
                                           {1, 2, 6}, {1, 6, 5}, {2, 3, 7}, {2, 7, 6}, {3, 0, 4}, {3, 4, 7}};
    CHECK(point_inside_closed_mesh(Vec3f(0.5f, 0.5f, 0.5f), v, t));
    CHECK(point_inside_closed_mesh(Vec3f(0.01f, 0.99f, 0.5f), v, t));
    CHECK_FALSE(point_inside_closed_mesh(Vec3f(1.5f, 0.5f, 0.5f), v, t));
    CHECK_FALSE(point_inside_closed_mesh(Vec3f(-0.1f, 0.5f, 0.5f), v, t));
}
