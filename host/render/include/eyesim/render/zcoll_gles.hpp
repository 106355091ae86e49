#pragma once
/// \file
/// ZCOLL render back-end on OpenGL ES 3 (off-screen FBO in an EglContext).
///
/// Colour ids and depth go to one RG32UI attachment (R = feature id + 1, G = depth in mm as float bits) so the
/// read-back needs no float render targets; a DEPTH_COMPONENT32F buffer does the depth test. Layer counting:
/// an extra pass with additive blending into an R8 target. Boolean mode: stencil marks membrane pixels and an
/// ANY_SAMPLES_PASSED occlusion query counts instrument samples in front of the membrane; no buffer read-back.
/// Rasterisation follows the GL rules (sample at pixel centres, no double hits on shared edges); llvmpipe
/// and GPUs snap to 1/256 or finer sub-pixel grids, so ties on edges may go to the other triangle than on the
/// CPU back-end (see docs/simulation.md for the measured bound).

#include "eyesim/render/egl_context.hpp"
#include "eyesim/sim/collision/raster_backend.hpp"

#include <memory>
#include <string>
#include <vector>

namespace eyesim::render {

/// The GLES3 ZCOLL back-end. Create with `create`; all GL objects are made in `create`.
class GlesZcollBackend final : public sim::collision::ZcollRasterBackend {
public:
    /// Creates an EGL context and the GL objects for viewports up to `max_resolution_px`. Null + `error` when
    /// EGL/GLES3 is unavailable.
    static std::unique_ptr<GlesZcollBackend> create(std::string& error, int max_resolution_px = 512);
    ~GlesZcollBackend() override;

    std::string_view name() const override { return "egl"; }
    void render(const sim::collision::MeshRef& membrane, const sim::collision::MeshRef* instrument,
                const sim::collision::ZcollView& view, const sim::collision::RasterRequest& req,
                sim::collision::RasterBuffers& out) override;
    bool any_penetration(const sim::collision::MeshRef& membrane, const sim::collision::MeshRef& instrument,
                         const sim::collision::ZcollView& view) override;

    /// The context (renderer name for reports).
    const EglContext& context() const { return *ctx_; }

private:
    GlesZcollBackend() = default;
    bool init(std::string& error, int max_resolution_px);
    void upload(const sim::collision::MeshRef& mesh, bool membrane);
    void set_view(const sim::collision::ZcollView& view, const Eigen::Isometry3f& mesh_to_eye, int mode);
    void bind_target(int resolution_px);

    std::unique_ptr<EglContext> ctx_;
    unsigned prog_ = 0, count_prog_ = 0;
    unsigned fbo_ = 0, color_rb_ = 0, depth_rb_ = 0, count_fbo_ = 0, count_rb_ = 0;
    unsigned vao_[2] = {0, 0}, pos_vbo_[2] = {0, 0}, vid_vbo_ = 0, query_ = 0;
    int max_r_ = 0;
    int u_mesh_to_cam_ = -1, u_scale_ = -1, u_central_ = -1, u_near_ = -1, u_far_ = -1, u_mode_ = -1;
    int c_mesh_to_cam_ = -1, c_scale_ = -1, c_central_ = -1, c_near_ = -1, c_far_ = -1;
    size_t vid_topology_size_ = 0;
    const void* vid_topology_ = nullptr;
    size_t pos_capacity_[2] = {0, 0};
    size_t draw_count_[2] = {0, 0};
    std::vector<float> scratch_pos_;
    std::vector<uint32_t> scratch_rgba_;
    std::vector<uint8_t> scratch_count_;
};

}  // namespace eyesim::render
