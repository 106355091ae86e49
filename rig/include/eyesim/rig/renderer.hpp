#pragma once
/// \file
/// Renderer of one camera's PAL fields with exact marker truth.
///
/// Image model (all colour values are 8-bit sRGB code values, the camera's response taken as linear in them):
/// - dark background, the white eye (Lambert, light at the camera: shade = 0.35 + 0.65 n·v), grey shafts,
///   coloured marker spheres (same shading; a marker fully facing the camera shows exactly its class colour);
/// - each field pixel integrates the frame pixel square around (x, 2y + p) (see camera.hpp) and the exposure;
/// - markers: exact per-pixel coverage. Pixels well inside a marker use 2×2 Gauss points for the shading;
///   pixels near its outline are split into n×n sub-cells, each with the exact area of a straight edge through
///   it (signed distance and normal from the sphere's silhouette cone, through the locally inverted distortion);
///   occluders (eye, other markers, shafts) are point-sampled per sub-cell. Motion blur: the exposure is split
///   into T time samples so a marker moves at most `blur_step_px` between samples;
/// - calibration checkerboard (board.hpp, `checkerboard` scenario): each pixel gets the exact area of every square
///   inside its aperture: pixels near an edge are split into n×n sub-cells (`board_subcells`), each mapped onto the
///   sheet as an affine footprint (parallelogram) and clipped exactly against the squares it overlaps; shading at
///   the pixel centre; drawn over the eye, background and shafts where it is nearer at the pixel centre; markers
///   behind it are hidden (per sub-cell); its own time samples for motion blur (the same 0.5 px rule, at most
///   `board_time_samples`);
/// - eye and background: precomputed (the eye is a uniformly white sphere rotating about its centre, so its
///   image is static), 4×4 samples near its outline; shafts: one sample per pixel at mid-exposure;
/// - noise (when noise_sigma > 0): Gaussian, σ_Y² = noise_sigma² + shot_gain·(Y − 16) on luma, σ = noise_sigma
///   on Cb and Cr, from a per (seed, camera, field) stream: deterministic and order-independent;
/// - output: BT.601 studio swing, Y = 16 + 219·(0.299 R + 0.587 G + 0.114 B)/255,
///   Cb = 128 + 224·(B − Y')/(1.772·255), Cr = 128 + 224·(R − Y')/(1.402·255), chroma filtered [1 2 1]/4 and
///   co-sited with even pixels, rounded, Y clamped to 16..235 and Cb/Cr to 16..240, bytes Cb Y0 Cr Y1.
/// Truth (MarkerCameraTruth): centroid of the marker's luma contribution (coverage × shading, over the pixel
/// apertures and time samples, before noise), in field pixels.

#include "eyesim/rig/camera.hpp"
#include "eyesim/rig/geometry.hpp"
#include "eyesim/rig/truth.hpp"

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

namespace eyesim::rig {

/// Lambert shading with the light at the camera: shade = kShadeAmbient + kShadeDiffuse · (n·v).
inline constexpr double kShadeAmbient = 0.35;
/// See kShadeAmbient.
inline constexpr double kShadeDiffuse = 0.65;
/// Background colour (sRGB code values).
inline constexpr std::array<float, 3> kBackgroundRgb{14.f, 14.f, 18.f};
/// Eye colour fully lit.
inline constexpr std::array<float, 3> kEyeRgb{236.f, 234.f, 226.f};
/// Shaft colour fully lit.
inline constexpr std::array<float, 3> kShaftRgb{150.f, 150.f, 156.f};

/// Renderer settings.
struct RenderOptions {
    double noise_sigma = 1.0;     ///< read noise σ in 8-bit DN (luma and chroma); 0 turns all noise off
    double shot_gain = 0.02;      ///< shot-noise variance per DN of luma above black
    uint64_t seed = 1;            ///< noise seed
    int edge_subcells = 8;        ///< n: n×n sub-cells per marker outline pixel
    int board_subcells = 2;       ///< n: n×n sub-cells per checkerboard edge pixel (blurred fields: at most 2)
    int board_time_samples = 8;   ///< cap on the checkerboard's time samples per field
    double blur_step_px = 0.5;    ///< max marker motion between time samples, frame px
    int max_time_samples = 32;    ///< cap on time samples per field
};

/// Gives the scene geometry at time t_us (fills `out`, reusing its storage).
using GeometryAt = std::function<void(double t_us, SceneGeometry& out)>;

/// Renders the fields of one camera. Not thread-safe; one per camera and thread.
class CameraRenderer {
public:
    /// Precomputes rays, the static eye/background image and the noise table. `eye_radius_mm` 0 = no eye.
    CameraRenderer(const CameraModel& cam, int cam_index, const Eigen::Vector3d& eye_center_rig_mm,
                   double eye_radius_mm, const RenderOptions& opt);
    ~CameraRenderer();
    CameraRenderer(CameraRenderer&&) noexcept;
    CameraRenderer& operator=(CameraRenderer&&) noexcept;

    /// Renders the camera's field `index`: kFieldBytes of UYVY into `uyvy_out` (may be null: truth only) and
    /// one MarkerCameraTruth per geometry marker into `truth` (resized).
    void render_field(const GeometryAt& geometry, int64_t index, uint8_t* uyvy_out,
                      std::vector<MarkerCameraTruth>& truth);

    /// The noise-free image of the last rendered field: 720×288×3 floats (R, G, B code values), row-major.
    const std::vector<float>& last_rgb() const;
    /// The camera.
    const CameraModel& camera() const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace eyesim::rig
