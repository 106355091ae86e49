#include "eyesim/render/zcoll_gles.hpp"

#include "gl_program.hpp"

#include <GLES3/gl3.h>

#include <cstring>

namespace eyesim::render {

using sim::collision::FeatureKind;
using sim::collision::MeshRef;
using sim::collision::Projection;
using sim::collision::RasterBuffers;
using sim::collision::RasterRequest;
using sim::collision::ZcollView;

namespace {

// Vertex shader shared by both programs: mesh frame → camera frame (x right, y up, z = depth along π).
const char* kVertexShader = R"(#version 300 es
layout(location = 0) in vec3 a_pos;
layout(location = 1) in uvec3 a_tri_vids;
uniform mat4 u_mesh_to_cam;
uniform float u_scale;
uniform int u_central;
uniform float u_near;
uniform float u_far;
flat out uint v_tri;
flat out uvec3 v_vids;
out vec3 v_bary;
out float v_depth;
void main() {
    vec3 c = (u_mesh_to_cam * vec4(a_pos, 1.0)).xyz;
    v_depth = c.z;
    v_tri = uint(gl_VertexID / 3);
    v_vids = a_tri_vids;
    int k = gl_VertexID % 3;
    v_bary = vec3(k == 0 ? 1.0 : 0.0, k == 1 ? 1.0 : 0.0, k == 2 ? 1.0 : 0.0);
    if (u_central == 0) {
        gl_Position = vec4(c.x * u_scale, c.y * u_scale, 2.0 * (c.z - u_near) / (u_far - u_near) - 1.0, 1.0);
    } else {
        float a = (u_far + u_near) / (u_far - u_near);
        float b = -2.0 * u_far * u_near / (u_far - u_near);
        gl_Position = vec4(c.x * u_scale, c.y * u_scale, a * c.z + b, c.z);
    }
}
)";

// Ids and depth: mode 0 triangle ids, 1 vertex ids (largest barycentric weight), 2 instrument.
const char* kIdShader = R"(#version 300 es
precision highp float;
precision highp int;
flat in uint v_tri;
flat in uvec3 v_vids;
in vec3 v_bary;
in float v_depth;
uniform int u_mode;
layout(location = 0) out uvec4 o_id_depth;
void main() {
    uint id;
    if (u_mode == 0) {
        id = v_tri + 1u;
    } else if (u_mode == 1) {
        id = (v_bary.x >= v_bary.y && v_bary.x >= v_bary.z) ? v_vids.x : (v_bary.y >= v_bary.z ? v_vids.y : v_vids.z);
        id += 1u;
    } else {
        id = 0xFFFFFFFFu;
    }
    o_id_depth = uvec4(id, floatBitsToUint(v_depth), 0u, 0u);
}
)";

// Layer counting: every fragment adds 1/255 to an R8 target (additive blending).
const char* kCountShader = R"(#version 300 es
precision mediump float;
layout(location = 0) out vec4 o_count;
void main() { o_count = vec4(1.0 / 255.0, 0.0, 0.0, 1.0); }
)";

GLuint link(const char* vs_src, const char* fs_src, std::string& error) {
    return link_program(vs_src, fs_src, "GLES3", error);
}

}  // namespace

std::unique_ptr<GlesZcollBackend> GlesZcollBackend::create(std::string& error, int max_resolution_px) {
    std::unique_ptr<GlesZcollBackend> b(new GlesZcollBackend());
    if (!b->init(error, max_resolution_px)) return nullptr;
    return b;
}

