#pragma once
/// \file
/// A simulated tissue (epiretinal membrane or retina) and its per-frame interface to instruments: the object a
/// host frame loop owns. Build it from a TriangleMesh, set rim / choroid nodes, feed tool inputs each frame,
/// `step`, then `write_to` the mesh for collision and rendering and read `events` and `damage`.

#include "eyesim/sim/mesh.hpp"
#include "eyesim/sim/tissue/integrator.hpp"
#include "eyesim/sim/tissue/mass_spring.hpp"
#include "eyesim/sim/tissue/node_push.hpp"
#include "eyesim/sim/tissue/tissue_events.hpp"
#include "eyesim/sim/tissue/tissue_params.hpp"

#include <memory>
#include <span>
#include <vector>

namespace eyesim::sim::tissue {

/// Forceps jaws (paper §3.3.1). While open nothing is bound; on closing, dynamic nodes within `grab_radius_mm` of
/// the tip are bound to it and follow its translation; on opening they are released.
struct ForcepsInput {
    Vec3f tip_mm = Vec3f::Zero();  ///< tip position, tissue frame
    bool closed = false;           ///< jaws closed below the grab threshold angle
    float grab_radius_mm = 0.2f;   ///< capture radius at closing
};

/// Vitrector suction: every dynamic node inside the cone (apex at the port, axis pointing away from the
/// instrument into the tissue) is pulled toward the apex with |f| = strength / max(d, suction_min_distance).
struct SuctionInput {
    bool on = false;                   ///< pedal: suction active
    Vec3f apex_mm = Vec3f::Zero();     ///< cutter port
    Vec3f axis = Vec3f::UnitZ();       ///< cone axis (need not be unit)
    float half_angle_deg = 30.0f;      ///< cone half-angle
    float range_mm = 2.0f;             ///< nodes farther than this feel nothing
    float strength_nN_mm = 1.0f;       ///< force × distance
};

/// Vitrector cutting: while on, every node within `radius_mm` of `centre_mm` is removed with its springs and
/// triangles.
struct CutterInput {
    bool on = false;                 ///< pedal: cutting active
    Vec3f centre_mm = Vec3f::Zero(); ///< cutter port
    float radius_mm = 0.1f;          ///< reach
};

/// Injection needle (retina relocation, paper §4.5 (2)). While inserted at x0: if p > detach_pressure_min,
/// attached nodes within d = detach_radius_mm_per_pressure·p of x0 detach and get a constant force of magnitude
/// injection_force_nN_per_pressure·p along x_i − x0. The needle velocity projected on the retina's tangent plane
/// at x0 (normal: x0 − container centre) above tear_warning_speed raises a tear warning.
struct NeedleInput {
    bool inserted = false;                       ///< needle tip has penetrated the retina
    Vec3f tip_mm = Vec3f::Zero();                ///< x0
    Vec3f velocity_mm_per_s = Vec3f::Zero();     ///< needle tip velocity
    float pressure = 0.0f;                       ///< injection pressure (pedal), the unit of TissueParams
};

/// Damage counters since construction.
struct TissueDamage {
    uint64_t springs_torn = 0;        ///< springs deleted by the tearing rule
    uint64_t triangles_torn = 0;      ///< triangles lost because one of their edges tore
    float torn_area_mm2 = 0.0f;       ///< rest area of those triangles
    uint64_t nodes_cut = 0;           ///< nodes removed by the cutter (or left without triangles by it)
    uint64_t triangles_cut = 0;       ///< triangles removed by the cutter
    float removed_area_mm2 = 0.0f;    ///< rest area removed by the cutter
    uint64_t nodes_detached = 0;      ///< retina nodes detached by injections
};

/// A tissue: mass-spring system + integrator + tool state.
class Tissue {
public:
    /// Builds from a mesh; all nodes start kFree and at rest.
    Tissue(const TriangleMesh& mesh, const MaterialParams& material, const TissueParams& params,
           IntegratorKind integrator);
    /// Wraps an already built system (chains, tests).
    Tissue(MassSpringSystem system, const TissueParams& params, IntegratorKind integrator);

