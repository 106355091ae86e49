#pragma once
/// \file
/// ZCOLL: image-based collision detection between an instrument and a deforming membrane (paper §3.3–3.3.2),
/// with π-convexity detection and an exact fallback (beyond the paper).
///
/// Per frame: the membrane's vertex positions change, its topology does not. One engine per membrane; every
/// buffer is sized in the constructor, queries do not allocate. Results are views into the engine's buffers,
/// valid until its next query.

#include "eyesim/sim/collision/exact.hpp"
#include "eyesim/sim/collision/instrument.hpp"
#include "eyesim/sim/collision/raster_backend.hpp"
#include "eyesim/sim/collision/view.hpp"

#include <memory>
#include <span>
#include <vector>

namespace eyesim::sim::collision {

/// Settings of a ZCOLL engine.
struct ZcollConfig {
    int resolution_px = 32;                       ///< R of the viewport (buffers are R×R)
    FeatureKind features = FeatureKind::Triangle; ///< colour ids per triangle (paper) or per vertex
    bool check_pi_convexity = true;  ///< count membrane layers per pixel; >1 → not π-convex in V
    bool exact_fallback = true;      ///< when not π-convex: colliding triangles from the exact narrow phase
    float grab_below_deg = 8.0f;     ///< forceps grab rule: jaws closed below this opening bind nodes to the tip
    float grab_radius_mm = 0.3f;     ///< … and every membrane node this close to the tip is bound as well
    float suction_gain_mm2 = 1.0e-2f;  ///< suction force = gain / distance (force units · mm)
    float suction_min_distance_mm = 0.05f;  ///< distances are clamped to this (no singularity at the port)
};

/// One colliding pixel: the feature seen there and its deformation value ZI − ZM (≤ 0, mm along π).
struct ZcollFeature {
    uint32_t id;            ///< triangle or vertex index of the membrane
    uint16_t x_px, y_px;    ///< pixel
    float depth_delta_mm;   ///< ZI − ZM: the deformation vector is π · depth_delta_mm (towards the camera)
};

/// Result of a ZCOLL query (views into the engine's buffers).
struct ZcollResult {
    bool invalid_input = false;   ///< the vertex span does not match the engine's membrane (nothing done)
    bool gated_out = false;       ///< broad phase: V does not touch the membrane's bounds, nothing rendered
    bool colliding = false;       ///< any colliding feature
    bool pi_convex = true;        ///< false when some pixel of V saw ≥ 2 membrane layers
    uint32_t multi_layer_pixels = 0;  ///< how many pixels did
    bool fallback_used = false;   ///< colliding_triangles come from the exact narrow phase
    bool grabbed = false;         ///< forceps grab rule fired (push vectors not produced)
    std::span<const ZcollFeature> features;        ///< per colliding pixel (push mode)
    std::span<const uint32_t> colliding_triangles; ///< unique, ascending
    std::span<const uint32_t> pushed_nodes;        ///< nodes with a push vector (Eq. 1), ascending
    std::span<const Vec3f> node_push_eye_mm;       ///< v_i for pushed_nodes[k], eye frame, mm
    std::span<const uint32_t> grabbed_nodes;       ///< nodes bound to the tip (grab rule), ascending
    std::span<const uint32_t> suction_nodes;       ///< nodes inside the suction cone
    std::span<const Vec3f> suction_force_eye;      ///< force on suction_nodes[k], towards the port, eye frame
};

/// Eq. 1: v = max_{d∈D} |d| · Σd / |Σd|. Returns zero for an empty set or a vanishing sum.
Vec3f eq1_push_vector(std::span<const Vec3f> deformation_vectors);

/// Eq. 1 per node from what was gathered over each node's deformation vectors (`node_sum[v]` = Σd, `node_max[v]`
/// = max |d|): sorts `nodes` and appends, in that order, push = max |d| · Σd / |Σd| (zero for a vanishing sum).
void eq1_node_pushes(std::vector<uint32_t>& nodes, std::span<const Vec3f> node_sum, std::span<const float> node_max,
                     std::vector<Vec3f>& push);

/// The ZCOLL engine for one membrane topology.
class ZcollEngine {
public:
    /// `membrane` gives the topology (triangles, adjacency) and the vertex count, copied into the engine;
    /// positions come per query (a span of exactly that many vertices, else `invalid_input`).
    /// `backend` renders (null: a CpuRasterBackend). `max_instrument_triangles` sizes the exact fallback.
    ZcollEngine(const TriangleMesh& membrane, const ZcollConfig& config,
                std::unique_ptr<ZcollRasterBackend> backend = nullptr, size_t max_instrument_triangles = 4096);
    ~ZcollEngine();

    /// Push mode (forceps, pick, …): colliding features, deformation vectors, Eq. 1 node vectors, grab rule
    /// (when `instrument` is a forceps closed below `grab_below_deg`), π-convexity check and fallback.
    const ZcollResult& push(std::span<const Vec3f> membrane_vertices_eye_mm, const PosedInstrument& instrument,
                            const ZcollView& view);

    /// Boolean mode: is the instrument colliding with the membrane in V? No deformation vectors, no read-back.
    bool collides(std::span<const Vec3f> membrane_vertices_eye_mm, const PosedInstrument& instrument,
                  const ZcollView& view);

    /// Vitrector suction: central projection from the port, colour buffer only; nodes inside the cone get a
    /// force ∝ 1/distance to `suction_tip_eye_mm`, pointing at it.
    const ZcollResult& suction(std::span<const Vec3f> membrane_vertices_eye_mm, const ZcollView& cone_view,
                               const Vec3f& suction_tip_eye_mm);

    const ZcollConfig& config() const { return config_; }       ///< settings
    ZcollRasterBackend& backend() { return *backend_; }          ///< the render back-end
    const RasterBuffers& buffers() const { return buffers_; }    ///< last read-back (for tests, pictures)
    /// Broad phase: does V overlap the bounds of these membrane vertices?
    bool volume_touches(std::span<const Vec3f> membrane_vertices_eye_mm, const ZcollView& view) const;

private:
    void reset_result();
    void collect_features(const ZcollView& view, bool only_single_layer);
    void compute_push_vectors(const ZcollView& view);
    void collect_grab(std::span<const Vec3f> membrane_vertices_eye_mm, const PosedInstrument& instrument);
    void unique_triangles_from_features();

    TriangleMesh topology_;  // a copy: the caller's mesh may move or be reassigned
    ZcollConfig config_;
    std::unique_ptr<ZcollRasterBackend> backend_;
    RasterBuffers buffers_;
    ExactNarrowPhase exact_;
    ZcollResult result_;
    // Work buffers (sized once).
    std::vector<ZcollFeature> features_;
    std::vector<uint32_t> triangles_, nodes_, grabbed_, suction_nodes_;
    std::vector<Vec3f> push_, suction_force_;
    std::vector<uint32_t> tri_stamp_, node_stamp_;
    std::vector<Vec3f> tri_sum_, node_sum_;
    std::vector<float> tri_max_, node_max_;
    uint32_t stamp_ = 0;
};

}  // namespace eyesim::sim::collision
