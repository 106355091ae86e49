#include "eyesim/sim/tissue/retina_mesh.hpp"

#include <algorithm>
#include <cmath>

namespace eyesim::sim::tissue {

TriangleMesh make_retina_hemisphere(float radius_mm, int rings, int segments) {
    rings = std::max(rings, 1);
    segments = std::max(segments, 3);
    TriangleMesh m;
    const double pi = 3.14159265358979323846;
    m.vertices_mm.emplace_back(0.0f, 0.0f, -radius_mm);  // posterior pole
    for (int k = 1; k <= rings; ++k) {
        const double theta = 0.5 * pi * double(k) / double(rings);  // polar angle from the pole
        for (int s = 0; s < segments; ++s) {
            const double phi = 2.0 * pi * double(s) / double(segments);
            m.vertices_mm.emplace_back(float(radius_mm * std::sin(theta) * std::cos(phi)),
                                       float(radius_mm * std::sin(theta) * std::sin(phi)),
                                       float(-radius_mm * std::cos(theta)));
        }
    }
    auto id = [segments](int ring, int s) { return uint32_t(1 + (ring - 1) * segments + (s % segments)); };
    // Winding: seen from the eye centre (inside), counter-clockwise, so normals point inward.
    for (int s = 0; s < segments; ++s) m.triangles.push_back({0u, id(1, s), id(1, s + 1)});
    for (int k = 1; k < rings; ++k)
        for (int s = 0; s < segments; ++s) {
            const uint32_t a = id(k, s), b = id(k + 1, s), c = id(k + 1, s + 1), d = id(k, s + 1);
            m.triangles.push_back({a, b, c});
            m.triangles.push_back({a, c, d});
        }
    m.build_adjacency();
    return m;
}

}  // namespace eyesim::sim::tissue
