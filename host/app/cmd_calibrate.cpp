// `eyesim calibrate`: a rig.yaml from recorded video: intrinsics from a checkerboard recording (or a file),
// extrinsics and field clocks from a wand recording (FPGA model → ordered wand views → Ceres bundle adjustment),
// the rig frame from the mechanical eye at rest; progress line, JSON summary, HTML report.
#include "eyesim/app/command.hpp"
#include "eyesim/app/refine.hpp"
#include "eyesim/calibration/intrinsics.hpp"
#include "eyesim/calibration/wand.hpp"
#include "eyesim/calibration/wand_report.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/camera.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/recording.hpp"

#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace {

namespace cal = eyesim::calibration;
namespace rig = eyesim::rig;
using eyesim::app::Error;

struct CalibrateOptions {
    std::string board, wand, out, intrinsics, report, bodies, truth_rig;
    bool json = false;
    bool refine_intrinsics = false;
    bool refine = true;  // the refinement stage on the wand's blobs (--no-refine: the FPGA model's centroids)
    bool synchronised = false;
    int64_t max_fields = -1;
    int64_t min_samples = 30;
    int64_t eye_fields = 200;
};

/// A directory the user named that must exist.
void require_dir(const std::string& path, const char* option) {
    if (!std::filesystem::is_directory(path)) throw Error(fmt::format("{} {}: no such recording directory", option, path));
}

/// A recording's camera with only what the recording itself says (name, image size, field order, shutter):
/// pose, clock and intrinsics cleared, so none of its rig.yaml's calibration can reach the result.
rig::CameraModel unposed(const rig::CameraModel& c) {
    rig::CameraModel m;
    m.name = c.name;
    m.image_width = c.image_width;
    m.image_height = c.image_height;
    m.first_field_parity = c.first_field_parity;
    m.exposure_us = c.exposure_us;
    return m;
}

/// Prints the progress line on stderr (one line, rewritten in place).
class ProgressLine {
public:
    explicit ProgressLine(bool on) : on_(on) {}
    ~ProgressLine() { end(); }
    void show(const std::string& text) {
        if (!on_) return;
        const auto now = std::chrono::steady_clock::now();
        if (now - last_ < std::chrono::milliseconds(100) && text.size() == width_) return;
        last_ = now;
        std::fprintf(stderr, "\r%s%s", text.c_str(), text.size() < width_ ? std::string(width_ - text.size(), ' ').c_str() : "");
        width_ = text.size();
        shown_ = true;
    }
    void end() {
        if (on_ && shown_) std::fprintf(stderr, "\n");
        shown_ = false;
        width_ = 0;
    }

private:
    bool on_;
    bool shown_ = false;
    size_t width_ = 0;
    std::chrono::steady_clock::time_point last_{};
};

