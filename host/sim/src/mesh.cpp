#include "eyesim/sim/mesh.hpp"

#include <algorithm>
#include <cmath>
#include <unordered_set>

namespace eyesim::sim {

void TriangleMesh::build_adjacency() {
    const size_t nv = vertices_mm.size();
    vertex_triangle_begin.assign(nv + 1, 0);
    for (const auto& t : triangles)
        for (uint32_t v : t) ++vertex_triangle_begin[v + 1];
    for (size_t v = 0; v < nv; ++v) vertex_triangle_begin[v + 1] += vertex_triangle_begin[v];
    vertex_triangles.assign(vertex_triangle_begin[nv], 0);
    std::vector<uint32_t> fill(vertex_triangle_begin.begin(), vertex_triangle_begin.end() - 1);
    for (uint32_t ti = 0; ti < triangles.size(); ++ti)
        for (uint32_t v : triangles[ti]) vertex_triangles[fill[v]++] = ti;

    edges.clear();
    std::unordered_set<uint64_t> seen;
    seen.reserve(triangles.size() * 2);
    for (const auto& t : triangles) {
        for (int k = 0; k < 3; ++k) {
            uint32_t a = t[k], b = t[(k + 1) % 3];
            if (a > b) std::swap(a, b);
            if (seen.insert((uint64_t{a} << 32) | b).second) edges.push_back({a, b});
        }
    }
}

TriangleMesh make_membrane_patch(float width_mm, float height_mm, int nx, int ny) {
    TriangleMesh m;
    m.vertices_mm.reserve(size_t(nx + 1) * size_t(ny + 1));
    for (int j = 0; j <= ny; ++j)
        for (int i = 0; i <= nx; ++i)
            m.vertices_mm.emplace_back(width_mm * (float(i) / float(nx) - 0.5f),
                                       height_mm * (float(j) / float(ny) - 0.5f), 0.0f);
    auto id = [nx](int i, int j) { return uint32_t(j * (nx + 1) + i); };
    m.triangles.reserve(size_t(2 * nx * ny));
    for (int j = 0; j < ny; ++j) {
        for (int i = 0; i < nx; ++i) {
            const uint32_t a = id(i, j), b = id(i + 1, j), c = id(i + 1, j + 1), d = id(i, j + 1);
            if ((i + j) % 2 == 0) {
                m.triangles.push_back({a, b, c});
                m.triangles.push_back({a, c, d});
            } else {
                m.triangles.push_back({a, b, d});
                m.triangles.push_back({b, c, d});
            }
        }
    }
    m.build_adjacency();
    return m;
}

TriangleMesh make_retina_hemisphere(float radius_mm, int rings, int segments) {
    rings = std::max(rings, 1);
    segments = std::max(segments, 3);
    TriangleMesh m;
    m.vertices_mm.reserve(1 + size_t(rings) * size_t(segments));
    m.vertices_mm.emplace_back(0.0f, 0.0f, -radius_mm);
    const double pi = 3.14159265358979323846;
    for (int r = 1; r <= rings; ++r) {
        const double polar = 0.5 * pi * double(r) / double(rings);  // angle from the posterior pole
        for (int s = 0; s < segments; ++s) {
            const double az = 2.0 * pi * double(s) / double(segments);
            m.vertices_mm.emplace_back(float(radius_mm * std::sin(polar) * std::cos(az)),
                                       float(radius_mm * std::sin(polar) * std::sin(az)),
                                       float(-radius_mm * std::cos(polar)));
        }
    }
    auto ring = [segments](int r, int s) { return uint32_t(1 + (r - 1) * segments + (s % segments)); };
    m.triangles.reserve(size_t(segments) * size_t(2 * rings - 1));
    // Seen from the centre (looking towards -z) increasing azimuth runs counter-clockwise: (inner, s, s+1).
    for (int s = 0; s < segments; ++s) m.triangles.push_back({0u, ring(1, s), ring(1, s + 1)});
    for (int r = 1; r < rings; ++r) {
        for (int s = 0; s < segments; ++s) {
            const uint32_t a = ring(r, s), b = ring(r, s + 1), c = ring(r + 1, s + 1), d = ring(r + 1, s);
            m.triangles.push_back({a, d, c});
            m.triangles.push_back({a, c, b});
        }
    }
    m.build_adjacency();
    return m;
}

}  // namespace eyesim::sim
