#pragma once
/// \file
/// The render back-end interface of ZCOLL (paper §3.3, steps 3–10) and the CPU rasteriser that implements it.
///
/// Rasterisation rules (both back-ends): a pixel is covered when its sample point (i + ½, j + ½) lies inside
/// the projected triangle; vertices are snapped to 1/256 pixel; samples exactly on an edge belong to the
/// triangle only for top and left edges (so triangles sharing an edge never both cover a sample); no face
/// culling; fragments with depth outside [near, far] are discarded (parallel views) — the same rules as
/// OpenGL ES with 8 sub-pixel bits. Depth compare: membrane LESS (first drawn wins a tie), instrument
/// LEQUAL against the membrane depth, as in the paper.

#include "eyesim/sim/collision/view.hpp"

#include <array>
#include <cstdint>
#include <limits>
#include <span>
#include <string_view>
#include <vector>

namespace eyesim::sim::collision {

/// What a colour id names: a membrane triangle, or a membrane vertex (the corner whose barycentric weight is
/// largest at the pixel, i.e. the vertex Voronoi region inside the triangle).
enum class FeatureKind : uint8_t { Triangle, Vertex };

/// A mesh to render: vertices in its own frame, triangles, and the pose own frame → eye.
struct MeshRef {
    std::span<const Vec3f> vertices_mm;                   ///< positions in the mesh's frame
    std::span<const std::array<uint32_t, 3>> triangles;   ///< vertex indices
    Eigen::Isometry3f to_eye = Eigen::Isometry3f::Identity();  ///< mesh frame → eye frame
};

/// Depth value of an empty pixel.
inline constexpr float kEmptyDepth = std::numeric_limits<float>::infinity();

/// The read-back buffers of one ZCOLL run, R×R each, row 0 at the bottom. Sized once by `resize`.
struct RasterBuffers {
    int resolution_px = 0;             ///< R
    std::vector<float> zm_mm;          ///< membrane depth ZM (kEmptyDepth where no membrane)
    std::vector<float> zi_mm;          ///< depth after rendering the instrument with LEQUAL: ZI ≤ ZM
    std::vector<uint32_t> cm;          ///< membrane colour buffer CM: feature id + 1, 0 = background
    std::vector<uint8_t> layers;       ///< membrane fragments per pixel inside V (saturating), if counted
    uint32_t multi_layer_pixels = 0;   ///< pixels with ≥ 2 membrane layers (not π-convex there)
    /// Every pixel outside columns [x0, x1] × rows [y0, y1] is background (cm 0, depths kEmptyDepth,
    /// layers 0): analysis may skip it. x1 < x0 means no membrane pixel at all.
    int x0 = 0, y0 = 0, x1 = -1, y1 = -1;

    /// Allocates for resolution R (call outside the frame loop).
    void resize(int resolution_px);
};

/// Which passes a run needs.
struct RasterRequest {
    FeatureKind ids = FeatureKind::Triangle;  ///< what CM encodes
    bool count_layers = false;                ///< fill `layers` and `multi_layer_pixels`
    bool instrument = true;                   ///< render the instrument and read ZI back (push mode)
};

/// A ZCOLL render back-end: renders the membrane (depth + colour ids) and the instrument into an R×R
/// viewport and reads the buffers back. Implementations: CpuRasterBackend here, the EGL/GLES3 back-end in
/// eyesim_render.
class ZcollRasterBackend {
public:
    virtual ~ZcollRasterBackend() = default;
    /// Short name for reports ("cpu", "egl").
    virtual std::string_view name() const = 0;
    /// Paper steps 3–10. `instrument` may be null when `req.instrument` is false (suction mode).
    virtual void render(const MeshRef& membrane, const MeshRef* instrument, const ZcollView& view,
                        const RasterRequest& req, RasterBuffers& out) = 0;
    /// Boolean ZCOLL: is any instrument sample in front of the membrane (ZI < ZM where CM ≠ 0)? Needs no
    /// deformation vectors and reads back no buffer (CPU: stops at the first such sample; GPU: occlusion query).
    virtual bool any_penetration(const MeshRef& membrane, const MeshRef& instrument, const ZcollView& view) = 0;
};

/// The default back-end: a scan-converting CPU rasteriser (fixed-point edge functions, top-left fill rule,
/// bounding-box traversal of the tiny viewport). Allocation happens only in the constructor and `reserve`.
class CpuRasterBackend final : public ZcollRasterBackend {
public:
    /// Reserves transform buffers for meshes up to these vertex counts (grown on demand otherwise).
    explicit CpuRasterBackend(size_t max_vertices = 4096);
    std::string_view name() const override { return "cpu"; }
    void render(const MeshRef& membrane, const MeshRef* instrument, const ZcollView& view, const RasterRequest& req,
                RasterBuffers& out) override;
    bool any_penetration(const MeshRef& membrane, const MeshRef& instrument, const ZcollView& view) override;

private:
    /// Projected vertices, structure of arrays (vectorisable): window position in 1/256 pixel, the
    /// interpolated depth quantity (parallel: depth in mm, central: 1/depth) and an outcode (bits: outside
    /// left, right, bottom, top, near, far of V; bit 6: behind the camera of a central view).
    struct Projected {
        std::vector<float> wx, wy;
        std::vector<int32_t> x, y;
        std::vector<float> q;
        std::vector<uint8_t> code;
        void resize(size_t n);
    };
    void project(const MeshRef& mesh, const ZcollView& view, Projected& out);
    /// Outcodes of projected instrument vertices against the membrane image bounds and deepest depth.
    void instrument_codes(const ZcollView& view);
    void raster_membrane(const MeshRef& membrane, const ZcollView& view, const RasterRequest& req,
                         RasterBuffers& out);
    Projected membrane_px_, instrument_px_;
    RasterBuffers scratch_;  // boolean mode: membrane buffers that are never read back
    // Screen bounds and deepest depth of the membrane in V: instrument triangles outside them cannot collide.
    int mem_x0_ = 0, mem_y0_ = 0, mem_x1_ = -1, mem_y1_ = -1;
    float mem_zmax_ = 0.0f;
};

}  // namespace eyesim::sim::collision
