#pragma once
/// \file
/// Exact instrument–membrane contact with deformation vectors: the colliding membrane triangles (those that
/// touch an instrument triangle or lie inside one of the instrument's closed parts — the exact set), and per
/// colliding triangle ZCOLL's deformation value ZI − ZM along a direction π, from which Eq. 1 node push vectors
/// follow as in ZcollEngine::push.
///
/// The instrument is rigid per closed part: each part's acceleration structure (a uniform grid over its
/// triangles) is built once in the frame the part had then. When the articulated vertices change (forceps
/// opening), each moved part's rigid motion since its grid was built is fitted (Kabsch) and the grid kept: the
/// walk maps the membrane triangle into the grid's frame and widens its box by the fit's residual, so a jaw that
/// turns costs the fit and its triangles' planes, not a new grid; a part that moved other than rigidly (by more
/// than a tenth of a cell) gets a new grid. The pair tests always use the triangles as they are now. Per query the membrane vertices are moved into the instrument frame
/// (one affine transform each, four at a time with SSE2) and culled by outcodes against the instrument's bounds;
/// the few remaining membrane triangles are tested against the grid's instrument triangles (each cell keeps a
/// copy of its triangles' bounds, so the walk reads them in order; coherence hints first: the
/// instrument triangle that hit the same membrane triangle last query or the previous membrane triangle; float
/// plane and edge-plane filters with a conservative margin; Möller's interval test in double, falling back to the predicates
/// of `triangles_intersect` near degeneracy). Containment is grown
/// from the intersecting triangles over the membrane's adjacency (ray parity, one test per inside/outside
/// region of non-intersecting triangles). Deformation: the sample points (colliding triangles' corners and
/// centroids) are binned in the plane ⊥ π (each bin's points copied contiguously); each front-facing instrument
/// triangle over the contact visits the bins its bounds cover and lowers the front-most depth along π of the
/// points inside it, four points at a time.

#include "eyesim/sim/collision/instrument.hpp"
#include "eyesim/sim/collision/raster_backend.hpp"
#include "eyesim/sim/collision/view.hpp"

#include <algorithm>
#include <cstddef>
#include <cmath>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

namespace eyesim::sim::collision {

/// Options of one contact query.
struct ContactOptions {
    bool include_contained = true;        ///< also report membrane triangles inside a closed instrument part
    bool deformation = true;              ///< per-triangle ZI − ZM along π and Eq. 1 node push vectors
    const OrientedBox* within = nullptr;  ///< only membrane triangles whose bounds overlap this box (e.g. V)
    /// Grab rule (forceps closed on tissue, paper §3.3.1): bind the nodes of the colliding triangles and every
    /// node within `grab_radius_mm` of `grab_tip_eye_mm` (also without colliding triangles); no push vectors are
    /// produced then.
    bool grab = false;
    Vec3f grab_tip_eye_mm{0, 0, 0};  ///< see grab
    float grab_radius_mm = 0.3f;     ///< see grab
};

/// One colliding membrane triangle and its deformation value.
struct TriangleContact {
    uint32_t triangle = 0;        ///< membrane triangle index
    /// ZI − ZM at `point_eye_mm` (mm, ≤ 0): the front-most instrument surface on the line through the point
    /// along π, minus the point's own depth, clamped to 0 (ZCOLL's convention: depth grows along π). The
    /// deformation vector is π · depth_delta_mm (towards −π, out of the instrument). 0 when the triangle only
    /// touches the instrument between its sample points.
    float depth_delta_mm = 0.0f;
    /// The membrane point the value was taken at: the deepest of the triangle's three corners and centroid.
    Vec3f point_eye_mm{0, 0, 0};
};

/// Result of a contact query: views into the engine's buffers, valid until its next query.
struct ContactResult {
    bool invalid_input = false;  ///< vertex span size ≠ the engine's membrane, or no instrument (nothing done)
    bool colliding = false;      ///< any colliding triangle
    bool grabbed = false;        ///< the grab rule fired (grabbed_nodes set, no push vectors)
    std::span<const uint32_t> colliding_triangles;  ///< the exact set, ascending
    std::span<const TriangleContact> contacts;      ///< per colliding triangle, same order (when deformation)
    std::span<const uint32_t> pushed_nodes;         ///< nodes with an Eq. 1 push vector, ascending
    std::span<const Vec3f> node_push_eye_mm;        ///< v_i for pushed_nodes[k], eye frame, mm
    std::span<const uint32_t> grabbed_nodes;        ///< nodes bound to the tip (grab rule), ascending
    size_t candidate_triangles = 0;  ///< membrane triangles that reached the grid (diagnostics)
    size_t pair_tests = 0;           ///< triangle pairs that reached the double-precision test
    size_t inside_tests = 0;         ///< point-in-part ray parity tests
    size_t front_triangles = 0;      ///< instrument triangles binned for the deformation values
    bool rebuilt = false;            ///< an instrument grid was (re)built in this query (new instrument, or a part
                                     ///< that moved other than rigidly)
    size_t refit_parts = 0;          ///< parts that moved rigidly in this query: their grids were kept
};

/// The exact contact engine for one membrane topology (any number of instruments; the structure of the last
/// one is kept). Buffers grow to the largest instrument and contact seen; a query on a known instrument
/// allocates nothing.
class ExactContact {
public:
    /// Copies `membrane`'s topology (adjacency built if missing). `max_instrument_triangles` reserves.
    explicit ExactContact(const TriangleMesh& membrane, size_t max_instrument_triangles = 4096);