bool GlesZcollBackend::init(std::string& error, int max_resolution_px) {
    ctx_ = EglContext::create(error);
    if (!ctx_) return false;
    max_r_ = max_resolution_px;
    prog_ = link(kVertexShader, kIdShader, error);
    if (!prog_) return false;
    count_prog_ = link(kVertexShader, kCountShader, error);
    if (!count_prog_) return false;
    u_mesh_to_cam_ = glGetUniformLocation(prog_, "u_mesh_to_cam");
    u_scale_ = glGetUniformLocation(prog_, "u_scale");
    u_central_ = glGetUniformLocation(prog_, "u_central");
    u_near_ = glGetUniformLocation(prog_, "u_near");
    u_far_ = glGetUniformLocation(prog_, "u_far");
    u_mode_ = glGetUniformLocation(prog_, "u_mode");
    c_mesh_to_cam_ = glGetUniformLocation(count_prog_, "u_mesh_to_cam");
    c_scale_ = glGetUniformLocation(count_prog_, "u_scale");
    c_central_ = glGetUniformLocation(count_prog_, "u_central");
    c_near_ = glGetUniformLocation(count_prog_, "u_near");
    c_far_ = glGetUniformLocation(count_prog_, "u_far");

    glGenRenderbuffers(1, &color_rb_);
    glBindRenderbuffer(GL_RENDERBUFFER, color_rb_);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_RG32UI, max_r_, max_r_);
    glGenRenderbuffers(1, &depth_rb_);
    glBindRenderbuffer(GL_RENDERBUFFER, depth_rb_);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH32F_STENCIL8, max_r_, max_r_);
    glGenFramebuffers(1, &fbo_);
    glBindFramebuffer(GL_FRAMEBUFFER, fbo_);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, color_rb_);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_STENCIL_ATTACHMENT, GL_RENDERBUFFER, depth_rb_);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        error = "GLES3: RG32UI + DEPTH32F_STENCIL8 framebuffer incomplete";
        return false;
    }
    glGenRenderbuffers(1, &count_rb_);
    glBindRenderbuffer(GL_RENDERBUFFER, count_rb_);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_R8, max_r_, max_r_);
    glGenFramebuffers(1, &count_fbo_);
    glBindFramebuffer(GL_FRAMEBUFFER, count_fbo_);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, count_rb_);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        error = "GLES3: R8 counting framebuffer incomplete";
        return false;
    }
    glGenVertexArrays(2, vao_);
    glGenBuffers(2, pos_vbo_);
    glGenBuffers(1, &vid_vbo_);
    for (int k = 0; k < 2; ++k) {
        glBindVertexArray(vao_[k]);
        glBindBuffer(GL_ARRAY_BUFFER, pos_vbo_[k]);
        glEnableVertexAttribArray(0);
        glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 0, nullptr);
        if (k == 0) {
            glBindBuffer(GL_ARRAY_BUFFER, vid_vbo_);
            glEnableVertexAttribArray(1);
            glVertexAttribIPointer(1, 3, GL_UNSIGNED_INT, 0, nullptr);
        } else {
            glDisableVertexAttribArray(1);
        }
    }
    glBindVertexArray(0);
    glGenQueries(1, &query_);
    scratch_rgba_.resize(size_t(max_r_) * size_t(max_r_) * 4);
    scratch_count_.resize(size_t(max_r_) * size_t(max_r_) * 4);
    if (glGetError() != GL_NO_ERROR) {
        error = "GLES3: error while creating the ZCOLL objects";
        return false;
    }
    return true;
}

GlesZcollBackend::~GlesZcollBackend() {
    if (!ctx_ || !ctx_->make_current()) return;
    glDeleteQueries(1, &query_);
    glDeleteBuffers(2, pos_vbo_);
    glDeleteBuffers(1, &vid_vbo_);
    glDeleteVertexArrays(2, vao_);
    glDeleteFramebuffers(1, &fbo_);
    glDeleteFramebuffers(1, &count_fbo_);
    glDeleteRenderbuffers(1, &color_rb_);
    glDeleteRenderbuffers(1, &depth_rb_);
    glDeleteRenderbuffers(1, &count_rb_);
    glDeleteProgram(prog_);
    glDeleteProgram(count_prog_);
}

