#include "eyesim/render/scene_renderer.hpp"

#include "eyesim/render/egl_context.hpp"
#include "scene_shaders.hpp"

#include "gl_program.hpp"

#include <GLES3/gl3.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstring>

namespace eyesim::render {
namespace {

namespace sh = scene_shaders;

constexpr float kPi = 3.14159265358979f;
constexpr float deg_to_rad(float d) { return d * kPi / 180.0f; }

/// Right-handed look-at (OpenGL convention: the camera looks down its −z, image right = forward × up).
Eigen::Matrix4f look_at(const Eigen::Vector3f& eye, const Eigen::Vector3f& target, const Eigen::Vector3f& up) {
    const Eigen::Vector3f f = (target - eye).normalized();
    const Eigen::Vector3f s = f.cross(up).normalized();
    const Eigen::Vector3f u = s.cross(f);
    Eigen::Matrix4f m = Eigen::Matrix4f::Identity();
    m.block<1, 3>(0, 0) = s.transpose();
    m.block<1, 3>(1, 0) = u.transpose();
    m.block<1, 3>(2, 0) = -f.transpose();
    m(0, 3) = -s.dot(eye);
    m(1, 3) = -u.dot(eye);
    m(2, 3) = f.dot(eye);
    return m;
}

/// OpenGL perspective projection (clip z in [−w, w]).
Eigen::Matrix4f perspective(float fovy_rad, float aspect, float near_mm, float far_mm) {
    const float t = 1.0f / std::tan(fovy_rad * 0.5f);
    Eigen::Matrix4f m = Eigen::Matrix4f::Zero();
    m(0, 0) = t / aspect;
    m(1, 1) = t;
    m(2, 2) = (far_mm + near_mm) / (near_mm - far_mm);
    m(2, 3) = 2.0f * far_mm * near_mm / (near_mm - far_mm);
    m(3, 2) = -1.0f;
    return m;
}

GLuint link(const char* vs_src, const char* fs_src, std::string& error) {
    return link_program(vs_src, fs_src, "scene renderer", error);
}

/// The baked fundus texture: texels, and the half extent it covers on the eye-frame x and y axes.
constexpr int kFundusTexturePx = 1024;
constexpr float kFundusHalf_mm = 13.0f;

/// A draw range in the per-frame index buffer.
struct Range {
    GLsizei first = 0;
    GLsizei count = 0;
};

}  // namespace

Eigen::Vector3f RenderConfig::view_position_eye_mm(int view) const {
    const float half = deg_to_rad(stereo_angle_deg) * 0.5f * (view == 0 ? -1.0f : 1.0f);
    return focus_eye_mm + view_distance_mm * Eigen::Vector3f(std::sin(half), 0.0f, std::cos(half));
}

/// GL objects and per-frame staging buffers.
struct SceneRenderer::Gl {
    GLuint scene_prog = 0, shadow_prog = 0;
    GLuint fundus_tex = 0;
    GLuint sphere_vao = 0, sphere_vbo = 0, sphere_ibo = 0;
    GLsizei sphere_index_count = 0;
    GLuint dyn_vao = 0, dyn_vbo = 0, dyn_ibo = 0;
    GLuint shadow_tex[2] = {0, 0}, shadow_fbo[2] = {0, 0};  // 0: opaque instruments, 1: membrane
    GLuint msaa_fbo = 0, msaa_color = 0, msaa_depth = 0;
    GLuint resolve_fbo = 0, resolve_color = 0;
    int samples = 1;
    std::vector<float> vertices;   // interleaved position (3) + normal (3)
    std::vector<uint32_t> indices;
    std::vector<uint8_t> readback;

    ~Gl() {
        glDeleteProgram(scene_prog);
        glDeleteProgram(shadow_prog);
        const GLuint vaos[] = {sphere_vao, dyn_vao};
        glDeleteVertexArrays(2, vaos);
        const GLuint bufs[] = {sphere_vbo, sphere_ibo, dyn_vbo, dyn_ibo};
        glDeleteBuffers(4, bufs);
        glDeleteTextures(2, shadow_tex);
        glDeleteTextures(1, &fundus_tex);
        const GLuint fbos[] = {shadow_fbo[0], shadow_fbo[1], msaa_fbo, resolve_fbo};
        glDeleteFramebuffers(4, fbos);
        const GLuint rbs[] = {msaa_color, msaa_depth, resolve_color};
        glDeleteRenderbuffers(3, rbs);
    }