int run(const CalibrateOptions& opt) {
    require_dir(opt.wand, "--wand");
    if (!opt.board.empty()) require_dir(opt.board, "--board");
    const rig::Bodies bodies = rig::load_bodies(opt.bodies.empty() ? rig::default_bodies_path() : opt.bodies);
    if (!bodies.wand.present())
        throw Error(fmt::format("{}: no \"wand\" entry (the wand's markers and spacings)", opt.bodies.empty() ? rig::default_bodies_path() : opt.bodies));
    ProgressLine line(eyesim::app::show_progress(opt.json));
    cal::CalibrationSummary sum;
    sum.out = opt.out;
    sum.wand_dir = opt.wand;
    sum.board_dir = opt.board;
    sum.intrinsics_file = opt.intrinsics;
    const std::string report_dir = opt.report;

    // The wand recording: camera count, field order and shutter (the recording's metadata). Its intrinsics,
    // poses and clocks are never read.
    rig::Recording wand_rec = rig::Recording::open(opt.wand);
    // A recording's findings (at open, and fields a video could not give as they are read), printed as they come.
    auto flush_warnings = [&](rig::Recording& rec) {
        for (std::string& w : rec.take_warnings()) {
            line.end();
            std::fprintf(stderr, "eyesim: warning: %s\n", w.c_str());
            sum.warnings.push_back(std::move(w));
        }
    };
    flush_warnings(wand_rec);
    const int nc = wand_rec.camera_count();

    // Intrinsics.
    std::vector<rig::CameraModel> cams;
    sum.board.assign(static_cast<size_t>(nc), std::nullopt);
    if (!opt.intrinsics.empty()) {
        const std::vector<rig::CameraModel> file = rig::load_rig_yaml(opt.intrinsics);
        if (static_cast<int>(file.size()) != nc)
            throw Error(fmt::format("--intrinsics {}: {} cameras, the wand recording has {}", opt.intrinsics, file.size(), nc));
        for (int c = 0; c < nc; ++c) {
            rig::CameraModel m = unposed(wand_rec.cameras()[static_cast<size_t>(c)]);
            const rig::CameraModel& f = file[static_cast<size_t>(c)];
            m.fx = f.fx;
            m.fy = f.fy;
            m.cx = f.cx;
            m.cy = f.cy;
            m.dist = f.dist;
            m.max_r2 = f.max_r2;
            cams.push_back(m);
        }
    } else {
        rig::Recording board = rig::Recording::open(opt.board);
        flush_warnings(board);
        if (board.camera_count() != nc)
            throw Error(fmt::format("--board {}: {} cameras, the wand recording has {}", opt.board, board.camera_count(), nc));
        if (!report_dir.empty()) std::filesystem::create_directories(report_dir);
        for (int c = 0; c < nc; ++c) {
            cal::IntrinsicsOptions io;
            if (!report_dir.empty()) io.coverage_png = fmt::format("{}/board_cam{}.png", report_dir, c);
            const cal::IntrinsicsResult r = cal::calibrate_intrinsics(board, c, io, [&](const cal::ProgressInfo& p) {
                if (p.phase == cal::ProgressInfo::Phase::kDetect)
                    line.show(fmt::format("calibrate: board cam{} scan {}/{}, board seen {}", c, p.done, p.total,
                                          c < static_cast<int>(p.samples_per_camera.size()) ? p.samples_per_camera[static_cast<size_t>(c)] : 0));
                else
                    line.show(fmt::format("calibrate: board cam{} solving", c));
            });
            flush_warnings(board);
            rig::CameraModel m = unposed(wand_rec.cameras()[static_cast<size_t>(c)]);
            m.fx = r.camera.fx;
            m.fy = r.camera.fy;
            m.cx = r.camera.cx;
            m.cy = r.camera.cy;
            m.dist = r.camera.dist;
            m.max_r2 = r.camera.max_r2;
            cams.push_back(m);
            sum.board[static_cast<size_t>(c)] =
                cal::BoardFigures{r.rms_px, r.views_used, r.coverage,
                                  r.coverage_png.empty() ? std::string() : std::filesystem::path(r.coverage_png).filename().string()};
        }
        line.end();
    }

    // Wand: the FPGA model's blobs, the wand's views, the eye's still markers.
    const int wand_class = bodies.wand.markers.front().colour_class;
    std::unique_ptr<eyesim::app::BlobRefiner> refiner;
    cal::BlobRefine refine;
    if (opt.refine) {
        refiner = std::make_unique<eyesim::app::BlobRefiner>(eyesim::app::recording_sphere_fit_config(wand_rec));
        refine = [&](const uint8_t* field, std::vector<eyesim::fpga::Blob>& blobs) {
            refiner->refine(field, rig::kFieldHeight, blobs);
        };
    }
    const auto t0 = std::chrono::steady_clock::now();
    const cal::RecordingBlobs blobs = cal::detect_recording(
        wand_rec, opt.max_fields, wand_class, static_cast<int>(bodies.wand.markers.size()), refine,
        [&](const cal::ProgressInfo& p) {
            std::string s = fmt::format("calibrate: wand field {}/{}, wand seen:", p.done, p.total);
            for (size_t c = 0; c < p.samples_per_camera.size(); ++c) s += fmt::format(" cam{} {}", c, p.samples_per_camera[c]);
            line.show(s);
        });
    sum.detect_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    flush_warnings(wand_rec);
    sum.fields = blobs.fields;
    sum.views = cal::find_wand_views(blobs, bodies.wand, cams);
    // The eye's markers fix the rig frame: their images from the refinement stage's sphere fit (less biased than
    // the pipeline's centroids), on --eye-fields fields spread over the recording (they keep still).
    eyesim::app::BlobRefiner eye_refiner(eyesim::app::recording_sphere_fit_config(wand_rec));
    line.show(fmt::format("calibrate: the eye's marker images on {} fields (rig frame)", opt.eye_fields));
    const cal::EyeImages eye = cal::eye_images(
        wand_rec, bodies.eye.markers.front().colour_class, opt.eye_fields, opt.max_fields,
        [&](const uint8_t* field, std::vector<eyesim::fpga::Blob>& b) { eye_refiner.refine(field, rig::kFieldHeight, b); });
    flush_warnings(wand_rec);

    cal::WandOptions wo;
    wo.refine_intrinsics = opt.refine_intrinsics;
    wo.synchronised = opt.synchronised;
    wo.min_samples_per_camera = opt.min_samples;
    sum.solve = cal::solve_wand(sum.views, cams, bodies.wand, wo, [&](const cal::ProgressInfo& p) {
        std::string s = "calibrate: wand views";
        for (int c = 0; c < nc; ++c) s += fmt::format(" cam{} {}", c, sum.views.accepted(c));
        line.show(s + fmt::format("; solve ({}) iteration {}, cost {:.6g}", p.stage, p.done, p.cost));
    });
    line.end();

    // The rig frame from the eye at rest, then the cameras in it.
    sum.rig_frame = cal::fit_rig_frame(eye, sum.solve.cameras, bodies.eye);
    sum.cameras = cal::to_rig_frame(sum.solve.cameras, sum.rig_frame);
    for (int c = 0; c < nc; ++c) sum.cameras[static_cast<size_t>(c)].name = fmt::format("cam{}", c);
    rig::save_rig_yaml(opt.out, sum.cameras);

    // Scoring only: the true rig is read after everything above.
    if (!opt.truth_rig.empty()) {
        sum.truth_file = opt.truth_rig;
        sum.truth = cal::compare_with_truth(sum.cameras, rig::load_rig_yaml(opt.truth_rig), bodies.eye);
    }
    for (int c = 0; c < nc; ++c) {
        const cal::WandCameraStats& st = sum.solve.stats[static_cast<size_t>(c)];
        if (st.coverage < 0.25) {
            const std::string w = fmt::format("cam{}: the wand covered only {:.0f} % of the image (wave it nearer the "
                                              "image edges for a better distortion estimate)",
                                              c, 100.0 * st.coverage);
            std::fprintf(stderr, "eyesim: warning: %s\n", w.c_str());
            sum.warnings.push_back(w);
        }
    }
    std::string index;
    if (!report_dir.empty()) index = cal::write_report(report_dir, sum);

    if (opt.json) {
        nlohmann::json j = cal::summary_json(sum);
        if (!index.empty()) j["report"] = index;
        std::printf("%s\n", j.dump().c_str());
        return 0;
    }
    std::printf("%s: %d cameras from %lld wand samples (%lld fields), %d iterations, solve %.2f s\n", opt.out.c_str(), nc,
                static_cast<long long>(sum.solve.samples), static_cast<long long>(sum.fields), sum.solve.iterations,
                sum.solve.solve_s);
    for (int c = 0; c < nc; ++c) {
        const cal::WandCameraStats& st = sum.solve.stats[static_cast<size_t>(c)];
        std::printf("  cam%d: %lld samples, image error %.4f field px RMS, world error %.4f mm, field time offset %.1f us, "
                    "coverage %.0f %%",
                    c, static_cast<long long>(st.samples), st.image_error_px_rms, st.world_error_mm,
                    sum.cameras[static_cast<size_t>(c)].field_time_offset_us, 100.0 * st.coverage);
        if (const auto& b = sum.board[static_cast<size_t>(c)]) std::printf(", board %.4f px RMS over %d views", b->rms_px, b->views_used);
        std::printf("\n");
        if (!sum.truth.empty()) {
            const cal::CameraTruthError& e = sum.truth[static_cast<size_t>(c)];
            std::printf("        vs truth: centre %.1f um, rotation %.5f deg, fx %+.4f %%, fy %+.4f %%, projection %.4f px RMS\n",
                        e.centre_error_um, e.rotation_error_deg, e.fx_error_pct, e.fy_error_pct, e.projection_error_px_rms);
        }
    }
    const auto& wl = sum.solve.wand_length_error_mm;
    if (!wl.empty()) {
        double s2 = 0, s1 = 0;
        for (double e : wl) {
            s1 += e;
            s2 += e * e;
        }
        std::printf("  wand length: error mean %.2f um, RMS %.2f um over %zu samples\n", 1e3 * s1 / static_cast<double>(wl.size()),
                    1e3 * std::sqrt(s2 / static_cast<double>(wl.size())), wl.size());
    }
    std::printf("  rig frame: %d eye markers, %d images (%d left out), %.1f um RMS, %.4f px RMS\n", sum.rig_frame.markers,
                sum.rig_frame.views, sum.rig_frame.views_dropped, sum.rig_frame.residual_mm_rms * 1e3,
                sum.rig_frame.residual_px_rms);
    if (!index.empty()) std::printf("  report: %s\n", index.c_str());
    return 0;
}