void GlesZcollBackend::upload(const MeshRef& mesh, bool membrane) {
    // Non-indexed triangles so gl_VertexID / 3 is the triangle id (flat ids without gl_PrimitiveID).
    const int k = membrane ? 0 : 1;
    const size_t nt = mesh.triangles.size();
    scratch_pos_.resize(nt * 9);
    float* p = scratch_pos_.data();
    for (const auto& t : mesh.triangles)
        for (uint32_t v : t) {
            const sim::Vec3f& q = mesh.vertices_mm[v];
            *p++ = q.x();
            *p++ = q.y();
            *p++ = q.z();
        }
    glBindBuffer(GL_ARRAY_BUFFER, pos_vbo_[k]);
    const size_t bytes = scratch_pos_.size() * sizeof(float);
    if (bytes > pos_capacity_[k]) {
        glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(bytes), scratch_pos_.data(), GL_STREAM_DRAW);
        pos_capacity_[k] = bytes;
    } else {
        glBufferSubData(GL_ARRAY_BUFFER, 0, GLsizeiptr(bytes), scratch_pos_.data());
    }
    draw_count_[k] = nt * 3;
    if (membrane && (vid_topology_ != mesh.triangles.data() || vid_topology_size_ != nt)) {
        // Per expanded vertex: its triangle's three vertex ids (uploaded once per topology).
        std::vector<uint32_t> vids(nt * 9);
        size_t i = 0;
        for (const auto& t : mesh.triangles)
            for (int c = 0; c < 3; ++c) {
                vids[i++] = t[0];
                vids[i++] = t[1];
                vids[i++] = t[2];
            }
        glBindBuffer(GL_ARRAY_BUFFER, vid_vbo_);
        glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(vids.size() * sizeof(uint32_t)), vids.data(), GL_STATIC_DRAW);
        vid_topology_ = mesh.triangles.data();
        vid_topology_size_ = nt;
    }
}

void GlesZcollBackend::set_view(const ZcollView& view, const Eigen::Isometry3f& mesh_to_eye, int mode) {
    const Eigen::Matrix3f ct = view.camera_to_eye.transpose();
    Eigen::Matrix4f m = Eigen::Matrix4f::Identity();
    m.topLeftCorner<3, 3>() = ct * mesh_to_eye.linear();
    m.topRightCorner<3, 1>() = ct * (mesh_to_eye.translation() - view.origin_eye_mm);
    const bool central = view.projection == Projection::Central;
    const float scale = central ? 1.0f / view.tan_half_angle : 1.0f / view.half_width_mm;
    const bool count = mode < 0;
    glUseProgram(count ? count_prog_ : prog_);
    glUniformMatrix4fv(count ? c_mesh_to_cam_ : u_mesh_to_cam_, 1, GL_FALSE, m.data());
    glUniform1f(count ? c_scale_ : u_scale_, scale);
    glUniform1i(count ? c_central_ : u_central_, central ? 1 : 0);
    glUniform1f(count ? c_near_ : u_near_, view.near_mm);
    glUniform1f(count ? c_far_ : u_far_, view.far_mm);
    if (!count) glUniform1i(u_mode_, mode);
}