    GLint loc(GLuint prog, const char* name) const { return glGetUniformLocation(prog, name); }

    /// Appends `mesh` with area-weighted vertex normals; invalid triangles are skipped. Returns its index range.
    Range append(const MeshView& mesh) {
        Range r;
        r.first = static_cast<GLsizei>(indices.size());
        const size_t base = vertices.size() / 6;
        const size_t n = mesh.vertices_eye_mm.size();
        vertices.resize(vertices.size() + n * 6, 0.0f);
        float* v = vertices.data() + base * 6;
        for (size_t i = 0; i < n; ++i) std::memcpy(v + i * 6, mesh.vertices_eye_mm[i].data(), 3 * sizeof(float));
        for (const auto& t : mesh.triangles) {
            if (t[0] >= n || t[1] >= n || t[2] >= n) continue;
            const Eigen::Vector3f& a = mesh.vertices_eye_mm[t[0]];
            const Eigen::Vector3f face = (mesh.vertices_eye_mm[t[1]] - a).cross(mesh.vertices_eye_mm[t[2]] - a);
            if (!face.allFinite()) continue;
            for (uint32_t k : t) {
                float* nrm = v + static_cast<size_t>(k) * 6 + 3;
                nrm[0] += face.x();
                nrm[1] += face.y();
                nrm[2] += face.z();
                indices.push_back(static_cast<uint32_t>(base + k));
            }
        }
        r.count = static_cast<GLsizei>(indices.size()) - r.first;
        return r;
    }

    /// Appends a small sphere (a highlight dot) of `radius_mm` at `c`.
    Range append_dot(const Eigen::Vector3f& c, float radius_mm) {
        constexpr int kRings = 6, kSegs = 10;
        Range r;
        r.first = static_cast<GLsizei>(indices.size());
        const uint32_t base = static_cast<uint32_t>(vertices.size() / 6);
        for (int i = 0; i <= kRings; ++i) {
            const float th = kPi * static_cast<float>(i) / kRings;
            for (int j = 0; j <= kSegs; ++j) {
                const float ph = 2.0f * kPi * static_cast<float>(j) / kSegs;
                const Eigen::Vector3f u(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th));
                const Eigen::Vector3f p = c + radius_mm * u;
                vertices.insert(vertices.end(), {p.x(), p.y(), p.z(), u.x(), u.y(), u.z()});
            }
        }
        for (int i = 0; i < kRings; ++i)
            for (int j = 0; j < kSegs; ++j) {
                const uint32_t a = base + static_cast<uint32_t>(i * (kSegs + 1) + j);
                const uint32_t b = a + kSegs + 1;
                indices.insert(indices.end(), {a, b, a + 1, a + 1, b, b + 1});
            }
        r.count = static_cast<GLsizei>(indices.size()) - r.first;
        return r;
    }
};

std::unique_ptr<SceneRenderer> SceneRenderer::create(int width, int height, std::string& error) {
    return create(width, height, RenderConfig{}, error);
}

