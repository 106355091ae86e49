#pragma once
/// \file
/// Triangle meshes in contiguous arrays, shared by collision detection and tissue simulation.
/// All coordinates are millimetres in the frame the owner states (membranes and instruments: the eye frame).

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <vector>

namespace eyesim::sim {

using Vec3f = Eigen::Vector3f;

/// Indexed triangle mesh. Vertices and triangles are contiguous; adjacency is derived on demand.
struct TriangleMesh {
    std::vector<Vec3f> vertices_mm;                   ///< vertex positions, mm
    std::vector<std::array<uint32_t, 3>> triangles;   ///< counter-clockwise seen from the front (+normal) side

    /// Vertex → adjacent triangles in compressed-row form: triangles of vertex v are
    /// vertex_triangles[vertex_triangle_begin[v] .. vertex_triangle_begin[v+1]).
    std::vector<uint32_t> vertex_triangle_begin;
    std::vector<uint32_t> vertex_triangles;

    /// Unique undirected edges (a < b), each listed once, in first-seen order.
    std::vector<std::array<uint32_t, 2>> edges;

    size_t vertex_count() const { return vertices_mm.size(); }
    size_t triangle_count() const { return triangles.size(); }

    /// Rebuilds vertex_triangle_* and edges from `triangles`. Call after any topology change.
    void build_adjacency();
};

/// Regular triangulated rectangular patch in the z = 0 plane, centred on the origin: nx × ny quads, each split
/// into two triangles (alternating diagonals so the mesh has no preferred shear direction), normal +z.
/// 2·nx·ny triangles: 14×14 → 392 (≈400), 22×23 → 1012 (≈1k), 39×39 → 3042 (≈3k).
TriangleMesh make_membrane_patch(float width_mm, float height_mm, int nx, int ny);

/// The paper's Table 3 membrane sizes: nx, ny for ≈400, ≈1k and ≈3k triangles.
struct PatchSize { int nx, ny; };
inline constexpr PatchSize kPatch400{14, 14};
inline constexpr PatchSize kPatch1k{22, 23};
inline constexpr PatchSize kPatch3k{39, 39};

/// Eye frame convention used by every generator here: eye centre at the origin, +z along the optical axis
/// towards the cornea; the retina lines the posterior inner wall (z < 0).
inline constexpr float kEyeRadius_mm = 12.0f;

/// Irregular outline of an epiretinal membrane: geodesic radius r(θ) = mean·(1 + irregularity·Σ a_k cos(kθ + φ_k))
/// over harmonics k = 2..5 with Σ a_k = 1, so r stays within mean·(1 ± irregularity). Amplitudes and phases
/// come from `seed` (deterministic on every platform).
struct MembraneOutline {
    float mean_radius_mm = 2.5f;  ///< mean geodesic radius on the retina
    float irregularity = 0.25f;   ///< relative depth of the outline's lobes, 0 = circle, ≤ 0.5
    uint32_t seed = 1;            ///< shape of the lobes
    /// Radius at polar angle θ (rad) about the centre, measured from the tangent basis of make_epiretinal_membrane.
    float radius_at(float theta) const;
};

/// Epiretinal membrane lying on the retina's inner surface: the triangles of a regular grid (in geodesic
/// coordinates about `centre_dir`, the unit direction of its centre from the eye centre) whose centroids fall
/// inside `outline`, wrapped onto the sphere of `surface_radius_mm` about the origin. The grid is sized so that
/// about `triangles` are kept. Normals point inwards (towards the eye centre); the boundary edges are its rim.
/// Tangent basis at the centre: e1 is +x (+y when centre_dir is near ±x) made perpendicular to centre_dir, and
/// e2 = e1 × centre_dir, so that e1 × e2 = −centre_dir.
TriangleMesh make_epiretinal_membrane(float surface_radius_mm, const Vec3f& centre_dir, const MembraneOutline& outline,
                                      int triangles);

/// Point on the sphere of `surface_radius_mm` at geodesic polar coordinates (rho_mm, theta) about `centre_dir`,
/// in the tangent basis of make_epiretinal_membrane.
Vec3f point_on_retina(float surface_radius_mm, const Vec3f& centre_dir, float rho_mm, float theta);

/// Posterior retina hemisphere: the inner eye sphere of radius `radius_mm` (centre at the origin) for z ≤ 0,
/// from the posterior pole (0, 0, -radius_mm) up to the equator z = 0. `rings` latitude bands (≥ 1) and
/// `segments` longitude sectors (≥ 3): vertex 0 is the pole, then `rings` rings of `segments` vertices each.
/// segments·(2·rings − 1) triangles, e.g. rings 20, segments 64 → 2496. Triangles are counter-clockwise seen
/// from the eye centre, so normals point inwards (towards the instruments). The equator ring is the open rim.
TriangleMesh make_retina_hemisphere(float radius_mm, int rings, int segments);

}  // namespace eyesim::sim