    /// Contact of a posed instrument (its articulated vertices and pose) with the membrane at
    /// `membrane_vertices_eye_mm` (exactly the topology's vertex count). `pi_eye` (unit) is the deformation
    /// direction (ZCOLL's view direction, e.g. `ZcollView::direction_eye()`).
    const ContactResult& query(std::span<const Vec3f> membrane_vertices_eye_mm, const PosedInstrument& instrument,
                               const Vec3f& pi_eye, const ContactOptions& options = {});

    /// The same for any instrument mesh: vertices in its own frame, pose `instrument.to_eye`, closed parts split
    /// at `part_triangle_begin` (empty: one part).
    const ContactResult& query(std::span<const Vec3f> membrane_vertices_eye_mm, const MeshRef& instrument,
                               std::span<const uint32_t> part_triangle_begin, const Vec3f& pi_eye,
                               const ContactOptions& options = {});

    /// Replaces the membrane topology (after tearing or cutting; allocates). The instrument structure is kept.
    void set_membrane(const TriangleMesh& membrane);

    /// Membrane triangle count of the topology.
    size_t triangle_count() const { return triangles_.size(); }

private:
    struct InstTri {
        Vec3f lo, hi;    // bounds (first: the filters read these, then the plane, then the corners)
        Vec3f n;         // unit normal
        float d;         // n · a
        Vec3f a, b, c;   // instrument frame
    };
    /// One closed part's uniform grid over its triangles (global indices [t0, t1)), in the frame the part had
    /// when the grid was built; `moved`: the part has since moved rigidly, instrument frame → grid frame is
    /// x ↦ rot·x + trans, within `slack_mm`.
    struct PartGrid {
        uint32_t t0 = 0, t1 = 0;
        std::vector<uint32_t> vertices;  // the vertices of the part's triangles, ascending
        std::vector<Vec3f> built_mm;     // where they were when the grid was built
        Vec3f lo{0, 0, 0}, inv_cell{1, 1, 1};
        int dims[3] = {1, 1, 1};
        std::vector<uint32_t> cell_begin, cell_items;
        std::vector<float> cell_box;  // per cell item: its triangle's bounds when built (lo xyz, hi xyz)
        bool moved = false, changed = false;
        Eigen::Matrix3f rot = Eigen::Matrix3f::Identity();
        Vec3f trans{0, 0, 0};
        float slack_mm = 0.0f;
        int cell(float x, int k) const { return std::clamp(int((x - lo[k]) * inv_cell[k]), 0, dims[k] - 1); }
        size_t index(int x, int y, int z) const {
            return (size_t(z) * size_t(dims[1]) + size_t(y)) * size_t(dims[0]) + size_t(x);
        }
        /// Bounds in the grid's frame of `count` instrument-frame points, widened by `margin_mm`, the slack and
        /// the map's rounding (a few ulps of the largest coordinate and of the translation, with room to spare).
        void mapped_box(const Vec3f* p, int count, float margin_mm, float box_lo[3], float box_hi[3]) const {
            float scale = std::max({std::fabs(trans.x()), std::fabs(trans.y()), std::fabs(trans.z())});
            for (int k = 0; k < 3; ++k) {
                box_lo[k] = std::numeric_limits<float>::infinity();
                box_hi[k] = -std::numeric_limits<float>::infinity();
            }
            for (int i = 0; i < count; ++i) {
                const float x = p[i].x(), y = p[i].y(), z = p[i].z();
                scale = std::max({scale, std::fabs(x), std::fabs(y), std::fabs(z)});
                for (int k = 0; k < 3; ++k) {
                    const float q = rot(k, 0) * x + rot(k, 1) * y + rot(k, 2) * z + trans[k];
                    box_lo[k] = std::min(box_lo[k], q);
                    box_hi[k] = std::max(box_hi[k], q);
                }
            }
            const float w = margin_mm + slack_mm + 8e-6f * scale;
            for (int k = 0; k < 3; ++k) {
                box_lo[k] -= w;
                box_hi[k] += w;
            }
        }
    };
    enum class InstrumentChange { None, Vertices, Topology };
    InstrumentChange instrument_change(const MeshRef& instrument, std::span<const uint32_t> parts) const;
    void build_instrument(const MeshRef& instrument, std::span<const uint32_t> parts);
    void move_instrument(const MeshRef& instrument);
    void build_grid(PartGrid& g);
    void set_triangle(size_t t);
    void set_triangles(uint32_t t0, uint32_t t1);  // set_triangle over [t0, t1)
    void update_bounds(bool changed_only);
    bool intersects_any(uint32_t mt);
    bool inside_any_part(const Vec3f& p_local);
    void compute_deformation(std::span<const Vec3f> membrane_vertices_eye_mm, const Eigen::Isometry3f& to_eye,
                             const Vec3f& pi_eye);
    void reset_result();