std::unique_ptr<SceneRenderer> SceneRenderer::create(int width, int height, const RenderConfig& config,
                                                     std::string& error) {
    if (width < 16 || height < 16 || width > 8192 || height > 8192) {
        error = "scene renderer: invalid view size " + std::to_string(width) + "x" + std::to_string(height);
        return nullptr;
    }
    std::unique_ptr<SceneRenderer> r(new SceneRenderer());
    r->config_ = config;
    r->width_ = width;
    r->height_ = height;
    r->context_ = EglContext::create(error);
    if (!r->context_) return nullptr;
    r->gl_ = std::make_unique<Gl>();
    Gl& g = *r->gl_;

    g.scene_prog = link(sh::kSceneVertex, sh::kSceneFragment, error);
    if (!g.scene_prog) return nullptr;
    g.shadow_prog = link(sh::kShadowVertex, sh::kShadowFragment, error);
    if (!g.shadow_prog) return nullptr;

    // Bake the procedural fundus albedo once into a mipmapped texture over the eye-frame x, y plane.
    {
        const GLuint bake = link(sh::kBakeVertex, sh::kBakeFragment, error);
        if (!bake) return nullptr;
        glGenTextures(1, &g.fundus_tex);
        glBindTexture(GL_TEXTURE_2D, g.fundus_tex);
        glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, kFundusTexturePx, kFundusTexturePx, 0, GL_RGBA, GL_UNSIGNED_BYTE,
                     nullptr);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
        GLuint fbo = 0, vao = 0;
        glGenFramebuffers(1, &fbo);
        glBindFramebuffer(GL_FRAMEBUFFER, fbo);
        glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, g.fundus_tex, 0);
        const bool complete = glCheckFramebufferStatus(GL_FRAMEBUFFER) == GL_FRAMEBUFFER_COMPLETE;
        if (complete) {
            glGenVertexArrays(1, &vao);
            glBindVertexArray(vao);
            glViewport(0, 0, kFundusTexturePx, kFundusTexturePx);
            glDisable(GL_DEPTH_TEST);
            glDisable(GL_BLEND);
            glUseProgram(bake);
            glUniform1f(glGetUniformLocation(bake, "u_fundus_half_mm"), kFundusHalf_mm);
            glDrawArrays(GL_TRIANGLES, 0, 3);
            glBindVertexArray(0);
            glDeleteVertexArrays(1, &vao);
        }
        glBindFramebuffer(GL_FRAMEBUFFER, 0);
        glDeleteFramebuffers(1, &fbo);
        glDeleteProgram(bake);
        if (!complete) {
            error = "scene renderer: fundus texture framebuffer incomplete";
            return nullptr;
        }
        glBindTexture(GL_TEXTURE_2D, g.fundus_tex);
        glGenerateMipmap(GL_TEXTURE_2D);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR_MIPMAP_LINEAR);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    }

    // Unit eye sphere, triangles counter-clockwise seen from the centre, normals inwards.
    {
        constexpr int kRings = 96, kSegs = 192;
        std::vector<float> v;
        std::vector<uint32_t> idx;
        for (int i = 0; i <= kRings; ++i) {
            const float th = kPi * static_cast<float>(i) / kRings;
            for (int j = 0; j <= kSegs; ++j) {
                const float ph = 2.0f * kPi * static_cast<float>(j) / kSegs;
                const Eigen::Vector3f u(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th));
                v.insert(v.end(), {u.x(), u.y(), u.z(), -u.x(), -u.y(), -u.z()});
            }
        }
        auto pos = [&](uint32_t k) { return Eigen::Vector3f(v[k * 6], v[k * 6 + 1], v[k * 6 + 2]); };
        auto tri = [&](uint32_t a, uint32_t b, uint32_t c) {
            const Eigen::Vector3f n = (pos(b) - pos(a)).cross(pos(c) - pos(a));
            if (n.squaredNorm() < 1e-14f) return;  // degenerate at the poles
            if (n.dot(pos(a) + pos(b) + pos(c)) > 0.0f) std::swap(b, c);  // make it face the centre
            idx.insert(idx.end(), {a, b, c});
        };
        for (int i = 0; i < kRings; ++i)
            for (int j = 0; j < kSegs; ++j) {
                const uint32_t a = static_cast<uint32_t>(i * (kSegs + 1) + j);
                const uint32_t b = a + kSegs + 1;
                tri(a, b, a + 1);
                tri(a + 1, b, b + 1);
            }
        g.sphere_index_count = static_cast<GLsizei>(idx.size());
        glGenVertexArrays(1, &g.sphere_vao);
        glGenBuffers(1, &g.sphere_vbo);
        glGenBuffers(1, &g.sphere_ibo);
        glBindVertexArray(g.sphere_vao);
        glBindBuffer(GL_ARRAY_BUFFER, g.sphere_vbo);
        glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(v.size() * sizeof(float)), v.data(), GL_STATIC_DRAW);
        glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, g.sphere_ibo);
        glBufferData(GL_ELEMENT_ARRAY_BUFFER, static_cast<GLsizeiptr>(idx.size() * sizeof(uint32_t)), idx.data(),
                     GL_STATIC_DRAW);
        glEnableVertexAttribArray(0);
        glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), nullptr);
        glEnableVertexAttribArray(1);
        glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float),
                              reinterpret_cast<const void*>(3 * sizeof(float)));
    }
    // Per-frame geometry: one interleaved vertex buffer and one index buffer.
    glGenVertexArrays(1, &g.dyn_vao);
    glGenBuffers(1, &g.dyn_vbo);
    glGenBuffers(1, &g.dyn_ibo);
    glBindVertexArray(g.dyn_vao);
    glBindBuffer(GL_ARRAY_BUFFER, g.dyn_vbo);
    glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, g.dyn_ibo);
    glEnableVertexAttribArray(0);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), nullptr);
    glEnableVertexAttribArray(1);
    glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), reinterpret_cast<const void*>(3 * sizeof(float)));
    glBindVertexArray(0);

    // Shadow maps: depth textures with hardware comparison (core in GLES 3.0).
    const int sm = std::clamp(config.shadow_map_px, 64, 4096);
    r->config_.shadow_map_px = sm;
    glGenTextures(2, g.shadow_tex);
    glGenFramebuffers(2, g.shadow_fbo);
    for (int k = 0; k < 2; ++k) {
        glBindTexture(GL_TEXTURE_2D, g.shadow_tex[k]);
        glTexImage2D(GL_TEXTURE_2D, 0, GL_DEPTH_COMPONENT24, sm, sm, 0, GL_DEPTH_COMPONENT, GL_UNSIGNED_INT,
                     nullptr);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_COMPARE_MODE, GL_COMPARE_REF_TO_TEXTURE);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_COMPARE_FUNC, GL_LEQUAL);
        glBindFramebuffer(GL_FRAMEBUFFER, g.shadow_fbo[k]);
        glFramebufferTexture2D(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_TEXTURE_2D, g.shadow_tex[k], 0);
        const GLenum none = GL_NONE;
        glDrawBuffers(1, &none);
        glReadBuffer(GL_NONE);
        if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
            error = "scene renderer: shadow-map framebuffer incomplete";
            return nullptr;
        }
    }

    // Multisampled colour + depth target, resolved into a single-sample colour buffer for read-back.
    GLint max_samples = 1;
    glGetIntegerv(GL_MAX_SAMPLES, &max_samples);
    g.samples = std::clamp(config.msaa_samples, 1, std::max(1, static_cast<int>(max_samples)));
    r->config_.msaa_samples = g.samples;
    glGenFramebuffers(1, &g.msaa_fbo);
    glGenRenderbuffers(1, &g.msaa_color);
    glGenRenderbuffers(1, &g.msaa_depth);
    glBindRenderbuffer(GL_RENDERBUFFER, g.msaa_color);
    glRenderbufferStorageMultisample(GL_RENDERBUFFER, g.samples > 1 ? g.samples : 0, GL_RGBA8, width, height);
    glBindRenderbuffer(GL_RENDERBUFFER, g.msaa_depth);
    glRenderbufferStorageMultisample(GL_RENDERBUFFER, g.samples > 1 ? g.samples : 0, GL_DEPTH_COMPONENT24, width,
                                     height);
    glBindFramebuffer(GL_FRAMEBUFFER, g.msaa_fbo);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, g.msaa_color);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, g.msaa_depth);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        error = "scene renderer: multisampled framebuffer incomplete (" + std::to_string(g.samples) + " samples)";
        return nullptr;
    }
    glGenFramebuffers(1, &g.resolve_fbo);
    glGenRenderbuffers(1, &g.resolve_color);
    glBindRenderbuffer(GL_RENDERBUFFER, g.resolve_color);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, width, height);
    glBindFramebuffer(GL_FRAMEBUFFER, g.resolve_fbo);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, g.resolve_color);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        error = "scene renderer: resolve framebuffer incomplete";
        return nullptr;
    }
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    if (const GLenum e = glGetError(); e != GL_NO_ERROR) {
        error = "scene renderer: GL error " + std::to_string(e) + " during set-up";
        return nullptr;
    }
    return r;
}

