#pragma once
/// \file
/// Exact geometric narrow phase between a membrane and an instrument: which membrane triangles touch the
/// instrument's surface (triangle–triangle tests) or lie inside one of its closed parts. ZCOLL falls back to
/// it where the membrane is not π-convex; tests and benchmarks use it as the reference set.

#include "eyesim/sim/collision/raster_backend.hpp"
#include "eyesim/sim/collision/view.hpp"

#include <span>
#include <vector>

namespace eyesim::sim::collision {

/// Options of an exact query.
struct ExactOptions {
    bool include_contained = true;        ///< also report membrane triangles entirely inside the instrument
    const OrientedBox* within = nullptr;  ///< only membrane triangles whose bounds overlap this box (e.g. V)
    /// Membrane vertex → triangle adjacency (TriangleMesh::vertex_triangle_begin / vertex_triangles). When
    /// given, containment is tested only on triangles reached from intersecting ones through the mesh
    /// (exact unless a whole membrane component lies inside the instrument), which is much cheaper.
    std::span<const uint32_t> vertex_triangle_begin;
    std::span<const uint32_t> vertex_triangles;  ///< see vertex_triangle_begin
};

/// Uniform-grid accelerated exact narrow phase. Buffers grow to the largest query seen, then stay.
class ExactNarrowPhase {
public:
    /// Reserves for meshes of these sizes.
    ExactNarrowPhase(size_t membrane_triangles, size_t instrument_triangles);

    /// Colliding membrane triangles (ascending). `membrane` is in the eye frame (to_eye ignored: identity);
    /// the instrument's `part_triangle_begin` splits its triangles into closed parts (for containment).
    std::span<const uint32_t> colliding_triangles(const MeshRef& membrane, const MeshRef& instrument,
                                                  std::span<const uint32_t> part_triangle_begin,
                                                  const ExactOptions& options);

    /// Number of triangle–triangle tests in the last query (for reports).
    size_t last_pair_tests() const { return pair_tests_; }

private:
    bool inside_part(const Vec3f& p, const MeshRef& instrument, uint32_t t0, uint32_t t1);
    bool candidate(const MeshRef& membrane, uint32_t t, const Vec3f& lo, const Vec3f& hi, const ExactOptions& o) const;
    std::vector<Vec3f> inst_eye_;
    std::vector<uint32_t> mem_stamp_, queue_;
    Vec3f grid_lo_{0, 0, 0}, grid_ext_{1, 1, 1}, inv_cell_{1, 1, 1};
    int dims_[3] = {1, 1, 1};
    std::vector<Vec3f> tri_lo_, tri_hi_, part_lo_, part_hi_;
    std::vector<uint32_t> cell_begin_, cell_items_, cell_fill_;
    std::vector<uint32_t> stamp_;
    std::vector<uint32_t> out_;
    uint32_t query_ = 0, mem_query_ = 0;
    size_t pair_tests_ = 0;
};

}  // namespace eyesim::sim::collision