    // Membrane topology.
    std::vector<std::array<uint32_t, 3>> triangles_;
    std::vector<uint32_t> vt_begin_, vt_items_;
    size_t vertex_count_ = 0;
    // Instrument structure (instrument frame).
    std::vector<Vec3f> inst_vertices_;
    std::vector<std::array<uint32_t, 3>> inst_triangles_;
    std::vector<uint32_t> parts_;
    std::vector<InstTri> tris_;
    std::vector<uint32_t> tri_part_;
    std::vector<Vec3f> part_lo_, part_hi_;
    std::vector<float> part_box_;  // per part: lo x y z 0, hi x y z 0 (one SSE compare each)
    Vec3f lo_{0, 0, 0}, hi_{0, 0, 0};  // the instrument's bounds now
    std::vector<PartGrid> grids_;
    std::vector<uint32_t> cell_fill_;
    bool built_ = false;
    // Per query: membrane in the instrument frame (structure of arrays), outcodes, stamps.
    std::vector<float> lx_, ly_, lz_;
    Vec3f local(uint32_t v) const { return {lx_[v], ly_[v], lz_[v]}; }
    std::vector<uint8_t> code_;
    std::vector<uint32_t> inst_stamp_, tri_stamp_, vert_stamp_, vscan_stamp_;
    std::vector<uint8_t> tri_state_, vert_inside_;
    std::vector<uint32_t> vin_stamp_;  // per vertex: query in which vin_ was set
    std::vector<uint8_t> vin_;         // per vertex: deep inside options.within (its quick accept)
    uint32_t inst_query_ = 0, query_ = 0;
    std::vector<uint32_t> hint_;  // per membrane triangle: the instrument triangle that last intersected it
    uint32_t last_hit_ = 0xFFFFFFFFu;
    std::vector<uint32_t> out_, queue_, merged_;
    // Deformation: bounding spheres and normals of the instrument triangles (structure of arrays, built with
    // the grid), the front-facing triangles over the contact as planes over (u, w) ⊥ π, binned.
    std::vector<float> tcx_, tcy_, tcz_, trad_, tnx_, tny_, tnz_;
    std::vector<uint32_t> kept_;
    // Sample points (colliding triangles' corners, then their centroids) on u, w, π; their bins over (u, w); the
    // points copied into bin order (slots, each bin padded to four), and the smallest front depth per slot.
    std::vector<float> pt_u_, pt_w_, pt_s_;
    std::vector<uint32_t> pt_bin_, vpoint_;  // vpoint_: per membrane vertex, its sample point (this query)
    std::vector<uint32_t> bin_begin_, bin_fill_, sl_point_;  // sl_point_: per point, its slot
    std::vector<float> sl_u_, sl_w_, sl_best_;
    Vec3f pu_{1, 0, 0}, pw_{0, 1, 0}, ps_{0, 0, 1};  // u, w, π in the instrument frame
    std::vector<uint32_t> vdepth_stamp_;
    std::vector<TriangleContact> contacts_;
    std::vector<uint32_t> nodes_, grabbed_;
    std::vector<Vec3f> push_, node_sum_;
    std::vector<float> node_max_;
    std::vector<uint32_t> node_stamp_;
    ContactResult result_;
};

}  // namespace eyesim::sim::collision