SceneRenderer::~SceneRenderer() {
    if (gl_ && context_ && context_->make_current()) gl_.reset();  // GL objects need their context current
}

const std::string& SceneRenderer::renderer_name() const { return context_->renderer(); }

void SceneRenderer::render(const SceneFrame& frame, StereoImages& out) {
    Gl& g = *gl_;
    const RenderConfig& c = config_;
    context_->make_current();
    const float radius = std::isfinite(frame.eye_radius_mm) && frame.eye_radius_mm > 0.0f ? frame.eye_radius_mm
                                                                                           : 12.0f;

    // 1. Stage this frame's geometry: tissue, instruments, highlight dots.
    g.vertices.clear();
    g.indices.clear();
    const Range tissue = g.append(frame.tissue);
    const size_t n_instr = std::min<size_t>(frame.instruments.size(), 8);
    std::array<Range, 8> instr{};
    const InstrumentView* light = nullptr;
    for (size_t i = 0; i < n_instr; ++i) {
        instr[i] = g.append(frame.instruments[i].mesh);
        if (frame.instruments[i].is_light_pipe && light == nullptr) light = &frame.instruments[i];
    }
    Range dots;
    dots.first = static_cast<GLsizei>(g.indices.size());
    for (const Eigen::Vector3f& p : frame.highlight_nodes_eye_mm)
        if (p.allFinite()) g.append_dot(p, c.highlight_radius_mm);
    dots.count = static_cast<GLsizei>(g.indices.size()) - dots.first;
    glBindVertexArray(g.dyn_vao);
    glBindBuffer(GL_ARRAY_BUFFER, g.dyn_vbo);
    glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(g.vertices.size() * sizeof(float)), g.vertices.data(),
                 GL_STREAM_DRAW);
    glBufferData(GL_ELEMENT_ARRAY_BUFFER, static_cast<GLsizeiptr>(g.indices.size() * sizeof(uint32_t)),
                 g.indices.data(), GL_STREAM_DRAW);
    auto draw = [](const Range& r) {
        if (r.count > 0)
            glDrawElements(GL_TRIANGLES, r.count, GL_UNSIGNED_INT,
                           reinterpret_cast<const void*>(static_cast<uintptr_t>(r.first) * sizeof(uint32_t)));
    };

    // 2. Shadow maps from the light pipe's tip: opaque instruments, and the membrane (partial shadow).
    Eigen::Vector3f spot_pos = Eigen::Vector3f::Zero(), spot_dir = -Eigen::Vector3f::UnitZ();
    bool has_spot = light != nullptr && light->tip_eye_mm.allFinite() && light->forward_eye.allFinite() &&
                    light->forward_eye.squaredNorm() > 1e-12f;
    Eigen::Matrix4f light_vp = Eigen::Matrix4f::Identity();
    const bool tissue_casts = !frame.tissue_is_retina && tissue.count > 0 && c.membrane_shadow > 0.0f;
    if (has_spot) {
        spot_pos = light->tip_eye_mm;
        spot_dir = light->forward_eye.normalized();
        const Eigen::Vector3f up =
            std::abs(spot_dir.y()) < 0.9f ? Eigen::Vector3f::UnitY() : Eigen::Vector3f::UnitX();
        const float fov = std::min(2.0f * deg_to_rad(c.spot_half_angle_deg + 4.0f), deg_to_rad(170.0f));
        light_vp = perspective(fov, 1.0f, 0.1f, 4.0f * radius + 2.0f) * look_at(spot_pos, spot_pos + spot_dir, up);
        glUseProgram(g.shadow_prog);
        glUniformMatrix4fv(g.loc(g.shadow_prog, "u_light_view_proj"), 1, GL_FALSE, light_vp.data());
        glUniform1f(g.loc(g.shadow_prog, "u_clip_radius"), radius * 1.001f);
        glViewport(0, 0, c.shadow_map_px, c.shadow_map_px);
        glEnable(GL_DEPTH_TEST);
        glDepthFunc(GL_LESS);
        glDepthMask(GL_TRUE);
        glDisable(GL_CULL_FACE);
        glDisable(GL_BLEND);
        glEnable(GL_POLYGON_OFFSET_FILL);
        glPolygonOffset(1.5f, 4.0f);
        for (int k = 0; k < 2; ++k) {
            glBindFramebuffer(GL_FRAMEBUFFER, g.shadow_fbo[k]);
            glClearDepthf(1.0f);
            glClear(GL_DEPTH_BUFFER_BIT);
            if (k == 0) {
                for (size_t i = 0; i < n_instr; ++i)
                    if (!frame.instruments[i].is_light_pipe) draw(instr[i]);
            } else if (tissue_casts) {
                draw(tissue);
            }
        }
        glDisable(GL_POLYGON_OFFSET_FILL);
    }

    // 3. Both microscope views.
    out.width = width_;
    out.height = height_;
    const size_t bytes = static_cast<size_t>(width_) * static_cast<size_t>(height_) * 4;
    out.left_rgba.resize(bytes);
    out.right_rgba.resize(bytes);
    g.readback.resize(bytes);
    const GLuint prog = g.scene_prog;
    glUseProgram(prog);
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_2D, g.shadow_tex[0]);
    glActiveTexture(GL_TEXTURE1);
    glBindTexture(GL_TEXTURE_2D, g.shadow_tex[1]);
    glUniform1i(g.loc(prog, "u_shadow_opaque"), 0);
    glUniform1i(g.loc(prog, "u_shadow_tissue"), 1);
    glActiveTexture(GL_TEXTURE2);
    glBindTexture(GL_TEXTURE_2D, g.fundus_tex);
    glUniform1i(g.loc(prog, "u_fundus"), 2);
    glUniform1f(g.loc(prog, "u_fundus_half_mm"), kFundusHalf_mm);
    glUniformMatrix4fv(g.loc(prog, "u_light_view_proj"), 1, GL_FALSE, light_vp.data());
    glUniform1f(g.loc(prog, "u_shadow_texel"), 1.0f / static_cast<float>(c.shadow_map_px));
    glUniform1f(g.loc(prog, "u_eye_radius"), radius);
    glUniform1f(g.loc(prog, "u_ambient"), c.ambient);
    glUniform1f(g.loc(prog, "u_coaxial"), c.coaxial);
    glUniform1i(g.loc(prog, "u_has_spot"), has_spot ? 1 : 0);
    glUniform3fv(g.loc(prog, "u_spot_pos"), 1, spot_pos.data());
    glUniform3fv(g.loc(prog, "u_spot_dir"), 1, spot_dir.data());
    const float outer = deg_to_rad(c.spot_half_angle_deg);
    const float inner = std::max(0.0f, outer - deg_to_rad(c.spot_edge_deg));
    glUniform1f(g.loc(prog, "u_spot_cos_outer"), std::cos(outer));
    glUniform1f(g.loc(prog, "u_spot_cos_inner"), std::cos(inner));
    glUniform1f(g.loc(prog, "u_spot_intensity"), c.spot_intensity);
    glUniform1f(g.loc(prog, "u_spot_falloff_mm"), std::max(c.spot_falloff_mm, 1e-3f));
    glUniform1f(g.loc(prog, "u_tissue_shadow"), tissue_casts ? c.membrane_shadow : 0.0f);
    const Eigen::Vector2f centre(0.5f * static_cast<float>(width_), 0.5f * static_cast<float>(height_));
    glUniform2fv(g.loc(prog, "u_centre_px"), 1, centre.data());
    glUniform1f(g.loc(prog, "u_stop_radius_px"),
                c.pupil_radius_fraction * 0.5f * static_cast<float>(std::min(width_, height_)));
    const GLint u_material = g.loc(prog, "u_material"), u_color = g.loc(prog, "u_color"),
                u_clip = g.loc(prog, "u_clip_radius"), u_scale = g.loc(prog, "u_scale"),
                u_vp = g.loc(prog, "u_view_proj"), u_cam = g.loc(prog, "u_cam_pos");

    const float near_mm = std::max(1.0f, c.view_distance_mm - 4.0f * radius);
    const float far_mm = c.view_distance_mm + 4.0f * radius;
    const Eigen::Matrix4f proj = perspective(deg_to_rad(c.vertical_fov_deg),
                                             static_cast<float>(width_) / static_cast<float>(height_), near_mm, far_mm);
    for (int view = 0; view < 2; ++view) {
        const Eigen::Vector3f cam = c.view_position_eye_mm(view);
        const Eigen::Matrix4f vp = proj * look_at(cam, c.focus_eye_mm, Eigen::Vector3f::UnitY());
        glBindFramebuffer(GL_FRAMEBUFFER, g.msaa_fbo);
        glViewport(0, 0, width_, height_);
        glClearColor(0.0f, 0.0f, 0.0f, 1.0f);
        glClearDepthf(1.0f);
        glDepthMask(GL_TRUE);
        glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
        glEnable(GL_DEPTH_TEST);
        glDepthFunc(GL_LEQUAL);
        glDisable(GL_BLEND);
        glUniformMatrix4fv(u_vp, 1, GL_FALSE, vp.data());
        glUniform3fv(u_cam, 1, cam.data());

        // Eye interior: only the inner wall facing the microscope (the front cap is culled).
        glEnable(GL_CULL_FACE);
        glCullFace(GL_BACK);
        glFrontFace(GL_CCW);
        glBindVertexArray(g.sphere_vao);
        glUniform1i(u_material, sh::kFundus);
        glUniform4f(u_color, 1.0f, 1.0f, 1.0f, 1.0f);
        glUniform1f(u_clip, -1.0f);
        glUniform1f(u_scale, radius);
        glDrawElements(GL_TRIANGLES, g.sphere_index_count, GL_UNSIGNED_INT, nullptr);
        glDisable(GL_CULL_FACE);

        glBindVertexArray(g.dyn_vao);
        glUniform1f(u_scale, 1.0f);
        if (frame.tissue_is_retina) {
            glEnable(GL_POLYGON_OFFSET_FILL);  // drawn over the eye sphere it lies on
            glPolygonOffset(-1.0f, -4.0f);
            draw(tissue);
            glDisable(GL_POLYGON_OFFSET_FILL);
        }
        // Instruments: only what is inside the eye is seen through the pupil.
        glUniform1f(u_clip, radius * 1.001f);
        for (size_t i = 0; i < n_instr; ++i) {
            const bool lp = frame.instruments[i].is_light_pipe;
            glUniform1i(u_material, lp ? sh::kLightPipe : sh::kMetal);
            if (lp)
                glUniform4f(u_color, 0.55f, 0.56f, 0.58f, 1.0f);
            else
                glUniform4f(u_color, 0.66f, 0.67f, 0.70f, 1.0f);
            draw(instr[i]);
        }
        glUniform1f(u_clip, -1.0f);
        glUniform1i(u_material, sh::kDot);
        glUniform4f(u_color, c.highlight_rgb.x(), c.highlight_rgb.y(), c.highlight_rgb.z(), 1.0f);
        draw(dots);
        // Membrane last, translucent, without depth writes; the destination keeps alpha 1.
        if (!frame.tissue_is_retina && tissue.count > 0) {
            glEnable(GL_BLEND);
            glBlendFuncSeparate(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA, GL_ZERO, GL_ONE);
            glDepthMask(GL_FALSE);
            glUniform1i(u_material, sh::kMembrane);
            glUniform4f(u_color, 0.86f, 0.87f, 0.88f, std::clamp(c.membrane_alpha, 0.0f, 1.0f));
            glUniform1f(u_clip, radius * 1.001f);
            draw(tissue);
            glDepthMask(GL_TRUE);
            glDisable(GL_BLEND);
        }

        // Resolve and read back, flipping to rows top to bottom.
        glBindFramebuffer(GL_READ_FRAMEBUFFER, g.msaa_fbo);
        glBindFramebuffer(GL_DRAW_FRAMEBUFFER, g.resolve_fbo);
        glBlitFramebuffer(0, 0, width_, height_, 0, 0, width_, height_, GL_COLOR_BUFFER_BIT, GL_NEAREST);
        glBindFramebuffer(GL_READ_FRAMEBUFFER, g.resolve_fbo);
        glPixelStorei(GL_PACK_ALIGNMENT, 1);
        glReadPixels(0, 0, width_, height_, GL_RGBA, GL_UNSIGNED_BYTE, g.readback.data());
        std::vector<uint8_t>& dst = view == 0 ? out.left_rgba : out.right_rgba;
        const size_t row = static_cast<size_t>(width_) * 4;
        for (int y = 0; y < height_; ++y) {
            uint8_t* d = dst.data() + static_cast<size_t>(height_ - 1 - y) * row;
            std::memcpy(d, g.readback.data() + static_cast<size_t>(y) * row, row);
            for (size_t x = 3; x < row; x += 4) d[x] = 255;
        }
    }
    glBindVertexArray(0);
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
}

}  // namespace eyesim::render
