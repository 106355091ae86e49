#pragma once
/// \file
/// What a simulator run tells people: the paper's Table 4 with this machine's figures beside the paper's,
/// tracking accuracy against truth, latency, scores and events; printed as text, summarised as JSON, and
/// written as a report folder (index.html with stereo snapshots and plots).

#include "eyesim/app/frame_loop.hpp"

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include <array>

#include <cstdio>
#include <memory>
#include <string>
#include <vector>

namespace eyesim::render {
class SceneRenderer;
struct StereoImages;
}

namespace eyesim::app {

/// Tracking accuracy of a run against the rig's ground truth.
struct AccuracySummary {
    bool available = false;          ///< the source had truth
    size_t frames = 0;               ///< frames scored
    double marker3d_rms_um = 0, marker3d_p95_um = 0;
    double tip_rms_um = 0, tip_p95_um = 0;
    double eye_rot_rms_deg = 0;
};

/// One stereo snapshot written to the report folder.
struct Snapshot {
    double time_s;        ///< scene time
    std::string file;     ///< file name inside the report folder
};

/// A copy of what a picture shows (tissue and posed instruments, eye frame), taken during a run and rendered
/// after it, so that rendering never delays the frames being tracked.
struct SceneCopy {
    double time_s = 0;                                     ///< scene time
    size_t frame = 0;                                      ///< frame index (its render time goes there)
    std::vector<Eigen::Vector3f> tissue_vertices_eye_mm;
    std::vector<std::array<uint32_t, 3>> tissue_triangles;
    bool tissue_is_retina = false;
    struct Inst {
        std::vector<Eigen::Vector3f> vertices_eye_mm;
        const std::vector<std::array<uint32_t, 3>>* triangles = nullptr;  ///< owned by the simulator's instrument
        Eigen::Vector3f tip_eye_mm, forward_eye;
        bool light = false;
    };
    std::vector<Inst> instruments;
    std::vector<Eigen::Vector3f> highlight_eye_mm;         ///< grabbed nodes
};

/// Copies the simulator's current state for a later picture.
SceneCopy copy_scene(const Simulator& sim);

/// Renders stereo microscope snapshots of the simulator state (EGL; headless with Mesa).
class Snapshotter {
public:
    /// Null renderer (and a reason) when EGL is unavailable: snapshots are then skipped, never fatal.
    Snapshotter(int width, int height);
    ~Snapshotter();
    /// Whether pictures can be made.
    bool available() const { return renderer_ != nullptr; }
    /// Why not, when not.
    const std::string& error() const { return error_; }
    /// GL renderer name.
    std::string renderer_name() const;
    /// Renders a copied state to `path` (side-by-side PNG). Returns false with `error()` set.
    bool snap(const SceneCopy& scene, const std::string& path);
    /// The scene's rigid training objects (case 3), drawn in every picture like instruments: shaded, casting
    /// shadows from the light pipe. They do not move, so they are meshed once here.
    void set_objects(const std::vector<sim::collision::ConvexObject>& objects);
    /// Renders a copied state into `out` (both views).
    bool render(const SceneCopy& scene, render::StereoImages& out);

private:
    std::unique_ptr<render::SceneRenderer> renderer_;
    std::string error_;
    std::vector<sim::TriangleMesh> objects_;  // eye frame
};

/// Writes `frames` as a side-by-side stereo animation (H.264 MP4 through OpenCV's FFmpeg back-end, MPEG-4 part 2
/// if H.264 is missing) at `fps`. False and a one-line reason in `error` on failure.
bool write_animation(const std::string& path, const std::vector<SceneCopy>& frames, double fps, Snapshotter& renderer,
                     std::string& error);

/// Everything a report needs.
struct RunReport {
    std::string title;                   ///< e.g. "eyesim demo: membrane-peel"
    std::string source;                  ///< where the markers came from
    std::string link_end;                ///< live runs: how the link ended ("device closed the link", …)
    const Simulator* sim = nullptr;      ///< the run
    const RunStats* stats = nullptr;     ///< counters and latencies (may be null)
    AccuracySummary accuracy;            ///< against truth, when available
    std::vector<Snapshot> snapshots;     ///< pictures taken
    std::string animation;               ///< file name of the stereo animation ("" when none)
    size_t animation_frames = 0;         ///< its frames
    std::string renderer;                ///< GL renderer used for pictures ("" when none)
    std::vector<std::string> warnings;   ///< non-fatal findings
};

/// The loss counters as a JSON object (docs/host.md: `sequence_gaps`, `frames_lost`, `resyncs`, …).
nlohmann::json loss_json(const LossCounts& c);

/// The latency figures of a run, each a difference of two named clocks: `latency_us` (field end → poses ready),
/// `transfer_us` (field end → received), `ready_after_receive_us` (received → poses ready, host clock only),
/// each {p50, p99, max, frames} or null with `latency_note` saying why.
nlohmann::json latency_json(const RunStats& s);

/// One text line of the latency figures (or why they are missing).
std::string latency_line(const RunStats& s);

/// Precision mode's counters (`--precision`): {patches, refined, refused {chi2, shift, …}, refused_total,
/// missing_patch, unmatched_patches, incomplete_patches, refined_fraction}, or null when precision mode was off.
nlohmann::json precision_json(const RunStats& s);

/// One text line of precision mode's counters ("" when it was off).
std::string precision_line(const RunStats& s);

/// Prints the Table-4 breakdown (this machine beside the paper), accuracy, latency, scores and events.
void print_report(std::FILE* out, const RunReport& r);

/// `s` with <, > and & escaped for HTML text.
std::string html_escape(const std::string& s);

/// The run as one JSON object (keys as in docs: `_us`, `_um`, `_deg`, `latency_us` {p50,p99,max}, …).
nlohmann::json report_json(const RunReport& r);

/// Writes `dir`/index.html with the tables, snapshots and plots (stage times, latency, tip path). Returns the
/// path of index.html. Throws Error when the folder cannot be written.
std::string write_report(const std::string& dir, const RunReport& r);

}  // namespace eyesim::app