    /// Sets the state of given nodes (e.g. kFixed for a rim).
    void set_node_state(std::span<const uint32_t> nodes, NodeState s);
    /// Fixes every boundary node of the mesh (nodes on an edge with a single triangle): the membrane rim.
    /// Returns how many were fixed.
    size_t fix_rim();
    /// Marks every node kAttached (retina on the choroid).
    void attach_all();

    /// Replaces the integrator (scene choice).
    void set_integrator(IntegratorKind kind);
    /// Current integrator.
    IntegratorKind integrator() const { return integrator_->kind(); }
    /// Mutable run-time rules.
    TissueParams& params() { return params_; }
    /// Run-time rules.
    const TissueParams& params() const { return params_; }

    /// Sets a constant external force on a node (a load; injections set theirs the same way). The per-step
    /// external force `system().ext_nN` is this constant force plus suction; write loads here, not there.
    void set_constant_force(uint32_t node, const Vec3f& f_nN);

    /// Adds each push vector to its node's position now (dynamic nodes only; others are ignored). Call with the
    /// collision result of this frame, before `step`.
    void push(std::span<const NodePush> pushes);
    /// Forceps tip and jaws for this frame (grabbed nodes move from last frame's tip to this one across the
    /// substeps of the next `step`).
    void set_forceps(const ForcepsInput& in);
    /// Vitrector suction for this frame.
    void set_suction(const SuctionInput& in) { suction_ = in; }
    /// Vitrector cutter for this frame (applied at the start of the next `step`).
    void set_cutter(const CutterInput& in) { cutter_ = in; }
    /// Injection needle for this frame (applied at the start of the next `step`).
    void set_needle(const NeedleInput& in) { needle_ = in; }

    /// Advances by frame_dt_s in `substeps` equal substeps. Clears and refills `events()`.
    void step(float frame_dt_s, int substeps);

    /// Writes positions (and, if the topology changed since the last call for this mesh, the live triangles and
    /// adjacency) into `mesh`. Vertex indices never change. Returns true if the topology was rewritten.
    bool write_to(TriangleMesh& mesh);

    /// Nodes bound to the closed forceps now.
    size_t grabbed_count() const { return grabbed_.size(); }
    /// Events of the last `step` call.
    const TissueEventList& events() const { return events_; }
    /// Damage counters since construction.
    const TissueDamage& damage() const { return damage_; }
    /// The mass-spring system (read positions, states, energies).
    const MassSpringSystem& system() const { return sys_; }
    /// Mutable access, for tests and scene set-up (initial velocities, displacements).
    MassSpringSystem& system_mut() { return sys_; }

private:
    void substep(float dt_s, float frame_fraction_end);
    void apply_tearing_rule();
    void apply_cutter();
    void apply_needle();

    MassSpringSystem sys_;
    TissueParams params_;
    std::unique_ptr<Integrator> integrator_;
    TissueEventList events_;
    TissueDamage damage_;

    ForcepsInput forceps_{};
    Vec3f tip_prev_mm_ = Vec3f::Zero();
    Vec3f tip_now_mm_ = Vec3f::Zero();
    std::vector<uint32_t> grabbed_;          // bound nodes
    std::vector<NodeState> grabbed_prev_;    // their state before grabbing
    std::vector<Vec3f> grabbed_offset_mm_;   // node − tip at closing
    SuctionInput suction_{};
    CutterInput cutter_{};
    NeedleInput needle_{};

    std::vector<Vec3f> injection_nN_;        // constant injection force per node (ext = injection + suction)
    bool ext_has_suction_ = false;
    std::vector<uint32_t> fixed_nodes_;      // rim nodes watched for lift-off
    bool tool_initialised_ = false;

    std::vector<uint32_t> scratch_springs_;  // tearing / cutting work lists, capacity kept
    std::vector<uint32_t> scratch_nodes_;
    uint64_t written_topology_version_ = ~uint64_t{0};
};

}  // namespace eyesim::sim::tissue
