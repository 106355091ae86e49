#include "eyesim/sim/mesh.hpp"

#include <Eigen/Geometry>
#include <catch2/catch.hpp>

#include <set>

using namespace eyesim::sim;

TEST_CASE("membrane patch sizes match the paper's Table 3 meshes", "[sim][mesh]") {
    CHECK(make_membrane_patch(8, 8, kPatch400.nx, kPatch400.ny).triangle_count() == 392);
    CHECK(make_membrane_patch(8, 8, kPatch1k.nx, kPatch1k.ny).triangle_count() == 1012);
    CHECK(make_membrane_patch(8, 8, kPatch3k.nx, kPatch3k.ny).triangle_count() == 3042);
}

TEST_CASE("patch adjacency agrees with a brute-force count and Euler's formula", "[sim][mesh]") {
    const int nx = 7, ny = 5;
    const TriangleMesh m = make_membrane_patch(7.0f, 5.0f, nx, ny);
    // Planar grid: E = nx(ny+1) + ny(nx+1) + nx·ny diagonals; V - E + F = 1 for a disc.
    CHECK(m.edges.size() == size_t(nx * (ny + 1) + ny * (nx + 1) + nx * ny));
    CHECK(long(m.vertex_count()) - long(m.edges.size()) + long(m.triangle_count()) == 1);
    for (uint32_t v = 0; v < m.vertex_count(); ++v) {
        std::set<uint32_t> expect;
        for (uint32_t t = 0; t < m.triangle_count(); ++t)
            for (uint32_t k : m.triangles[t])
                if (k == v) expect.insert(t);
        std::set<uint32_t> got(m.vertex_triangles.begin() + m.vertex_triangle_begin[v],
                               m.vertex_triangles.begin() + m.vertex_triangle_begin[v + 1]);
        CHECK(got == expect);
    }
    // Every triangle faces +z (counter-clockwise seen from above).
    for (const auto& t : m.triangles) {
        const Vec3f n = (m.vertices_mm[t[1]] - m.vertices_mm[t[0]]).cross(m.vertices_mm[t[2]] - m.vertices_mm[t[0]]);
        CHECK(n.z() > 0.0f);
    }
}
