#pragma once
/// \file
/// The mass-spring mesh: node data in structure-of-arrays form, a hot spring array, and the cold topology
/// bookkeeping (triangles, spring ↔ triangle links, node → spring incidence) that tearing and cutting update.

#include "eyesim/sim/mesh.hpp"
#include "eyesim/sim/tissue/node_state.hpp"
#include "eyesim/sim/tissue/spring.hpp"
#include "eyesim/sim/tissue/spring_schedule.hpp"
#include "eyesim/sim/tissue/tissue_params.hpp"

#include <array>
#include <cstdint>
#include <span>
#include <vector>

namespace eyesim::sim::tissue {

/// Result of a topology change.
struct TopologyDelta {
    uint32_t springs_removed = 0;     ///< springs deleted (torn, cut, or orphaned)
    uint32_t triangles_removed = 0;   ///< triangles that lost an edge spring or a node
    uint32_t nodes_removed = 0;       ///< nodes cut or left without any triangle
    float area_removed_mm2 = 0.0f;    ///< rest area of the removed triangles
};

/// Nodes and springs. Node arrays are parallel (index = TriangleMesh vertex index) and never reordered;
/// springs are kept dense (deleted springs are compacted away in order, so stepping stays deterministic).
///
/// Consistency rule kept by every topology change (checked by `check_consistency`):
/// - a triangle lives only while its three nodes live and its three edge springs live;
/// - an edge spring lives only while one of its triangles lives, a bending spring while both live;
/// - a node that had triangles is removed when none of its triangles lives.
struct MassSpringSystem {
    // ---- hot node data (structure of arrays; the vectors padded to 16 bytes, see padded_vec3.hpp) ----
    PaddedVec3Array x_mm;             ///< positions, mm
    PaddedVec3Array v_mm_per_s;       ///< velocities, mm/s
    PaddedVec3Array f_nN;             ///< total force of the current step, nN
    PaddedVec3Array ext_nN;           ///< external force of the step (injection, suction), nN
    std::vector<float> w_per_mg;      ///< effective inverse mass: 1/m for dynamic nodes, 0 for kinematic ones
    std::vector<float> inv_mass_per_mg;  ///< true inverse mass, used by the tearing rule for grabbed nodes too
    std::vector<float> mass_mg;       ///< node mass (0 for massless nodes), for body forces without a division
    std::vector<NodeState> state;     ///< node states

    // ---- hot springs ----
    /// Live springs, dense. Change them only through this class (construction, `remove`), or call
    /// `rebuild_incidence` afterwards: the force kernel reads its own copy (`schedule`).
    std::vector<Spring> springs;
    SpringSchedule schedule;          ///< springs in force-kernel order (see spring_schedule.hpp)

    // ---- cold topology ----
    std::vector<SpringInfo> spring_info;              ///< parallel to springs
    std::vector<std::array<uint32_t, 3>> triangles;   ///< all triangles ever built (indices stay valid)
    std::vector<std::array<uint32_t, 3>> triangle_springs;  ///< edge spring of each triangle edge
    std::vector<uint8_t> triangle_alive;              ///< 1 while the triangle lives
    std::vector<float> triangle_rest_area_mm2;        ///< rest area per triangle
    std::vector<uint32_t> node_spring_begin;          ///< node → springs incidence (compressed rows)
    std::vector<uint32_t> node_springs;               ///< spring indices, per node in increasing order
    std::vector<uint8_t> node_had_triangles;          ///< 1 if the node belonged to a triangle at build time
    uint64_t topology_version = 0;                    ///< increments on every topology change

    /// Builds nodes (rest = mesh positions, zero velocity, all kFree), edge springs and, if the material asks,
    /// bending springs from a triangle mesh. Node mass = density × ⅓ of the adjacent triangles' area.
    static MassSpringSystem from_mesh(const TriangleMesh& mesh, const MaterialParams& material);

    /// Builds a system without triangles (chains, single springs). All nodes kFree.
    static MassSpringSystem from_springs(std::span<const Vec3f> x_mm, std::span<const float> mass_mg,
                                         std::span<const Spring> springs);

    /// Number of nodes.
    size_t node_count() const { return x_mm.size(); }
    /// Number of live springs.
    size_t spring_count() const { return springs.size(); }
    /// Number of live triangles.
    size_t live_triangle_count() const;

    /// Sets a node's state (and its effective inverse mass). Velocity of nodes made kinematic is zeroed.
    void set_state(uint32_t node, NodeState s);

    /// f_nN = ext + m·g − drag·m·v + spring forces, at the current x and v (the scheduled vector kernel;
    /// `accumulate_spring_forces` is the plain reference it is tested against).
    void compute_forces(const TissueParams& params);

    /// Deletes the given springs and the given nodes (spans may be empty), then applies the consistency rule,
    /// compacts springs in order and rebuilds incidence. Allocation-free once capacities are reached.
    TopologyDelta remove(std::span<const uint32_t> spring_ids, std::span<const uint32_t> node_ids);

    /// Copies positions into `mesh.vertices_mm` (same vertex indices); when `rebuild_topology` is set, also
    /// replaces `mesh.triangles` by the live triangles and rebuilds its adjacency.
    void write_to(TriangleMesh& mesh, bool rebuild_topology) const;

    /// True when the consistency rule holds and every index is in range. `why` (optional) names the first fault.
    bool check_consistency(const char** why = nullptr) const;

    /// Kinetic energy ½ Σ m v² over dynamic nodes, nJ-scale units (mg·mm²/s² = nN·mm).
    double kinetic_energy() const;
    /// Elastic energy ½ Σ k (|d| − L)², nN·mm.
    double elastic_energy() const;

    /// Rebuilds node → spring incidence and the force schedule from `springs` (after construction or
    /// compaction).
    void rebuild_incidence();

private:
    std::vector<uint8_t> scratch_spring_dead_;  // reused by remove()
    std::vector<uint32_t> scratch_remap_;
};

/// Adds the spring forces of `springs` at (x, v) to f (f is not cleared), one spring at a time in array order:
/// the plain reference for the scheduled kernel that `compute_forces` runs.
void accumulate_spring_forces(std::span<const Spring> springs, const PaddedVec3Array& x_mm,
                              const PaddedVec3Array& v_mm_per_s, PaddedVec3Array& f_nN);

}  // namespace eyesim::sim::tissue
