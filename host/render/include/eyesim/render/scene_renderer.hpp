#pragma once
/// \file
/// Stereo pictures of the surgical scene as the operating microscope shows it, rendered off-screen through EGL +
/// OpenGL ES 3.0 (Mesa llvmpipe on machines without a GPU). The light pipe is a spot light at its tip that casts
/// shadows of the other instruments and of the membrane onto the retina: the surgeon's main depth cue (paper §2.1).
///
/// Eye frame (shared with collision and tissue code): origin at the eye centre, mm, +z out through the cornea
/// towards the microscope; the retina lines the posterior inner wall (posterior pole at (0, 0, −radius)).

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

namespace eyesim::render {

class EglContext;

/// A triangle mesh borrowed for one render call: vertices in the eye frame (mm) and vertex-index triples.
struct MeshView {
    std::span<const Eigen::Vector3f> vertices_eye_mm;       ///< vertex positions, eye frame, mm
    std::span<const std::array<uint32_t, 3>> triangles;     ///< indices into vertices_eye_mm
};

/// One instrument: its mesh already posed in the eye frame, and its working tip and axis.
struct InstrumentView {
    MeshView mesh;                  ///< posed mesh, eye frame
    Eigen::Vector3f tip_eye_mm;     ///< working tip (light pipe: centre of the emitting end face), eye frame, mm
    Eigen::Vector3f forward_eye;    ///< unit axis pointing from the shaft towards the tip (into the eye)
    bool is_light_pipe = false;     ///< the first light pipe is the scene's spot light and shadow source
};

/// Everything drawn in one stereo frame. Spans are only read during render().
struct SceneFrame {
    float eye_radius_mm = 12.0f;                               ///< inner eyeball sphere, centre at the origin
    MeshView tissue;                                           ///< membrane or retina mesh; may be empty
    bool tissue_is_retina = false;                             ///< draw `tissue` as retina (opaque fundus)
    std::span<const InstrumentView> instruments;               ///< 0..4 instruments
    std::span<const Eigen::Vector3f> highlight_nodes_eye_mm;   ///< optional nodes drawn as unlit dots
};

/// The two microscope views, RGBA8, rows top to bottom, `width * height * 4` bytes each.
struct StereoImages {
    int width = 0;                  ///< pixels per view
    int height = 0;                 ///< pixels per view
    std::vector<uint8_t> left_rgba;   ///< left eyepiece (view 0)
    std::vector<uint8_t> right_rgba;  ///< right eyepiece (view 1)
};

/// Microscope optics and lighting. The two views are pinhole cameras that converge on `focus_eye_mm`: view v sits
/// at focus + distance·(sin(±angle/2), 0, cos(angle/2)) (left: −x), looks at the focus, image up is +y of the
/// eye frame, image right is roughly +x.
struct RenderConfig {
    Eigen::Vector3f focus_eye_mm{0.0f, 0.0f, -10.5f};  ///< convergence point of the two views, eye frame, mm
    float view_distance_mm = 90.0f;        ///< from each view's centre of projection to the focus, mm
    float stereo_angle_deg = 4.0f;         ///< full convergence angle between the two viewing axes
    float vertical_fov_deg = 13.0f;        ///< full vertical field of view of each view
    float pupil_radius_fraction = 0.97f;   ///< round field stop: radius / (min(width, height) / 2); 0 disables
    int msaa_samples = 4;                  ///< multisampling (clamped to GL_MAX_SAMPLES; 1 disables)
    float ambient = 0.05f;                 ///< unshadowed ambient light
    float coaxial = 0.12f;                 ///< the microscope's own dim coaxial illumination (along −z)
    float spot_intensity = 2.6f;           ///< light pipe intensity at its tip (before distance falloff)
    float spot_falloff_mm = 8.0f;          ///< distance falloff: intensity / (1 + (d / falloff)²)
    float spot_half_angle_deg = 38.0f;     ///< light cone half angle (outer edge)
    float spot_edge_deg = 10.0f;           ///< width of the soft edge inside the outer half angle
    float membrane_alpha = 0.5f;           ///< membrane opacity
    float membrane_shadow = 0.45f;         ///< fraction of light the membrane blocks
    float highlight_radius_mm = 0.12f;     ///< radius of a highlight dot
    Eigen::Vector3f highlight_rgb{0.15f, 1.0f, 0.25f};  ///< highlight dot colour (unlit), linear 0..1
    int shadow_map_px = 1024;              ///< size of each (square) shadow map

    /// Centre of projection of view 0 (left) or 1 (right), eye frame, mm.
    Eigen::Vector3f view_position_eye_mm(int view) const;
};

/// Off-screen stereo renderer. Owns its EGL context and GL objects; use from one thread. Not copyable.
class SceneRenderer {
public:
    /// Creates the renderer for `width` × `height` views with the default configuration; null and a one-line
    /// reason in `error` when EGL / GLES 3 is unavailable or the size is invalid.
    static std::unique_ptr<SceneRenderer> create(int width, int height, std::string& error);
    /// As above with an explicit configuration.
    static std::unique_ptr<SceneRenderer> create(int width, int height, const RenderConfig& config,
                                                 std::string& error);
    ~SceneRenderer();
    SceneRenderer(const SceneRenderer&) = delete;
    SceneRenderer& operator=(const SceneRenderer&) = delete;

    /// Renders both microscope views of `frame` into `out` (resized as needed). Deterministic: equal inputs give
    /// equal bytes on the same driver. Makes this renderer's GL context current on the calling thread and leaves it
    /// current (other GL users, such as the ZCOLL back-end, make their own context current before use).
    void render(const SceneFrame& frame, StereoImages& out);
    /// GL_RENDERER of the context, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)".
    const std::string& renderer_name() const;
    /// The configuration in use (msaa_samples as actually granted).
    const RenderConfig& config() const { return config_; }

private:
    struct Gl;
    SceneRenderer() = default;
    RenderConfig config_;
    int width_ = 0, height_ = 0;
    std::unique_ptr<EglContext> context_;
    std::unique_ptr<Gl> gl_;
};

/// Writes an 8-bit RGBA image (rows top to bottom) as a PNG (uncompressed deflate: no zlib needed). False and a
/// one-line reason on failure.
bool write_png(const std::string& path, int w, int h, const uint8_t* rgba, std::string& error);
/// Writes the two views side by side, left view on the left (parallel free-viewing), as one PNG.
bool write_side_by_side_png(const std::string& path, const StereoImages& img, std::string& error);

}  // namespace eyesim::render