eyesim::app::Registrar reg{"calibrate", "Calibrate the rig from recordings: a checkerboard (intrinsics) and a wand (extrinsics)",
                           [](CLI::App& sub) {
    auto opt = std::make_shared<CalibrateOptions>();
    auto* board = sub.add_option("--board", opt->board, "checkerboard recording (intrinsics of every camera)");
    sub.add_option("--wand", opt->wand, "wand recording: the wand waved through the working volume, the eye at rest")
        ->required();
    sub.add_option("--out", opt->out, "rig.yaml to write")->required();
    auto* intr = sub.add_option("--intrinsics", opt->intrinsics,
                                "rig.yaml whose intrinsics (K, distortion, max_r2) to use instead of --board; its "
                                "poses and clocks are ignored");
    board->excludes(intr);
    sub.add_option("--report", opt->report, "write index.html and PNG plots into this directory");
    sub.add_flag("--json", opt->json, "print one JSON summary object on stdout");
    sub.add_flag("--refine-intrinsics", opt->refine_intrinsics,
                 "also refine K and distortion in the wand bundle adjustment");
    sub.add_flag("--refine,!--no-refine", opt->refine,
                 "wand blob centroids from the refinement stage's shaded-sphere fit (the default; calibration is "
                 "offline), or with --no-refine the FPGA model's centroids alone");
    sub.add_flag("--synchronised", opt->synchronised,
                 "the cameras share one field clock (default: solve each camera's time offset)");
    sub.add_option("--fields", opt->max_fields, "use at most this many wand fields per camera")
        ->check(CLI::Range(int64_t{1}, int64_t{1} << 40));
    sub.add_option("--min-samples", opt->min_samples, "fewest wand samples a camera may have (default 30)")
        ->check(CLI::Range(int64_t{5}, int64_t{1} << 40));
    sub.add_option("--eye-fields", opt->eye_fields,
                   "fields (spread over the recording) whose eye-marker images are refined and averaged for the rig "
                   "frame (default 200)")
        ->check(CLI::Range(int64_t{2}, int64_t{1} << 40));
    sub.add_option("--bodies", opt->bodies, "marker bodies JSON with the wand and the eye (default: scenes/bodies.json)");
    sub.add_option("--truth-rig", opt->truth_rig,
                   "true rig.yaml of a synthetic recording: read after the solve, to report the errors against it");
    return [opt]() -> int {
        if (opt->board.empty() && opt->intrinsics.empty())
            throw Error("calibrate: intrinsics needed: --board DIR (a checkerboard recording) or --intrinsics rig.yaml", 2);
        try {
            return run(*opt);
        } catch (const rig::RigError& e) {
            throw Error(e.what());
        } catch (const cal::CalibrationError& e) {
            throw Error(fmt::format("calibrate: {}", e.what()));
        }
    };
}};

}  // namespace
