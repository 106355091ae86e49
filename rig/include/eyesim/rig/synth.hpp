#pragma once
/// \file
/// The synthesiser: renders all cameras of the rig for a scenario and writes a recording directory
/// (rig.yaml, cam<k>.uyvy or a video cam<k>.mkv/.avi/.mpg/.mp4, truth.jsonl, manifest.json).

#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/camera.hpp"
#include "eyesim/rig/renderer.hpp"
#include "eyesim/rig/scenario.hpp"
#include "eyesim/rig/truth.hpp"

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace eyesim::rig {

/// Renders field i of every camera and its truth line.
class RigSynth {
public:
    /// One CameraRenderer per camera; the scenario must have been made from `bodies`.
    RigSynth(std::vector<CameraModel> cams, Bodies bodies, Scenario scenario, const RenderOptions& opt);

    /// Renders field `index` of every camera into `uyvy[c]` (kFieldBytes each; null entries: truth only) and
    /// fills `truth`.
    void render(int64_t index, const std::vector<uint8_t*>& uyvy, FieldTruth& truth);

    /// Cameras.
    const std::vector<CameraModel>& cameras() const noexcept { return cams_; }
    /// Markers in truth order.
    const std::vector<SceneMarker>& markers() const noexcept { return markers_; }
    /// The scenario.
    const Scenario& scenario() const noexcept { return scenario_; }

private:
    std::vector<CameraModel> cams_;
    Bodies bodies_;
    Scenario scenario_;
    std::vector<SceneMarker> markers_;
    std::vector<CameraRenderer> renderers_;
    std::vector<MarkerCameraTruth> cam_truth_;
};

/// What `write_recording` should produce.
struct SynthRequest {
    std::string out_dir;             ///< created if missing
    std::string scenario = "static"; ///< scenario_names()
    double seconds = 1.0;            ///< fields = round(seconds * 50) (video: rounded up to even)
    uint64_t seed = 1;               ///< scenario and noise seed
    std::string format = "uyvy";     ///< "uyvy" or a video format (video.hpp parse_video_format)
    std::string encoder_options;     ///< video: FFmpeg encoder options over the codec's ("crf=6"; VideoWriter)
    RenderOptions render;            ///< noise etc. (render.seed is set from seed)
    std::vector<CameraModel> cameras = default_rig();  ///< the rig
    std::string bodies_path = default_bodies_path();   ///< marker bodies
};

/// Result of `write_recording`.
struct SynthSummary {
    int64_t fields = 0;              ///< fields per camera
    int cameras = 0;                 ///< camera count
    double render_s = 0;             ///< wall time spent rendering
    double fields_per_s = 0;         ///< camera-fields rendered per second (all cameras)
    std::vector<std::string> files;  ///< files written (relative to out_dir)
    int64_t visible_marker_views = 0;  ///< (marker, camera, field) triples with visible == true
};

/// Writes a recording directory. `progress(done, total)` is called after each field (may be empty).
/// Throws RigError on bad requests or I/O failure.
SynthSummary write_recording(const SynthRequest& req, const std::function<void(int64_t, int64_t)>& progress = {});

}  // namespace eyesim::rig