void GlesZcollBackend::render(const MeshRef& membrane, const MeshRef* instrument, const ZcollView& view,
                              const RasterRequest& req, RasterBuffers& out) {
    ctx_->make_current();
    const int r = view.resolution_px;
    if (out.resolution_px != r) out.resize(r);
    const size_t npx = size_t(r) * size_t(r);
    glViewport(0, 0, r, r);
    glDisable(GL_BLEND);
    glDisable(GL_STENCIL_TEST);
    glDisable(GL_CULL_FACE);
    glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
    glDepthMask(GL_TRUE);
    // Steps 3–8: membrane into depth + ids, read back ZM and CM (one RG32UI read).
    glBindFramebuffer(GL_FRAMEBUFFER, fbo_);
    const float inf = sim::collision::kEmptyDepth;
    GLuint clear_id[4] = {0, 0, 0, 0};
    std::memcpy(&clear_id[1], &inf, sizeof inf);
    glClearBufferuiv(GL_COLOR, 0, clear_id);
    glClearBufferfi(GL_DEPTH_STENCIL, 0, 1.0f, 0);
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    upload(membrane, true);
    set_view(view, membrane.to_eye, req.ids == FeatureKind::Vertex ? 1 : 0);
    glBindVertexArray(vao_[0]);
    glDrawArrays(GL_TRIANGLES, 0, GLsizei(draw_count_[0]));
    glReadPixels(0, 0, r, r, GL_RGBA_INTEGER, GL_UNSIGNED_INT, scratch_rgba_.data());
    for (size_t p = 0; p < npx; ++p) {
        out.cm[p] = scratch_rgba_[4 * p];
        std::memcpy(&out.zm_mm[p], &scratch_rgba_[4 * p + 1], sizeof(float));
    }
    out.multi_layer_pixels = 0;
    out.x0 = out.y0 = 0;
    out.x1 = out.y1 = r - 1;  // the whole viewport was read back
    if (req.count_layers) {
        // Every membrane fragment in V, depth test off: the per-pixel layer count.
        glBindFramebuffer(GL_FRAMEBUFFER, count_fbo_);
        const GLfloat zero[4] = {0, 0, 0, 0};
        glClearBufferfv(GL_COLOR, 0, zero);
        glDisable(GL_DEPTH_TEST);
        glEnable(GL_BLEND);
        glBlendFunc(GL_ONE, GL_ONE);
        glBlendEquation(GL_FUNC_ADD);
        set_view(view, membrane.to_eye, -1);
        glDrawArrays(GL_TRIANGLES, 0, GLsizei(draw_count_[0]));
        glDisable(GL_BLEND);
        glReadPixels(0, 0, r, r, GL_RGBA, GL_UNSIGNED_BYTE, scratch_count_.data());
        for (size_t p = 0; p < npx; ++p) {
            out.layers[p] = scratch_count_[4 * p];
            if (out.cm[p] != 0 && out.layers[p] >= 2) ++out.multi_layer_pixels;
        }
        glBindFramebuffer(GL_FRAMEBUFFER, fbo_);
        glEnable(GL_DEPTH_TEST);
    } else {
        std::fill(out.layers.begin(), out.layers.begin() + long(npx), uint8_t{0});
    }
    if (!req.instrument || instrument == nullptr) {
        std::copy(out.zm_mm.begin(), out.zm_mm.end(), out.zi_mm.begin());
        glBindVertexArray(0);
        return;
    }
    // Steps 9–10: instrument with LEQUAL into the same depth buffer, read ZI back.
    glDepthFunc(GL_LEQUAL);
    upload(*instrument, false);
    set_view(view, instrument->to_eye, 2);
    glBindVertexArray(vao_[1]);
    glVertexAttribI4ui(1, 0, 0, 0, 0);
    glDrawArrays(GL_TRIANGLES, 0, GLsizei(draw_count_[1]));
    glReadPixels(0, 0, r, r, GL_RGBA_INTEGER, GL_UNSIGNED_INT, scratch_rgba_.data());
    for (size_t p = 0; p < npx; ++p) std::memcpy(&out.zi_mm[p], &scratch_rgba_[4 * p + 1], sizeof(float));
    glBindVertexArray(0);
}

bool GlesZcollBackend::any_penetration(const MeshRef& membrane, const MeshRef& instrument, const ZcollView& view) {
    ctx_->make_current();
    const int r = view.resolution_px;
    glViewport(0, 0, r, r);
    glBindFramebuffer(GL_FRAMEBUFFER, fbo_);
    glClearBufferfi(GL_DEPTH_STENCIL, 0, 1.0f, 0);
    glColorMask(GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
    glDisable(GL_BLEND);
    // Membrane: depth, and stencil = 1 where it is seen.
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glDepthMask(GL_TRUE);
    glEnable(GL_STENCIL_TEST);
    glStencilFunc(GL_ALWAYS, 1, 0xFF);
    glStencilOp(GL_KEEP, GL_KEEP, GL_REPLACE);
    upload(membrane, true);
    set_view(view, membrane.to_eye, 0);
    glBindVertexArray(vao_[0]);
    glDrawArrays(GL_TRIANGLES, 0, GLsizei(draw_count_[0]));
    // Instrument samples in front of a membrane sample: counted by the occlusion query, nothing read back.
    glDepthMask(GL_FALSE);
    glStencilFunc(GL_EQUAL, 1, 0xFF);
    glStencilOp(GL_KEEP, GL_KEEP, GL_KEEP);
    upload(instrument, false);
    set_view(view, instrument.to_eye, 2);
    glBindVertexArray(vao_[1]);
    glVertexAttribI4ui(1, 0, 0, 0, 0);
    glBeginQuery(GL_ANY_SAMPLES_PASSED, query_);
    glDrawArrays(GL_TRIANGLES, 0, GLsizei(draw_count_[1]));
    glEndQuery(GL_ANY_SAMPLES_PASSED);
    GLuint any = 0;
    glGetQueryObjectuiv(query_, GL_QUERY_RESULT, &any);
    glBindVertexArray(0);
    glDisable(GL_STENCIL_TEST);
    glDepthMask(GL_TRUE);
    glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
    return any != 0;
}

}  // namespace eyesim::render
