#include "eyesim/sim/mesh.hpp"

#include <Eigen/Geometry>

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

namespace {

/// Tangent basis at `c` (unit) with e1 × e2 = −c (so grid triangles counter-clockwise in (e1, e2) face inwards).
void tangent_basis(const Vec3f& c, Vec3f& e1, Vec3f& e2) {
    const Vec3f a = std::fabs(c.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY();
    e1 = (a - a.dot(c) * c).normalized();
    e2 = e1.cross(c);  // e1 × (e1 × c) = −c
}

/// Exponential map of the sphere: geodesic offset (u, v) in the tangent basis at c → point on the sphere.
Vec3f wrap(float r, const Vec3f& c, const Vec3f& e1, const Vec3f& e2, float u, float v) {
    const float rho = std::sqrt(u * u + v * v);
    if (rho < 1e-9f) return r * c;
    const float a = rho / r;
    return r * (std::cos(a) * c + std::sin(a) * (u * e1 + v * e2) / rho);
}

}  // namespace

float MembraneOutline::radius_at(float theta) const {
    // splitmix64 from the seed: amplitudes and phases of harmonics 2..5.
    uint64_t s = seed * 0x9E3779B97F4A7C15ull + 0x632BE59BD9B4E019ull;
    auto next = [&s] {
        uint64_t z = (s += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return double((z ^ (z >> 31)) >> 11) * 0x1.0p-53;
    };
    double amp[4], phase[4], sum = 0.0;
    for (int k = 0; k < 4; ++k) {
        amp[k] = 0.2 + next();
        phase[k] = 2.0 * 3.14159265358979323846 * next();
        sum += amp[k];
    }
    double lobes = 0.0;
    for (int k = 0; k < 4; ++k) lobes += amp[k] / sum * std::cos(double(k + 2) * theta + phase[k]);
    return float(mean_radius_mm * (1.0 + irregularity * lobes));
}

Vec3f point_on_retina(float surface_radius_mm, const Vec3f& centre_dir, float rho_mm, float theta) {
    Vec3f e1, e2;
    const Vec3f c = centre_dir.normalized();
    tangent_basis(c, e1, e2);
    return wrap(surface_radius_mm, c, e1, e2, rho_mm * std::cos(theta), rho_mm * std::sin(theta));
}

TriangleMesh make_epiretinal_membrane(float surface_radius_mm, const Vec3f& centre_dir, const MembraneOutline& outline,
                                      int triangles) {
    const Vec3f c = centre_dir.normalized();
    Vec3f e1, e2;
    tangent_basis(c, e1, e2);
    const float half = outline.mean_radius_mm * (1.0f + std::fabs(outline.irregularity)) * 1.02f;
    auto inside = [&](float u, float v) { return std::sqrt(u * u + v * v) <= outline.radius_at(std::atan2(v, u)); };
    // Grid cells n × n over [−half, half]²: about π·mean²·(1 + irr²/2) / (2·half)² of its 2n² triangles are kept.
    const double frac = 3.14159265358979323846 * outline.mean_radius_mm * outline.mean_radius_mm *
                        (1.0 + 0.5 * outline.irregularity * outline.irregularity) / (4.0 * half * half);
    const int n = std::max(2, int(std::lround(std::sqrt(std::max(triangles, 2) / (2.0 * frac)))));
    const float step = 2.0f * half / float(n);
    std::vector<int32_t> remap(size_t(n + 1) * size_t(n + 1), -1);
    auto id = [n](int i, int j) { return size_t(j) * size_t(n + 1) + size_t(i); };
    TriangleMesh m;
    auto vertex = [&](int i, int j) {
        int32_t& r = remap[id(i, j)];
        if (r < 0) {
            r = int32_t(m.vertices_mm.size());
            m.vertices_mm.push_back(wrap(surface_radius_mm, c, e1, e2, -half + step * float(i), -half + step * float(j)));
        }
        return uint32_t(r);
    };
    auto keep = [&](int i0, int j0, int i1, int j1, int i2, int j2) {
        const float u = -half + step * float(i0 + i1 + i2) / 3.0f, v = -half + step * float(j0 + j1 + j2) / 3.0f;
        if (inside(u, v)) m.triangles.push_back({vertex(i0, j0), vertex(i1, j1), vertex(i2, j2)});
    };
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            if ((i + j) % 2 == 0) {
                keep(i, j, i + 1, j, i + 1, j + 1);
                keep(i, j, i + 1, j + 1, i, j + 1);
            } else {
                keep(i, j, i + 1, j, i, j + 1);
                keep(i + 1, j, i + 1, j + 1, i, j + 1);
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
