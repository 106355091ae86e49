// `eyesim validate`: FPGA model → FieldMarkers packets (the firmware's wire conversion, encoded and parsed) →
// tracking, over a recording (with or without ground truth) or a capture; accuracy against the truth where there is
// one, the truth-free figures (residuals, marker-pair distances, eye-centre stability, dropouts) always, latency and
// drop statistics, optional HTML report.
#include "eyesim/app/command.hpp"
#include "eyesim/app/refine.hpp"
#include "eyesim/app/report.hpp"

#include "eyesim/firmware/latency.hpp"
#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/fpga/register_map.hpp"
#include "eyesim/fpga/timing.hpp"
#include "eyesim/fpga/wire.hpp"
#include "eyesim/frame/session.hpp"
#include "eyesim/protocol/capture.hpp"
#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/stream_parser.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/match.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/truth.hpp"
#include "eyesim/tracking/rig_adapter.hpp"
#include "eyesim/tracking/tracker.hpp"
#include "eyesim/tracking/truth_free.hpp"
#include "eyesim/tracking/validation.hpp"

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <optional>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

namespace tr = eyesim::tracking;
namespace rig = eyesim::rig;
namespace proto = eyesim::protocol;
using eyesim::app::html_escape;
using eyesim::app::Error;

struct ValidateOptions {
    std::string dir;
    std::string capture;
    std::string rig;
    std::string report;
    bool json = false;
    int max_fields = 0;
    std::string sync = "interpolate";
    bool no_trocar = false;
    bool no_image_model = false;
    double truth_noise_px = 0.02;
    bool truth_projected = false;
    std::string write_capture;
    double sigma_px = 0.05;
    std::string bodies;
    std::uint64_t seed = 1;
    bool refine = false;
    bool no_hints = false;  ///< --refine without occlusion hints: every fit a whole sphere
    std::string emit = "field";  ///< device emission: "field" (a field's parts at its end) or "blob" (low latency)
    double report_delay_ms = 19.0;  ///< --sync async: fixed-lag frames this long after exposure (0: each part at once)
};

/// Everything collected from one tracking run.
struct RunStats {
    std::string name;
    std::vector<double> marker_err_um, marker_err_eye_um, marker_err_inst_um, marker_err_occluded_um;
    // Every marker matched to a truth marker, the flagged ones included: leaving markers out cannot improve it.
    std::vector<double> marker_err_all_um;
    std::vector<double> tip_err_um, tip_eye_err_um, axis_err_deg, insertion_err_um, eye_err_deg;
    std::vector<double> tip_in_eye_err_um;  // the tips the truth puts inside the eye
    std::vector<double> latency_end_to_ready_us, latency_end_to_received_us, latency_sample_to_ready_us;
    std::vector<double> compute_us;
    // Display-time prediction (async filters): the pose predicted to the next reference field's exposure mid (about
    // when the pose is ready), against that field's truth; and the same with the pose held, for comparison.
    std::vector<double> predicted_tip_err_um, predicted_eye_err_deg, held_tip_err_um, held_eye_err_deg,
        prediction_horizon_us;
    // Per frame, for the time plot: time (s), marker RMS (µm), tip error per instrument (µm, −1 if none).
    std::vector<double> frame_t_s, frame_marker_rms_um, frame_eye_deg;
    std::vector<std::vector<double>> frame_tip_um;
    // Per scored marker, for the volume plot.
    std::vector<Eigen::Vector3d> marker_pos_mm;
    std::vector<double> marker_pos_err_um;
    long frames = 0, two_view_frames = 0, too_few_camera_frames = 0, ghosts = 0, images_dropped_sync = 0,
         images_unmatched = 0, markers_unassigned = 0, truth_visible2 = 0, eye_held = 0;
    long eye_model_views = 0;  // views the eye's model corrected and the poses used (Tracker::eye_model_views)
    long time_ordered_parts = 0;  // low-latency parts fused at their own time, before newer ones (per body)
    long smoothed_poses = 0;      // fixed-lag frames' body poses smoothed by later parts
    std::vector<long> tip_held;
};

/// Per-camera centroid comparison (FPGA path only). `err_px` by this command's rule; `fpga_rule_err_px` by the
/// rule of `eyesim fpga` (see kCentroidRules), so that the report can show both.
struct CentroidStats {
    std::vector<double> err_px, fpga_rule_err_px;
    long blobs = 0, matched = 0, missed = 0, spurious = 0, fields_with_drops = 0, fpga_rule_missed = 0;
};

/// Why `eyesim fpga` and `eyesim validate` give different centroid figures for the same recording.
constexpr const char* kCentroidRules =
    "Both commands match each truth marker to the nearest unused blob of its colour class (rig/match.hpp) and "
    "measure the distance in field pixels to the rendered intensity centroid. They score different markers with "
    "different gates: `eyesim fpga` scores every marker with a visible rendered area of at least 2 field px, partly "
    "hidden ones included, with a 3 px gate, on the pipeline's blobs as they leave the FPGA model; `eyesim validate` "
    "scores only markers with no part hidden (occluded_fraction 0), with a 1.5 px gate, on the blobs after the wire "
    "conversion (Q16.16 coordinates, encoded and parsed back), and counts a marker as missed only when its area is at "
    "least 4 px. Partly hidden markers (markers crossing, the eye's rim, the instruments' shafts) and matches between "
    "1.5 and 3 px therefore enter `fpga`'s RMS and not `validate`'s.";

double us_now() {
    return std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

/// One FieldMarkers message with its modelled host receive time.
struct Timed {
    double received_us;
    proto::FieldMarkers msg;
};

/// Feeds messages of one field index into the tracker (in receive order) and scores the frames that come out:
/// against the truth when there is one (`truth` may be empty), and by the truth-free checks always.
class Runner {
public:
    Runner(std::string name, const tr::TrackerConfig& cfg, const std::vector<rig::FieldTruth>& truth,
           const tr::InstrumentModel* wand)
        : tracker_(cfg), bodies_(cfg.bodies), truth_(truth), free_(cfg.bodies, int(cfg.cameras.size()), wand) {
        stats_.name = std::move(name);
        stats_.tip_held.assign(std::size_t(cfg.bodies.instrument_count), 0);
        stats_.frame_tip_um.resize(std::size_t(cfg.bodies.instrument_count));
    }

    void push(std::vector<Timed>& msgs) {
        std::stable_sort(msgs.begin(), msgs.end(),
                         [](const Timed& a, const Timed& b) { return a.received_us < b.received_us; });
        for (const Timed& t : msgs) {
            // A fixed-lag frame that falls due before this message goes at its time, as a host's timer sends it.
            for (double due = tracker_.next_report_host_us(); due < t.received_us; due = tracker_.next_report_host_us())
                drain(due);
            tracker_.push(t.msg, t.received_us);
            drain(t.received_us);
        }
    }

    void finish(double now_us) {
        tracker_.finish();
        drain(now_us);
        stats_.eye_model_views = long(tracker_.eye_model_views());
        stats_.time_ordered_parts = long(tracker_.time_ordered_parts());
        stats_.smoothed_poses = long(tracker_.smoothed_poses());
    }

    RunStats& stats() { return stats_; }
    const tr::TruthFreeStats& truth_free() const { return free_; }
    /// The newest frame the tracker gave (nullptr before the first).
    const tr::TrackingFrame* last_frame() const { return stats_.frames > 0 ? &frame_ : nullptr; }

private:
    void drain(double now_us) {
        while (tracker_.pop(frame_, now_us)) score();
    }

    void score() {
        RunStats& s = stats_;
        free_.add(tracker_, frame_);  // before anything else: it reads the tracker's images of this frame
        ++s.frames;
        if (frame_.flags & tr::kFrameTwoView) ++s.two_view_frames;
        if (frame_.flags & tr::kFrameTooFewCameras) ++s.too_few_camera_frames;
        s.images_dropped_sync += frame_.images_dropped_sync;
        s.images_unmatched += frame_.markers.unmatched_images;
        s.markers_unassigned += frame_.markers_unassigned;
        s.compute_us.push_back(frame_.timing.compute_us);
        if (frame_.timing.field_end_host_us > 0) {  // 0: a frame from a part of a field still being read out
            s.latency_end_to_ready_us.push_back(frame_.timing.poses_ready_host_us - frame_.timing.field_end_host_us);
            s.latency_end_to_received_us.push_back(frame_.timing.received_host_us - frame_.timing.field_end_host_us);
        }
        s.latency_sample_to_ready_us.push_back(frame_.timing.poses_ready_host_us - frame_.timing.sample_host_us);
        if (frame_.reference_field >= truth_.size()) return;
        const rig::FieldTruth& truth = truth_[frame_.reference_field];
        score_prediction(truth);
        const tr::FrameScore fs = tr::score_frame(frame_, bodies_, truth);
        s.ghosts += fs.ghosts;
        s.truth_visible2 += fs.truth_markers_visible2;
        double ss = 0;
        for (const tr::MarkerScore& m : fs.markers) {
            const double e = m.error_mm * 1e3;
            s.marker_err_all_um.push_back(e);
            if (m.occluded) {  // flagged by the tracker as biased: reported apart
                s.marker_err_occluded_um.push_back(e);
                continue;
            }
            s.marker_err_um.push_back(e);
            (m.truth_eye ? s.marker_err_eye_um : s.marker_err_inst_um).push_back(e);
            s.marker_pos_mm.push_back(m.truth_rig_mm);
            s.marker_pos_err_um.push_back(e);
            ss += e * e;
        }
        s.frame_t_s.push_back(truth.t_us * 1e-6);
        s.frame_marker_rms_um.push_back(fs.markers.empty() ? -1.0 : std::sqrt(ss / double(fs.markers.size())));
        s.frame_eye_deg.push_back(fs.eye_error_deg);
        if (fs.eye_error_deg >= 0) s.eye_err_deg.push_back(fs.eye_error_deg); else ++s.eye_held;
        for (std::size_t b = 0; b < fs.tip_error_mm.size(); ++b) {
            s.frame_tip_um[b].push_back(fs.tip_error_mm[b] >= 0 ? fs.tip_error_mm[b] * 1e3 : -1.0);
            if (fs.tip_error_mm[b] < 0) {
                ++s.tip_held[b];
                continue;
            }
            s.tip_err_um.push_back(fs.tip_error_mm[b] * 1e3);
            if (b < fs.tip_in_eye.size() && fs.tip_in_eye[b]) s.tip_in_eye_err_um.push_back(fs.tip_error_mm[b] * 1e3);
            s.tip_eye_err_um.push_back(fs.tip_eye_error_mm[b] * 1e3);
            s.axis_err_deg.push_back(fs.axis_error_deg[b]);
            if (fs.insertion_error_mm[b] >= 0) s.insertion_err_um.push_back(fs.insertion_error_mm[b] * 1e3);
        }
    }

    // Async filters only: the poses predicted from the filters' state now (nothing of the next field fused yet) to
    // the next reference field's instant, scored against its truth, beside the frame's own poses held to then.
    void score_prediction(const rig::FieldTruth& truth) {
        if (tracker_.config().sync.mode != tr::SyncMode::Async || frame_.reference_field + 1 >= truth_.size()) return;
        const rig::FieldTruth& next = truth_[frame_.reference_field + 1];
        const double horizon_us = next.t_us - truth.t_us;
        if (!(horizon_us > 0.0)) return;
        predicted_ = frame_;
        if (!tracker_.pose_at(frame_.time_device_us + horizon_us, predicted_.eye,
                              std::span(predicted_.instruments.data(), std::size_t(predicted_.instrument_count))))
            return;
        RunStats& s = stats_;
        s.prediction_horizon_us.push_back(horizon_us);
        const tr::FrameScore ps = tr::score_frame(predicted_, bodies_, next);
        const tr::FrameScore hs = tr::score_frame(frame_, bodies_, next);
        if (ps.eye_error_deg >= 0 && hs.eye_error_deg >= 0) {
            s.predicted_eye_err_deg.push_back(ps.eye_error_deg);
            s.held_eye_err_deg.push_back(hs.eye_error_deg);
        }
        for (std::size_t b = 0; b < ps.tip_error_mm.size() && b < hs.tip_error_mm.size(); ++b)
            if (ps.tip_error_mm[b] >= 0 && hs.tip_error_mm[b] >= 0) {
                s.predicted_tip_err_um.push_back(ps.tip_error_mm[b] * 1e3);
                s.held_tip_err_um.push_back(hs.tip_error_mm[b] * 1e3);
            }
    }

    tr::Tracker tracker_;
    tr::BodySet bodies_;
    const std::vector<rig::FieldTruth>& truth_;
    tr::TruthFreeStats free_;
    tr::TrackingFrame frame_, predicted_;
    RunStats stats_;
};

/// The bodies file's calibration wand as an instrument-like body (origin at marker 0, +z along the rod) for the
/// truth-free checks; nullopt when the file has none.
std::optional<tr::InstrumentModel> wand_model(const rig::Bodies& bodies) {
    if (!bodies.wand.present() || bodies.wand.markers.size() > std::size_t(tr::kMaxBodyMarkers)) return std::nullopt;
    tr::InstrumentModel m;
    m.name = "wand";
    for (std::size_t i = 0; i < bodies.wand.markers.size(); ++i) {
        tr::BodyMarker& b = m.markers[std::size_t(m.marker_count++)];
        b.colour_class = std::uint8_t(bodies.wand.markers[i].colour_class);
        b.pos_body_mm = bodies.wand.marker_position_mm(i);
    }
    return m;
}

/// A progress line on stderr with the time left, at most five times a second; only when `on` (stderr a terminal,
/// no --json: eyesim::app::show_progress).
class Progress {
public:
    Progress(bool on, std::string what, std::string unit) : on_(on), what_(std::move(what)), unit_(std::move(unit)) {}
    Progress(const Progress&) = delete;
    Progress& operator=(const Progress&) = delete;
    ~Progress() { end(); }

    /// `done` of `total` (total ≤ 0: unknown, no time left shown).
    void update(long done, long total) {
        if (!on_) return;
        const double now = us_now();
        if (done < total && now - last_us_ < 2e5) return;
        last_us_ = now;
        const double elapsed_s = (now - t0_us_) * 1e-6;
        std::string line = total > 0 ? fmt::format("{}: {}/{} {}, {} elapsed", what_, done, total, unit_, duration(elapsed_s))
                                     : fmt::format("{}: {} {}, {} elapsed", what_, done, unit_, duration(elapsed_s));
        if (total > 0 && done > 0 && done < total)
            line += fmt::format(", about {} left", duration(elapsed_s * double(total - done) / double(done)));
        std::fprintf(stderr, "\r%-*s", int(std::max<std::size_t>(width_, line.size())), line.c_str());
        width_ = line.size();
        shown_ = true;
    }

    /// Ends the line (once).
    void end() {
        if (shown_) std::fprintf(stderr, "\n");
        shown_ = false;
    }

private:
    static std::string duration(double s) {
        if (s < 10) return fmt::format("{:.1f} s", s);
        if (s < 60) return fmt::format("{:.0f} s", s);
        return fmt::format("{} min {:02} s", long(s) / 60, long(s) % 60);
    }
    bool on_;
    std::string what_, unit_;
    double t0_us_ = us_now(), last_us_ = -1e18;
    std::size_t width_ = 0;
    bool shown_ = false;
};

// ------------------------------------------------------------------------------------------------------------
// Plots (OpenCV drawing)
// ------------------------------------------------------------------------------------------------------------

const cv::Scalar kInk(30, 30, 30), kGrid(215, 215, 215), kBg(255, 255, 255);
const std::array<cv::Scalar, 4> kSeries{cv::Scalar(180, 90, 20), cv::Scalar(30, 120, 230), cv::Scalar(40, 160, 40),
                                        cv::Scalar(160, 40, 160)};

struct Axes {
    cv::Mat img;
    cv::Rect area;
    double x0, x1, y0, y1;
    cv::Point map(double x, double y) const {
        const double u = (x - x0) / std::max(x1 - x0, 1e-12), v = (y - y0) / std::max(y1 - y0, 1e-12);
        return {area.x + int(std::lround(u * area.width)), area.y + area.height - int(std::lround(v * area.height))};
    }
};

Axes make_axes(const std::string& title, const std::string& xlabel, const std::string& ylabel, double x0, double x1,
               double y0, double y1, int w = 760, int h = 440) {
    Axes a{cv::Mat(h, w, CV_8UC3, kBg), cv::Rect(80, 40, w - 110, h - 100), x0, x1, y0, y1};
    cv::putText(a.img, title, {80, 26}, cv::FONT_HERSHEY_SIMPLEX, 0.6, kInk, 1, cv::LINE_AA);
    for (int k = 0; k <= 5; ++k) {
        const double x = x0 + (x1 - x0) * k / 5.0, y = y0 + (y1 - y0) * k / 5.0;
        const cv::Point px = a.map(x, y0), py = a.map(x0, y);
        cv::line(a.img, {px.x, a.area.y}, {px.x, a.area.y + a.area.height}, kGrid);
        cv::line(a.img, {a.area.x, py.y}, {a.area.x + a.area.width, py.y}, kGrid);
        cv::putText(a.img, fmt::format("{:.4g}", x), {px.x - 18, a.area.y + a.area.height + 18},
                    cv::FONT_HERSHEY_SIMPLEX, 0.4, kInk, 1, cv::LINE_AA);
        cv::putText(a.img, fmt::format("{:.4g}", y), {8, py.y + 4}, cv::FONT_HERSHEY_SIMPLEX, 0.4, kInk, 1,
                    cv::LINE_AA);
    }
    cv::rectangle(a.img, a.area, kInk);
    cv::putText(a.img, xlabel, {a.area.x + a.area.width / 2 - 60, h - 22}, cv::FONT_HERSHEY_SIMPLEX, 0.5, kInk, 1,
                cv::LINE_AA);
    cv::putText(a.img, ylabel, {8, 26 + 0}, cv::FONT_HERSHEY_SIMPLEX, 0.45, kInk, 1, cv::LINE_AA);
    return a;
}

void save_png(const std::string& path, const cv::Mat& img) {
    if (!cv::imwrite(path, img)) throw Error(path + ": cannot write PNG");
}

double percentile_of(std::vector<double> v, double q) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, std::size_t(q * double(v.size())))];
}

void plot_histogram(const std::string& path, const std::string& title, const std::string& xlabel,
                    const std::vector<std::pair<std::string, std::vector<double>>>& sets) {
    double hi = 0;
    for (const auto& s : sets) hi = std::max(hi, percentile_of(s.second, 0.995));
    hi = hi > 0 ? hi * 1.05 : 1.0;
    const int bins = 40;
    std::vector<std::vector<double>> frac(sets.size(), std::vector<double>(bins, 0.0));
    double top = 0;
    for (std::size_t k = 0; k < sets.size(); ++k) {
        for (double v : sets[k].second) frac[k][std::size_t(std::clamp(int(v / hi * bins), 0, bins - 1))] += 1.0;
        for (double& f : frac[k]) {
            f /= std::max<double>(1.0, double(sets[k].second.size()));
            top = std::max(top, f);
        }
    }
    Axes a = make_axes(title, xlabel, "fraction", 0, hi, 0, top > 0 ? top * 1.1 : 1.0);
    for (std::size_t k = 0; k < sets.size(); ++k) {
        for (int b = 0; b < bins; ++b) {
            const cv::Point p0 = a.map(hi * b / bins, 0), p1 = a.map(hi * (b + 1) / bins, frac[k][std::size_t(b)]);
            if (sets.size() == 1) cv::rectangle(a.img, p0, p1, kSeries[k], cv::FILLED);
            cv::rectangle(a.img, p0, p1, kSeries[k % kSeries.size()], 1);
        }
        cv::putText(a.img, fmt::format("{} (n={})", sets[k].first, sets[k].second.size()),
                    {a.area.x + a.area.width - 260, a.area.y + 20 + 18 * int(k)}, cv::FONT_HERSHEY_SIMPLEX, 0.45,
                    kSeries[k % kSeries.size()], 1, cv::LINE_AA);
    }
    save_png(path, a.img);
}

void plot_series(const std::string& path, const std::string& title, const std::string& ylabel,
                 const std::vector<double>& t, const std::vector<std::pair<std::string, std::vector<double>>>& ys) {
    double hi = 0;
    for (const auto& y : ys) hi = std::max(hi, percentile_of(y.second, 0.995));
    hi = hi > 0 ? hi * 1.1 : 1.0;
    const double t0 = t.empty() ? 0 : t.front(), t1 = t.empty() ? 1 : std::max(t.back(), t0 + 1e-3);
    Axes a = make_axes(title, "time (s)", ylabel, t0, t1, 0, hi);
    for (std::size_t k = 0; k < ys.size(); ++k) {
        cv::Point prev(-1, -1);
        for (std::size_t i = 0; i < t.size() && i < ys[k].second.size(); ++i) {
            const double v = ys[k].second[i];
            if (v < 0) {  // not measured in this frame: gap in the line, tick at the bottom
                cv::line(a.img, a.map(t[i], 0), a.map(t[i], 0) + cv::Point(0, -4), cv::Scalar(0, 0, 200));
                prev = {-1, -1};
                continue;
            }
            const cv::Point p = a.map(t[i], std::min(v, hi));
            if (prev.x >= 0) cv::line(a.img, prev, p, kSeries[k % kSeries.size()], 1, cv::LINE_AA);
            prev = p;
        }
        cv::putText(a.img, ys[k].first, {a.area.x + 10, a.area.y + 20 + 18 * int(k)}, cv::FONT_HERSHEY_SIMPLEX,
                    0.45, kSeries[k % kSeries.size()], 1, cv::LINE_AA);
    }
    save_png(path, a.img);
}

/// Marker error across the working volume: two projections (x–y from below, x–z from the side), colour = error.
void plot_volume(const std::string& path, const std::vector<Eigen::Vector3d>& pos, const std::vector<double>& err) {
    cv::Mat img(460, 1000, CV_8UC3, kBg);
    const double emax = std::max(25.0, percentile_of(err, 0.99));
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e9), hi = Eigen::Vector3d::Constant(-1e9);
    for (const auto& p : pos) {
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
    }
    if (pos.empty()) lo.setConstant(-1), hi.setConstant(1);
    const double span = std::max((hi - lo).maxCoeff(), 1.0) * 1.05;
    const Eigen::Vector3d mid = 0.5 * (lo + hi);
    const std::array<std::pair<int, int>, 2> planes{{{0, 1}, {0, 2}}};
    const std::array<const char*, 2> names{"x-y (rig, from below)", "x-z (rig, side)"};
    // Largest errors drawn last so they stay visible.
    std::vector<std::size_t> order(pos.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return err[a] < err[b]; });
    for (int pl = 0; pl < 2; ++pl) {
        const cv::Rect r(40 + 470 * pl, 40, 400, 360);
        cv::rectangle(img, r, kInk);
        cv::putText(img, fmt::format("{}  [{:.0f} mm square]", names[std::size_t(pl)], span), {r.x, 28},
                    cv::FONT_HERSHEY_SIMPLEX, 0.5, kInk, 1, cv::LINE_AA);
        const auto [ax, ay] = planes[std::size_t(pl)];
        for (std::size_t i : order) {
            const double u = (pos[i][ax] - mid[ax]) / span + 0.5, v = (pos[i][ay] - mid[ay]) / span + 0.5;
            const cv::Point p(r.x + int(u * r.width), r.y + r.height - int(v * r.height));
            cv::Mat one(1, 1, CV_8UC1, cv::Scalar(std::clamp(err[i] / emax, 0.0, 1.0) * 255.0)), col;
            cv::applyColorMap(one, col, cv::COLORMAP_JET);
            const cv::Vec3b c = col.at<cv::Vec3b>(0, 0);
            cv::circle(img, p, 2, cv::Scalar(c[0], c[1], c[2]), cv::FILLED);
        }
    }
    // Colour bar.
    for (int k = 0; k < 300; ++k) {
        cv::Mat one(1, 1, CV_8UC1, cv::Scalar(k * 255 / 299)), col;
        cv::applyColorMap(one, col, cv::COLORMAP_JET);
        const cv::Vec3b c = col.at<cv::Vec3b>(0, 0);
        cv::line(img, {350 + k, 420}, {350 + k, 435}, cv::Scalar(c[0], c[1], c[2]));
    }
    cv::putText(img, "0 um", {300, 432}, cv::FONT_HERSHEY_SIMPLEX, 0.45, kInk, 1, cv::LINE_AA);
    cv::putText(img, fmt::format("{:.0f} um (3D marker error)", emax), {660, 432}, cv::FONT_HERSHEY_SIMPLEX, 0.45,
                kInk, 1, cv::LINE_AA);
    save_png(path, img);
}

// ------------------------------------------------------------------------------------------------------------
// JSON helpers
// ------------------------------------------------------------------------------------------------------------

// A figure with no sample behind it is not measured: null, never 0.
nlohmann::json summary_json(std::vector<double> v) {
    const tr::ErrorSummary s = tr::summarise(v);
    if (s.count == 0)
        return {{"count", 0}, {"rms", nullptr}, {"mean", nullptr}, {"p50", nullptr},
                {"p95", nullptr}, {"p99", nullptr}, {"max", nullptr}};
    return {{"count", s.count}, {"rms", s.rms}, {"mean", s.mean}, {"p50", s.p50},
            {"p95", s.p95},     {"p99", s.p99}, {"max", s.max}};
}

nlohmann::json latency_json(std::vector<double> v) {
    const tr::ErrorSummary s = tr::summarise(v);
    if (s.count == 0) return {{"p50", nullptr}, {"p99", nullptr}, {"max", nullptr}};
    return {{"p50", s.p50}, {"p99", s.p99}, {"max", s.max}};
}

nlohmann::json rms(std::vector<double> v) {
    if (v.empty()) return nullptr;
    return tr::summarise(v).rms;
}

/// A figure formatted by `format` (one `{}` field), or "not measured" for null.
std::string figure(const nlohmann::json& v, const char* format) {
    return v.is_null() ? std::string("not measured") : fmt::format(fmt::runtime(format), v.get<double>());
}

nlohmann::json run_json(const RunStats& s, const tr::BodySet& bodies) {
    nlohmann::json j;
    j["frames"] = s.frames;
    j["marker3d_rms_um"] = rms(s.marker_err_um);
    j["marker3d_um"] = summary_json(s.marker_err_um);
    j["marker3d_eye_um"] = summary_json(s.marker_err_eye_um);
    j["marker3d_instrument_um"] = summary_json(s.marker_err_inst_um);
    j["marker3d_flagged_occluded_um"] = summary_json(s.marker_err_occluded_um);
    j["marker3d_all_rms_um"] = rms(s.marker_err_all_um);
    j["marker3d_all_um"] = summary_json(s.marker_err_all_um);
    j["tip_rms_um"] = rms(s.tip_err_um);
    j["tip_um"] = summary_json(s.tip_err_um);
    // The same over the frames whose truth has the tip inside the eye: a withdrawn instrument's tip, out of the
    // trocar's reach and far from the cameras' best view, is measured several times worse (`occlusion`).
    j["tip_in_eye_rms_um"] = rms(s.tip_in_eye_err_um);
    j["tip_in_eye_frames"] = s.tip_in_eye_err_um.size();
    j["tip_eye_frame_um"] = summary_json(s.tip_eye_err_um);
    j["axis_deg"] = summary_json(s.axis_err_deg);
    j["insertion_um"] = summary_json(s.insertion_err_um);
    j["eye_rot_rms_deg"] = rms(s.eye_err_deg);
    j["eye_rot_deg"] = summary_json(s.eye_err_deg);
    j["latency_us"] = latency_json(s.latency_end_to_ready_us);
    j["latency_field_end_to_received_us"] = latency_json(s.latency_end_to_received_us);
    j["exposure_to_pose_us"] = latency_json(s.latency_sample_to_ready_us);
    j["tracking_compute_us"] = latency_json(s.compute_us);
    {
        // Null figures outside --sync async (no filter to predict with).
        std::vector<double> horizon = s.prediction_horizon_us;
        std::sort(horizon.begin(), horizon.end());
        j["display_prediction"] = {
            {"horizon_us", horizon.empty() ? nlohmann::json(nullptr) : nlohmann::json(horizon[horizon.size() / 2])},
            {"frames", horizon.size()},
            {"tip_rms_um", rms(s.predicted_tip_err_um)},
            {"eye_rot_rms_deg", rms(s.predicted_eye_err_deg)},
            {"held_tip_rms_um", rms(s.held_tip_err_um)},
            {"held_eye_rot_rms_deg", rms(s.held_eye_err_deg)}};
    }
    const long found = long(s.marker_err_um.size());
    j["markers"] = {{"found", found},
                    {"truth_visible_in_2_cameras", s.truth_visible2},
                    {"ghosts", s.ghosts},
                    {"unassigned", s.markers_unassigned},
                    {"images_unmatched", s.images_unmatched},
                    {"images_dropped_sync", s.images_dropped_sync}};
    j["frames_two_view"] = s.two_view_frames;
    j["frames_too_few_cameras"] = s.too_few_camera_frames;
    j["eye_not_measured_frames"] = s.eye_held;
    j["eye_model_views"] = s.eye_model_views;
    j["time_ordered_parts"] = s.time_ordered_parts;
    j["smoothed_poses"] = s.smoothed_poses;
    nlohmann::json held = nlohmann::json::object();
    for (int b = 0; b < bodies.instrument_count; ++b)
        held[bodies.instruments[std::size_t(b)].name] = s.tip_held[std::size_t(b)];
    j["instrument_not_measured_frames"] = held;
    return j;
}

// ------------------------------------------------------------------------------------------------------------
// Truth-free figures (eyesim/tracking/truth_free.hpp): JSON, text, plots
// ------------------------------------------------------------------------------------------------------------

std::vector<double> as_double(const std::vector<float>& v) { return {v.begin(), v.end()}; }

nlohmann::json rms_of(double ss, long n) {
    if (n <= 0) return nullptr;
    return std::sqrt(ss / double(n));
}

nlohmann::json p95_of(std::vector<double> v) { return summary_json(std::move(v))["p95"]; }

/// Distances of the per-frame eye centres from their mean (µm).
std::vector<double> eye_centre_spread_um(const tr::TruthFreeStats& tf, Eigen::Vector3d& mean) {
    mean.setZero();
    for (const Eigen::Vector3d& c : tf.eye_centres_mm()) mean += c;
    if (!tf.eye_centres_mm().empty()) mean /= double(tf.eye_centres_mm().size());
    std::vector<double> d;
    for (const Eigen::Vector3d& c : tf.eye_centres_mm()) d.push_back((c - mean).norm() * 1e3);
    return d;
}

/// One pair's figures (null where it was never measured).
nlohmann::json pair_json(const tr::TruthFreeStats& tf, const tr::PairDistance& p) {
    const bool any = p.frames > 0;
    return {{"body", tf.body_name(p.body)},
            {"markers", {p.a, p.b}},
            {"model_mm", p.model_mm},
            {"frames", p.frames},
            {"mean_error_um", any ? nlohmann::json(p.sum_um / double(p.frames)) : nlohmann::json(nullptr)},
            {"rms_error_um", rms_of(p.ss_um2, p.frames)},
            {"max_abs_error_um", any ? nlohmann::json(p.max_abs_um) : nlohmann::json(nullptr)}};
}

/// The `truth_free` object of the JSON summary (docs/validation.md, "Validation without truth").
nlohmann::json truth_free_json(const tr::TruthFreeStats& tf) {
    nlohmann::json j;
    j["frames"] = tf.frames();
    std::vector<double> rp, fp, ray;
    nlohmann::json cams = nlohmann::json::array();
    for (std::size_t c = 0; c < tf.cameras().size(); ++c) {
        const tr::CameraResiduals& cr = tf.cameras()[c];
        const std::vector<double> r = as_double(cr.reprojection_px), f = as_double(cr.fit_reprojection_px),
                                  u = as_double(cr.ray_um);
        rp.insert(rp.end(), r.begin(), r.end());
        fp.insert(fp.end(), f.begin(), f.end());
        ray.insert(ray.end(), u.begin(), u.end());
        cams.push_back({{"camera", c},
                        {"views", r.size()},
                        {"reprojection_rms_px", rms(r)},
                        {"reprojection_p95_px", p95_of(r)},
                        {"fit_reprojection_rms_px", rms(f)},
                        {"ray_residual_rms_um", rms(u)},
                        {"ray_residual_p95_um", p95_of(u)},
                        {"views_left_out_occluded", cr.views_left_out}});
    }
    j["reprojection_rms_px"] = rms(rp);
    j["reprojection_px"] = summary_json(rp);
    j["fit_reprojection_rms_px"] = rms(fp);
    j["fit_reprojection_px"] = summary_json(fp);
    j["ray_residual_rms_um"] = rms(ray);
    j["ray_residual_um"] = summary_json(ray);
    j["per_camera"] = cams;

    const std::vector<double> pe = as_double(tf.pair_errors_um());
    std::vector<double> pabs;
    double psum = 0;
    for (double e : pe) pabs.push_back(std::abs(e)), psum += e;
    j["pair_distance_rms_um"] = rms(pe);
    j["pair_distance_mean_error_um"] = pe.empty() ? nlohmann::json(nullptr) : nlohmann::json(psum / double(pe.size()));
    j["pair_distance_abs_error_um"] = summary_json(pabs);
    nlohmann::json pairs = nlohmann::json::array();
    for (const tr::PairDistance& p : tf.pairs()) pairs.push_back(pair_json(tf, p));
    j["pair_distances"] = pairs;

    nlohmann::json bodies = nlohmann::json::array();
    j["wand_length_error_um"] = nullptr;
    for (const tr::BodyTrack& b : tf.bodies()) {
        const long span = b.first_frame < 0 ? 0 : b.last_frame - b.first_frame + 1;
        nlohmann::json bj{{"body", b.name},
                          {"measured_frames", b.measured_frames},
                          {"first_frame", b.first_frame < 0 ? nlohmann::json(nullptr) : nlohmann::json(b.first_frame)},
                          {"last_frame", b.last_frame < 0 ? nlohmann::json(nullptr) : nlohmann::json(b.last_frame)},
                          {"tracked_span_frames", span}};
        // Its length (outermost markers): the wand's calibration length when the body is a wand.
        bj["length"] = b.length_pair < 0 ? nlohmann::json(nullptr) : pair_json(tf, tf.pairs()[std::size_t(b.length_pair)]);
        if (b.name == "wand" && b.measured_frames > 0) j["wand_length_error_um"] = bj["length"];
        bodies.push_back(bj);
    }
    j["bodies"] = bodies;

    nlohmann::json markers = nlohmann::json::array();
    for (const tr::MarkerResiduals& m : tf.markers()) {
        const tr::BodyTrack& b = tf.bodies()[std::size_t(m.body)];
        const long span = b.first_frame < 0 ? 0 : b.last_frame - b.first_frame + 1;
        markers.push_back({{"body", b.name},
                           {"marker", m.marker},
                           {"colour_class", m.colour_class},
                           {"frames_assigned", m.frames_assigned},
                           {"frames_flagged_occluded", m.frames_occluded},
                           {"tracked_span_frames", span},
                           {"dropout_fraction", span ? nlohmann::json(1.0 - double(m.frames_assigned) / double(span))
                                                     : nlohmann::json(nullptr)},
                           {"views", m.views},
                           {"reprojection_rms_px", rms_of(m.reprojection_ss_px2, m.views)},
                           {"fit_reprojection_rms_px", rms_of(m.fit_reprojection_ss_px2, m.views)},
                           {"ray_residual_rms_um", rms_of(m.ray_ss_um2, m.views)}});
    }
    j["per_marker"] = markers;
    const long span = tf.span_marker_frames();
    j["dropout_fraction"] = span ? nlohmann::json(double(tf.dropped_marker_frames()) / double(span)) : nlohmann::json(nullptr);
    j["unassigned_markers"] = tf.unassigned_markers();

    Eigen::Vector3d mean;
    const std::vector<double> spread = eye_centre_spread_um(tf, mean);
    const Eigen::Vector3d& conf = tf.eye_centre_configured_mm();
    nlohmann::json ec{{"frames", spread.size()},
                      {"spread_rms_um", rms(spread)},
                      {"spread_um", summary_json(spread)},
                      {"configured_rig_mm", {conf.x(), conf.y(), conf.z()}}};
    if (spread.empty()) {
        ec["mean_rig_mm"] = nullptr;
        ec["mean_offset_um"] = nullptr;
    } else {
        ec["mean_rig_mm"] = {mean.x(), mean.y(), mean.z()};
        ec["mean_offset_um"] = (mean - conf).norm() * 1e3;
    }
    j["eye_centre"] = ec;
    return j;
}

/// Text lines of the truth-free figures.
void print_truth_free(const nlohmann::json& t, const std::string& chain) {
    const std::string dropout = t["dropout_fraction"].is_null()
                                    ? std::string("not measured")
                                    : fmt::format("{:.2f} %", 100.0 * t["dropout_fraction"].get<double>());
    std::printf("  truth-free, %s (%ld frames): reprojection RMS %s (fitted bodies %s), ray residual RMS %s, "
                "marker-pair distance RMS %s (mean %s), eye centre spread RMS %s (mean %s from the configured "
                "centre), dropouts %s\n",
                chain.c_str(), t["frames"].get<long>(), figure(t["reprojection_rms_px"], "{:.4f} px").c_str(),
                figure(t["fit_reprojection_rms_px"], "{:.4f} px").c_str(),
                figure(t["ray_residual_rms_um"], "{:.1f} um").c_str(),
                figure(t["pair_distance_rms_um"], "{:.1f} um").c_str(),
                figure(t["pair_distance_mean_error_um"], "{:+.1f} um").c_str(),
                figure(t["eye_centre"]["spread_rms_um"], "{:.1f} um").c_str(),
                figure(t["eye_centre"]["mean_offset_um"], "{:.1f} um").c_str(), dropout.c_str());
    std::string cams;
    for (const auto& c : t["per_camera"])
        cams += fmt::format("{}cam{} {} / {} ({} views)", cams.empty() ? "" : ", ", c["camera"].get<int>(),
                            figure(c["reprojection_rms_px"], "{:.4f} px"), figure(c["ray_residual_rms_um"], "{:.1f} um"),
                            c["views"].get<long>());
    std::printf("    per camera, reprojection / ray residual RMS: %s\n", cams.c_str());
    if (!t["wand_length_error_um"].is_null())
        std::printf("    wand length error: mean %s, RMS %s over %ld frames\n",
                    figure(t["wand_length_error_um"]["mean_error_um"], "{:+.1f} um").c_str(),
                    figure(t["wand_length_error_um"]["rms_error_um"], "{:.1f} um").c_str(),
                    t["wand_length_error_um"]["frames"].get<long>());
}

/// The truth-free plots; returns (file, caption) of each, in report order.
std::vector<std::pair<std::string, std::string>> plot_truth_free(const std::string& d, const tr::TruthFreeStats& tf,
                                                                 Progress& pr, long& step, long steps) {
    std::vector<std::pair<std::string, std::string>> out;
    std::vector<std::pair<std::string, std::vector<double>>> rp, fp, ray;
    for (std::size_t c = 0; c < tf.cameras().size(); ++c) {
        const std::string name = fmt::format("camera {}", c);
        rp.push_back({name, as_double(tf.cameras()[c].reprojection_px)});
        fp.push_back({name, as_double(tf.cameras()[c].fit_reprojection_px)});
        ray.push_back({name, as_double(tf.cameras()[c].ray_um)});
    }
    const auto done = [&](std::string file, std::string caption) {
        out.push_back({std::move(file), std::move(caption)});
        pr.update(++step, steps);
    };
    plot_histogram(d + "reprojection_hist.png", "Reprojection residual: triangulated point vs image used",
                   "residual (frame px)", rp);
    done("reprojection_hist.png", "Reprojection residual per camera (triangulated point against the image used)");
    plot_histogram(d + "fit_reprojection_hist.png", "Reprojection residual: fitted body point vs image used",
                   "residual (frame px)", fp);
    done("fit_reprojection_hist.png", "Reprojection residual per camera (fitted body's model point)");
    plot_histogram(d + "ray_residual_hist.png", "Ray residual: distance of each camera ray from the point",
                   "residual (um)", ray);
    done("ray_residual_hist.png", "Ray-convergence residual per camera");
    std::vector<double> pabs;
    for (float e : tf.pair_errors_um()) pabs.push_back(std::abs(double(e)));
    plot_histogram(d + "pair_distance_hist.png", "Marker-pair distance: |measured - bodies file|", "error (um)",
                   {{"all bodies", pabs}});
    done("pair_distance_hist.png", "Marker-pair distance error against the bodies file, every pair of every body");
    Eigen::Vector3d mean;
    plot_histogram(d + "eye_centre_hist.png", "Eye centre per frame: distance from the mean centre", "distance (um)",
                   {{"eye centre", eye_centre_spread_um(tf, mean)}});
    done("eye_centre_hist.png", "Eye-centre stability: the centre of a free rigid fit of the eye's markers, per frame");
    plot_series(d + "residual_over_time.png", "Reprojection residual RMS per frame (red ticks: no view scored)",
                "px", tf.frame_t_s(), {{"reprojection RMS per frame (frame px)", tf.frame_reprojection_px()}});
    done("residual_over_time.png", "Reprojection residual RMS per frame over time");
    return out;
}

// ------------------------------------------------------------------------------------------------------------
// HTML report (the style of `demo` and `sim`: index.html with tables and PNG plots)
// ------------------------------------------------------------------------------------------------------------

/// A table: header cells (with units), then rows of already formatted cells.
std::string html_table(const std::vector<std::string>& head, const std::vector<std::vector<std::string>>& rows) {
    std::string h = "<table><tr>";
    for (const std::string& c : head) h += "<th>" + html_escape(c) + "</th>";
    h += "</tr>\n";
    for (const auto& r : rows) {
        h += "<tr>";
        for (const std::string& c : r) h += "<td>" + html_escape(c) + "</td>";
        h += "</tr>\n";
    }
    return h + "</table>\n";
}

std::string html_figures(const std::vector<std::pair<std::string, std::string>>& plots) {
    std::string h;
    for (const auto& [file, caption] : plots)
        h += fmt::format("<figure><img src='{}' alt='{}'><figcaption>{}</figcaption></figure>\n", file,
                         html_escape(caption), html_escape(caption));
    return h;
}

std::string cell(const nlohmann::json& v, const char* format) { return figure(v, format); }

std::string count_cell(const nlohmann::json& v) { return v.is_null() ? std::string("not measured") : v.dump(); }

/// The truth-free section of the report.
std::string html_truth_free(const nlohmann::json& t, const std::vector<std::pair<std::string, std::string>>& plots) {
    std::string h = "<h2>Truth-free checks (what real data allows)</h2>\n<p>From the tracker's own frames, as on a rig "
                    "without ground truth. Residuals are in frame pixels (720&times;576; a field pixel is two frame "
                    "rows high) against the image the tracker used (the received centroid, moved by its "
                    "shaft-occlusion correction on instrument markers). Views the tracker judged partly occluded and "
                    "markers it flagged occluded are counted, not scored.</p>\n";
    const auto pct = [](const nlohmann::json& v) {
        return v.is_null() ? std::string("not measured") : fmt::format("{:.2f}", 100.0 * v.get<double>());
    };
    h += html_table(
        {"quantity", "value", "what it is"},
        {{"frames", std::to_string(t["frames"].get<long>()), "tracking frames scored"},
         {"reprojection residual RMS (px)", cell(t["reprojection_rms_px"], "{:.4f}"),
          "triangulated 3D point projected into each camera vs the image used"},
         {"reprojection residual p95 (px)", cell(t["reprojection_px"]["p95"], "{:.4f}"), ""},
         {"fitted-body reprojection RMS (px)", cell(t["fit_reprojection_rms_px"], "{:.4f}"),
          "the body's model marker under the fitted pose, projected"},
         {"ray residual RMS (µm)", cell(t["ray_residual_rms_um"], "{:.2f}"),
          "distance of each camera's ray through its image from the triangulated point"},
         {"ray residual p95 (µm)", cell(t["ray_residual_um"]["p95"], "{:.2f}"), ""},
         {"marker-pair distance error RMS (µm)", cell(t["pair_distance_rms_um"], "{:.2f}"),
          "measured distance − bodies file, every pair of assigned markers of every body"},
         {"marker-pair distance mean error (µm)", cell(t["pair_distance_mean_error_um"], "{:+.2f}"),
          "a bias here is a scale error of the rig or a body built differently from its file"},
         {"eye-centre spread RMS (µm)", cell(t["eye_centre"]["spread_rms_um"], "{:.1f}"),
          "per-frame centre of a free rigid fit of the eye markers, distance from its mean"},
         {"eye-centre mean offset (µm)", cell(t["eye_centre"]["mean_offset_um"], "{:.1f}"),
          "mean per-frame centre vs the configured centre (bodies file)"},
         {"dropouts (% of marker-frames)", pct(t["dropout_fraction"]),
          "markers not assigned within their body's tracked span"},
         {"wand length error mean (µm)",
          t["wand_length_error_um"].is_null() ? std::string("no wand found") : cell(t["wand_length_error_um"]["mean_error_um"], "{:+.2f}"),
          "the wand's outermost markers against the bodies file"},
         {"unassigned triangulated markers", std::to_string(t["unassigned_markers"].get<long>()), "no body claimed them"}});
    h += "<h3>Per camera</h3>\n";
    std::vector<std::vector<std::string>> rows;
    for (const auto& c : t["per_camera"])
        rows.push_back({std::to_string(c["camera"].get<int>()), std::to_string(c["views"].get<long>()),
                        cell(c["reprojection_rms_px"], "{:.4f}"), cell(c["reprojection_p95_px"], "{:.4f}"),
                        cell(c["fit_reprojection_rms_px"], "{:.4f}"), cell(c["ray_residual_rms_um"], "{:.2f}"),
                        cell(c["ray_residual_p95_um"], "{:.2f}"), std::to_string(c["views_left_out_occluded"].get<long>())});
    h += html_table({"camera", "views scored", "reprojection RMS (px)", "reprojection p95 (px)",
                     "fitted-body reprojection RMS (px)", "ray residual RMS (µm)", "ray residual p95 (µm)",
                     "views left out (partly occluded)"},
                    rows);
    h += html_figures(plots);
    h += "<h3>Per marker: residuals and dropouts</h3>\n<p>Tracked span: the body's first to last measured frame; "
         "dropout: the fraction of that span in which the marker was not assigned. Bodies never measured are left "
         "out of this table and the next (see Bodies).</p>\n";
    rows.clear();
    for (const auto& m : t["per_marker"]) {
        if (m["tracked_span_frames"].get<long>() == 0) continue;
        const nlohmann::json& d = m["dropout_fraction"];
        rows.push_back({m["body"].get<std::string>(), std::to_string(m["marker"].get<int>()),
                        std::to_string(m["colour_class"].get<int>()), std::to_string(m["tracked_span_frames"].get<long>()),
                        std::to_string(m["frames_assigned"].get<long>()), pct(d),
                        std::to_string(m["frames_flagged_occluded"].get<long>()), std::to_string(m["views"].get<long>()),
                        cell(m["reprojection_rms_px"], "{:.4f}"), cell(m["fit_reprojection_rms_px"], "{:.4f}"),
                        cell(m["ray_residual_rms_um"], "{:.2f}")});
    }
    h += html_table({"body", "marker", "colour class", "tracked span (frames)", "assigned (frames)", "dropout (%)",
                     "flagged occluded (frames)", "views scored", "reprojection RMS (px)",
                     "fitted-body reprojection RMS (px)", "ray residual RMS (µm)"},
                    rows);
    h += "<h3>Marker-pair distances against the bodies file</h3>\n";
    rows.clear();
    std::set<std::string> measured;
    for (const auto& b : t["bodies"])
        if (b["measured_frames"].get<long>() > 0) measured.insert(b["body"].get<std::string>());
    for (const auto& p : t["pair_distances"])
        if (measured.count(p["body"].get<std::string>()))
            rows.push_back({p["body"].get<std::string>(),
                            fmt::format("{}–{}", p["markers"][0].get<int>(), p["markers"][1].get<int>()),
                            fmt::format("{:.3f}", p["model_mm"].get<double>()), std::to_string(p["frames"].get<long>()),
                            cell(p["mean_error_um"], "{:+.2f}"), cell(p["rms_error_um"], "{:.2f}"),
                            cell(p["max_abs_error_um"], "{:.2f}")});
    h += html_table({"body", "markers", "distance in file (mm)", "frames", "mean error (µm)", "RMS error (µm)",
                     "max |error| (µm)"},
                    rows);
    h += "<h3>Bodies</h3>\n";
    rows.clear();
    for (const auto& b : t["bodies"])
        rows.push_back({b["body"].get<std::string>(), std::to_string(b["measured_frames"].get<long>()),
                        count_cell(b["first_frame"]), count_cell(b["last_frame"]),
                        std::to_string(b["tracked_span_frames"].get<long>()),
                        b["length"].is_null() ? std::string("–") : cell(b["length"]["mean_error_um"], "{:+.2f}")});
    h += html_table({"body", "measured (frames)", "first frame", "last frame", "tracked span (frames)",
                     "length error, outermost markers, mean (µm)"},
                    rows);
    const nlohmann::json& ec = t["eye_centre"];
    h += fmt::format("<p>Eye centre: {} frames with at least three eye markers; spread RMS {} µm, p95 {} µm; mean "
                     "centre {} from the configured centre.</p>\n",
                     ec["frames"].get<long>(), cell(ec["spread_rms_um"], "{:.1f}"), cell(ec["spread_um"]["p95"], "{:.1f}"),
                     cell(ec["mean_offset_um"], "{:.1f} µm"));
    return h;
}

/// The truth section of the report (recordings with truth.jsonl).
std::string html_truth(const nlohmann::json& j, const std::vector<std::pair<std::string, std::string>>& centroid_plots,
                       const std::vector<std::pair<std::string, std::string>>& pose_plots) {
    std::string h = "<h2>Centroids against the rendered truth (field px)</h2>\n";
    std::vector<std::vector<std::string>> rows;
    for (const auto& c : j["per_camera"])
        rows.push_back({std::to_string(c["camera"].get<int>()), cell(c["centroid_rms_px"], "{:.4f}"),
                        cell(c["centroid_p95_px"], "{:.4f}"), cell(c["centroid_max_px"], "{:.4f}"),
                        std::to_string(c["matched"].get<long>()), std::to_string(c["missed_visible_markers"].get<long>()),
                        std::to_string(c["spurious_blobs"].get<long>()), std::to_string(c["blobs"].get<long>()),
                        cell(c["fpga_rule"]["centroid_rms_px"], "{:.4f}"), std::to_string(c["fpga_rule"]["matched"].get<long>()),
                        std::to_string(c["fpga_rule"]["missed"].get<long>())});
    h += html_table({"camera", "RMS (px)", "p95 (px)", "max (px)", "matched", "missed", "spurious blobs", "blobs",
                     "RMS by eyesim fpga's rule (px)", "matched by fpga's rule", "missed by fpga's rule"},
                    rows);
    // The rules' `code` spans as <code>.
    std::string rules = html_escape(kCentroidRules);
    for (bool open = true; rules.find('`') != std::string::npos; open = !open)
        rules.replace(rules.find('`'), 1, open ? "<code>" : "</code>");
    h += "<p><b>Why <code>eyesim fpga</code> gives other centroid figures.</b> " + rules +
         " The last three columns score this run's blobs by <code>fpga</code>'s rule.</p>\n";
    h += html_figures(centroid_plots);
    const nlohmann::json& f = j["fpga_chain"];
    const nlohmann::json& t = j["truth_centroids"];
    h += fmt::format("<h2>Poses against the truth</h2>\n<p>FPGA chain: the FPGA model's blobs through the wire "
                     "format to the tracker. Truth centroids: the rendered centroids + {} px Gaussian noise, the same "
                     "tracker (isolates the tracking error from the centroid error). The first 3D marker rows leave out "
                     "markers the tracker flags as partly occluded; those are listed apart, and the \"all matched\" "
                     "row takes every marker matched to a truth marker.</p>\n",
                     t["noise_px"].get<double>());
    rows.clear();
    const auto row = [&](const char* what, const char* key, const char* unit) {
        rows.push_back({fmt::format("{} ({})", what, unit), cell(f[key]["rms"], "{:.3f}"), cell(f[key]["p95"], "{:.3f}"),
                        cell(f[key]["max"], "{:.3f}"), std::to_string(f[key]["count"].get<long>()),
                        cell(t[key]["rms"], "{:.3f}"), cell(t[key]["p95"], "{:.3f}"), cell(t[key]["max"], "{:.3f}"),
                        std::to_string(t[key]["count"].get<long>())});
    };
    row("3D marker error", "marker3d_um", "µm");
    row("3D marker error, eye", "marker3d_eye_um", "µm");
    row("3D marker error, instruments", "marker3d_instrument_um", "µm");
    row("3D error of markers flagged occluded", "marker3d_flagged_occluded_um", "µm");
    row("3D marker error, all matched (flagged included)", "marker3d_all_um", "µm");
    row("tip error, rig frame", "tip_um", "µm");
    row("tip error, eye frame", "tip_eye_frame_um", "µm");
    row("axis error", "axis_deg", "deg");
    row("insertion depth error", "insertion_um", "µm");
    row("eye rotation error", "eye_rot_deg", "deg");
    h += html_table({"quantity (unit)", "FPGA RMS", "FPGA p95", "FPGA max", "FPGA samples", "truth centroids RMS",
                     "truth centroids p95", "truth centroids max", "truth centroids samples"},
                    rows);
    h += html_figures(pose_plots);
    return h;
}

/// Latency and drops of the FPGA chain.
std::string html_chain(const nlohmann::json& f, long fields_with_drops, long parse_errors) {
    std::string h = "<h2>Latency (modelled device and link, measured tracking)</h2>\n";
    std::vector<std::vector<std::string>> rows;
    for (const auto& [name, key] : std::vector<std::pair<std::string, std::string>>{
             {"field end → packet received (µs)", "latency_field_end_to_received_us"},
             {"field end → poses ready (µs)", "latency_us"},
             {"exposure mid → poses ready (µs)", "exposure_to_pose_us"},
             {"tracking stage compute (µs)", "tracking_compute_us"}})
        rows.push_back({name, cell(f[key]["p50"], "{:.1f}"), cell(f[key]["p99"], "{:.1f}"), cell(f[key]["max"], "{:.1f}")});
    h += html_table({"span", "p50", "p99", "max"}, rows);
    h += "<h2>Drops and rejections (FPGA chain)</h2>\n";
    rows.clear();
    for (const auto& [k, v] : f["markers"].items()) rows.push_back({k, v.dump()});
    rows.push_back({"frames", f["frames"].dump()});
    rows.push_back({"frames with two views at most", f["frames_two_view"].dump()});
    rows.push_back({"frames with too few cameras", f["frames_too_few_cameras"].dump()});
    rows.push_back({"frames the eye was not measured", f["eye_not_measured_frames"].dump()});
    rows.push_back({"marker views the eye's model corrected", f["eye_model_views"].dump()});
    rows.push_back({"low-latency parts fused before newer ones (per body)", f["time_ordered_parts"].dump()});
    rows.push_back({"fixed-lag body poses smoothed by later parts", f["smoothed_poses"].dump()});
    for (const auto& [k, v] : f["instrument_not_measured_frames"].items())
        rows.push_back({"frames " + k + " was not measured", v.dump()});
    rows.push_back({"fields with dropped blobs", std::to_string(fields_with_drops)});
    rows.push_back({"parse errors", std::to_string(parse_errors)});
    h += html_table({"count", "value"}, rows);
    return h;
}

/// Writes `dir`/index.html around the sections; returns its path.
std::string write_index(const std::string& dir, const std::string& title, const std::string& intro,
                        const std::vector<std::string>& warnings, const std::string& body) {
    const std::string path = dir + "/index.html";
    std::ofstream h(path);
    if (!h) throw Error(path + ": cannot write");
    h << "<!doctype html><html><head><meta charset='utf-8'><title>" << html_escape(title) << "</title>"
      << "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
         "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:4px 10px;text-align:right}"
         "th{background:#f0f0f0}td:first-child{text-align:left}img{max-width:100%}"
         "figcaption{font-size:90%;color:#555}</style></head><body>\n";
    h << "<h1>" << html_escape(title) << "</h1>\n<p>" << intro << "</p>\n";
    for (const std::string& w : warnings) h << "<p><b>warning:</b> " << html_escape(w) << "</p>\n";
    h << body << "</body></html>\n";
    h.close();
    if (!h) throw Error(path + ": write failed");
    return path;
}

void make_report_dir(const std::string& dir) {
    std::error_code ec;
    std::filesystem::create_directories(dir, ec);
    if (ec) throw Error(dir + ": cannot create directory: " + ec.message());
}

/// Messages in a capture file (for the progress line's time left).
long count_capture_messages(const std::string& path) {
    auto reader = std::make_unique<proto::CaptureReader>();
    if (!reader->open(path.c_str())) return 0;
    proto::StreamParser parser;
    proto::CaptureRecord rec;
    long n = 0;
    for (;;) {
        const proto::CaptureStatus st = reader->next(rec);
        if (st == proto::CaptureStatus::Corrupt) continue;
        if (st != proto::CaptureStatus::Ok) break;
        if (rec.direction == proto::CaptureDirection::Sent) continue;  // the host's own commands
        parser.parse(rec.bytes, [&](const proto::DecodedFrame&) { ++n; });
    }
    return n;
}

// ------------------------------------------------------------------------------------------------------------
// A capture (`eyesim fpga --out`, `eyesim track` input): truth-free figures only
// ------------------------------------------------------------------------------------------------------------

int run_validate_capture(const ValidateOptions& opt) {
    for (const auto& [given, name] : std::vector<std::pair<bool, const char*>>{
             {!opt.write_capture.empty(), "--write-capture"}, {opt.refine, "--refine"},
             {opt.max_fields > 0, "--max-fields"}, {opt.truth_projected, "--truth-projected"}, {opt.no_hints, "--no-hints"}})
        if (given) throw Error(std::string("validate: ") + name + " needs --recording (a capture holds no fields)", 2);
    if (opt.rig.empty()) throw Error("validate: --capture needs --rig FILE (the cameras the capture was made with)", 2);
    const bool progress = eyesim::app::show_progress(opt.json);
    std::vector<rig::CameraModel> cams;
    rig::Bodies bodies;
    try {
        cams = rig::load_rig_yaml(opt.rig);
        bodies = rig::load_bodies(opt.bodies.empty() ? rig::default_bodies_path() : opt.bodies);
    } catch (const rig::RigError& e) {
        throw Error(e.what());
    }
    tr::TrackerConfig cfg;
    try {
        cfg = eyesim::frame::tracker_config(cams, bodies, tr::all_instruments(bodies));
    } catch (const eyesim::frame::SourceError& e) {
        throw Error(opt.rig + ": " + e.what());
    }
    cfg.sync.mode = tr::sync_mode_from_name(opt.sync);
    cfg.async.report_delay_us = 1000.0 * opt.report_delay_ms;
    cfg.pose.trocar_constraint = !opt.no_trocar;
    cfg.marker_image_model = !opt.no_image_model;
    cfg.centroid_sigma_px = opt.sigma_px;
    const int ncam = int(cfg.cameras.size());
    std::unique_ptr<eyesim::frame::HostRun> run;
    try {
        run = std::make_unique<eyesim::frame::HostRun>(cfg);
    } catch (const eyesim::frame::SourceError& e) {
        throw Error(opt.rig + ": " + e.what());
    } catch (const std::invalid_argument& e) {
        throw Error(opt.rig + ": " + e.what());
    }
    const std::optional<tr::InstrumentModel> wand = wand_model(bodies);
    tr::TruthFreeStats tf(cfg.bodies, ncam, wand ? &*wand : nullptr);
    const long total = progress ? count_capture_messages(opt.capture) : 0;
    Progress pr(progress, "validate", "messages");
    eyesim::frame::HostRun& hr = *run;
    hr.set_hook([&](const tr::TrackingFrame& f, const eyesim::frame::FramePoses&) {
        tf.add(hr.tracker(), f);
        pr.update(long(hr.stats().messages), total);
    });
    std::vector<std::string> warnings;
    const double t0 = us_now();
    try {
        eyesim::frame::run_capture(opt.capture, hr, warnings);
    } catch (const eyesim::frame::SourceError& e) {
        throw Error(e.what());
    }
    pr.update(total, total);
    pr.end();
    const double wall_s = (us_now() - t0) * 1e-6;
    const eyesim::frame::RunStats& st = hr.stats();
    if (st.parser.frames == 0)
        throw Error(fmt::format("{}: no protocol frames ({} bytes skipped)", opt.capture, st.parser.skipped_bytes));
    if (const std::string lost = eyesim::frame::loss_summary(st.loss); !lost.empty())
        warnings.push_back(opt.capture + ": " + lost);
    long assigned = 0;
    for (const tr::MarkerResiduals& m : tf.markers()) assigned += m.frames_assigned;
    if (assigned == 0)
        throw Error(fmt::format("{}: no marker assigned to a body in {} tracking frames ({} FieldMarkers messages; "
                                "{} triangulated markers, none fitted a body of {})",
                                opt.capture, tf.frames(), st.field_markers, tf.unassigned_markers(),
                                opt.bodies.empty() ? rig::default_bodies_path() : opt.bodies));
    if (tf.bodies().front().measured_frames == 0)
        warnings.push_back(fmt::format("{}: eye not measured in any of the {} frames: its figures are not measured",
                                       opt.capture, tf.frames()));
    for (const std::string& w : warnings) std::fprintf(stderr, "eyesim: warning: %s\n", w.c_str());

    nlohmann::json j;
    j["capture"] = opt.capture;
    j["rig"] = opt.rig;
    j["truth"] = false;
    j["cameras"] = ncam;
    j["frames"] = st.frames;
    j["fields"] = st.fields;
    j["fields_per_s"] = double(st.fields) / std::max(wall_s, 1e-9);
    j["sync"] = opt.sync;
    j["trocar_constraint"] = !opt.no_trocar;
    j["marker_image_model"] = !opt.no_image_model;
    // Truth figures, and the exposure → pose latency (a capture's replay has no exposure times on the host clock).
    for (const char* k : {"centroid_rms_px", "marker3d_rms_um", "marker3d_all_rms_um", "tip_rms_um", "tip_in_eye_rms_um",
                          "eye_rot_rms_deg"})
        j[k] = nullptr;
    j["exposure_to_pose_us"] = {{"p50", nullptr}, {"p99", nullptr}, {"max", nullptr}};
    j["truth_free"] = truth_free_json(tf);
    j.update(eyesim::app::latency_json(st));
    j["loss"] = eyesim::app::loss_json(st.loss);
    j["errors"] = st.parser.errors();
    j["warnings"] = warnings;
    if (!opt.report.empty()) {
        make_report_dir(opt.report);
        const std::string d = opt.report + "/";
        long step = 0;
        const long steps = 7;
        Progress rp(progress, "validate: writing report", "files");
        const auto plots = plot_truth_free(d, tf, rp, step, steps);
        const std::string intro = fmt::format(
            "Capture <b>{}</b> tracked with rig <b>{}</b>: {} tracking frames from {} camera fields, {} cameras, sync "
            "{}, trocar constraint {}. No ground truth: truth-free figures only. Latency: {}.",
            html_escape(opt.capture), html_escape(opt.rig), st.frames, st.fields, ncam, opt.sync,
            opt.no_trocar ? "off" : "on", html_escape(eyesim::app::latency_line(st)));
        j["report"] = write_index(opt.report, "eyesim validate: " + opt.capture, intro, warnings,
                                  html_truth_free(j["truth_free"], plots));
        rp.update(steps, steps);
    }
    if (opt.json) {
        std::printf("%s\n", j.dump().c_str());
    } else {
        std::printf("%s: %llu tracking frames from %llu fields x %d cameras (rig %s, sync %s); no truth\n",
                    opt.capture.c_str(), static_cast<unsigned long long>(st.frames),
                    static_cast<unsigned long long>(st.fields), ncam, opt.rig.c_str(), opt.sync.c_str());
        print_truth_free(j["truth_free"], "capture");
        if (const std::string l = eyesim::app::latency_line(st); !l.empty()) std::printf("  %s\n", l.c_str());
        if (j.contains("report")) std::printf("  report: %s\n", j["report"].get<std::string>().c_str());
    }
    return 0;
}

// ------------------------------------------------------------------------------------------------------------
// The command
// ------------------------------------------------------------------------------------------------------------

int run_validate(const ValidateOptions& opt) {
    if (opt.dir.empty() == opt.capture.empty())
        throw Error("validate: give exactly one of --recording DIR, --capture FILE", 2);
    if (!opt.capture.empty()) return run_validate_capture(opt);
    if (opt.no_hints && !opt.refine) throw Error("validate: --no-hints needs --refine", 2);
    const bool progress = eyesim::app::show_progress(opt.json);
    rig::Recording rec = [&] {
        try {
            return rig::Recording::open(opt.dir);
        } catch (const rig::RigError& e) {
            throw Error(e.what());
        }
    }();
    // Warnings: one line each on stderr as they are found, and all of them in the JSON summary.
    std::vector<std::string> warnings;
    const auto warn = [&](std::string w) {
        std::fprintf(stderr, "eyesim: warning: %s\n", w.c_str());
        warnings.push_back(std::move(w));
    };
    for (std::string& w : rec.take_warnings()) warn(std::move(w));
    // Truth is optional: without it, the truth-free figures alone (a recording from a real rig).
    const std::string truth_path = rec.truth_path();
    const bool have_truth = !truth_path.empty();
    std::vector<rig::FieldTruth> truth;
    rig::Bodies bodies;
    std::vector<rig::CameraModel> track_cams = rec.cameras();
    const std::string rig_path = opt.rig.empty() ? opt.dir + "/rig.yaml" : opt.rig;
    try {
        if (have_truth) truth = rig::read_truth(truth_path);
        bodies = rig::load_bodies(opt.bodies.empty() ? rig::default_bodies_path() : opt.bodies);
        if (!opt.rig.empty()) track_cams = rig::load_rig_yaml(opt.rig);
    } catch (const rig::RigError& e) {
        throw Error(e.what());
    }
    if (have_truth && truth.empty()) throw Error(truth_path + ": no lines");
    const int ncam = rec.camera_count();
    if (ncam < 2 || ncam > tr::kMaxCameras)
        throw Error(opt.dir + "/rig.yaml: camera_count: " + std::to_string(ncam) + " (need 2.." +
                    std::to_string(tr::kMaxCameras) + ")");
    if (int(track_cams.size()) != ncam)
        throw Error(fmt::format("{}: {} cameras, the recording {} has {}", opt.rig, track_cams.size(), opt.dir, ncam));
    for (std::size_t i = 0; i < truth.size(); ++i) {
        if (truth[i].field != std::int64_t(i))
            throw Error(fmt::format("{}:{}: field: {} (expected {})", truth_path, i + 1, truth[i].field, i));
        if (truth[i].cameras.size() != std::size_t(ncam))
            throw Error(fmt::format("{}:{}: cameras: {} entries for {} cameras", truth_path, i + 1,
                                    truth[i].cameras.size(), ncam));
    }
    // Fields asked for, then cut to the shortest camera and to the truth; each cut of what was asked is a warning.
    const std::int64_t wanted =
        opt.max_fields > 0 ? std::int64_t(opt.max_fields) : std::numeric_limits<std::int64_t>::max();
    const std::int64_t common = rec.common_field_count();
    std::int64_t longest = 0;
    std::string lengths;
    for (int c = 0; c < ncam; ++c) {
        longest = std::max(longest, rec.field_count(c));
        lengths += fmt::format("{}{} {} fields", c ? ", " : "", rec.cameras()[std::size_t(c)].name, rec.field_count(c));
    }
    if (common < std::min(longest, wanted))
        warn(fmt::format("{}: cameras of different lengths ({}): only the first {} fields of each camera are used",
                         opt.dir, lengths, common));
    const std::int64_t streams = std::min(common, wanted);
    if (have_truth && std::int64_t(truth.size()) < streams)
        warn(fmt::format("{}: truth for {} fields, the streams have {}: the last {} fields are not scored", truth_path,
                         truth.size(), streams, streams - std::int64_t(truth.size())));
    const std::int64_t n = have_truth ? std::min<std::int64_t>(streams, std::int64_t(truth.size())) : streams;
    if (n < 3)
        throw Error(opt.dir + ": only " + std::to_string(n) + (have_truth ? " fields with truth" : " fields") +
                    " (need at least 3)");

    // Tracker configuration: the cameras (rig.yaml, or --rig), the scene's instruments (from the truth; without
    // one, every kind of the bodies file, as `eyesim track`), FPGA field timing from the recording's cameras.
    std::vector<tr::SceneInstrument> scene;
    if (have_truth)
        for (const rig::InstrumentTruth& it : truth[0].instruments) scene.push_back({it.kind, it.trocar});
    else
        scene = tr::all_instruments(bodies);
    tr::TrackerConfig cfg;
    try {
        cfg.bodies = tr::body_set(bodies, scene);
    } catch (const std::invalid_argument& e) {
        throw Error(std::string(e.what()));
    }
    const double end_after_start_us = double(eyesim::fpga::field_end_us(0));
    for (int c = 0; c < ncam; ++c) {
        const rig::CameraModel& cm = rec.cameras()[std::size_t(c)];
        cfg.cameras.push_back(tr::camera_geometry(track_cams[std::size_t(c)]));
        // Device field_end = field start (vertical sync = exposure end) + the FPGA's end-of-active-video time; the
        // frame's instant is the exposure mid-time, half a shutter before the start.
        tr::CameraTiming t;
        t.end_to_sample_us = {end_after_start_us + 0.5 * cm.exposure_us, end_after_start_us + 0.5 * cm.exposure_us};
        cfg.timing.push_back(t);
    }
    cfg.sync.mode = tr::sync_mode_from_name(opt.sync);
    cfg.async.report_delay_us = 1000.0 * opt.report_delay_ms;
    cfg.pose.trocar_constraint = !opt.no_trocar;
    cfg.marker_image_model = !opt.no_image_model;
    cfg.centroid_sigma_px = opt.sigma_px;
    for (const auto& g : cfg.cameras)
        if (!g.valid()) throw Error(rig_path + ": a camera has invalid intrinsics or rotation");

    const std::optional<tr::InstrumentModel> wand = wand_model(bodies);
    Runner fpga_run("fpga", cfg, truth, wand ? &*wand : nullptr);
    tr::TrackerConfig cfg_truth = cfg;
    cfg_truth.centroid_sigma_px = std::max(opt.truth_noise_px, 0.005);
    Runner truth_run("truth_centroids", cfg_truth, truth, nullptr);

    std::vector<std::unique_ptr<eyesim::fpga::RegisterMap>> regs;
    std::vector<std::unique_ptr<eyesim::fpga::Pipeline>> pipes;
    for (int c = 0; c < ncam; ++c) {
        regs.push_back(std::make_unique<eyesim::fpga::RegisterMap>());
        pipes.push_back(std::make_unique<eyesim::fpga::Pipeline>(*regs.back()));
    }
    std::vector<CentroidStats> cstats(static_cast<std::size_t>(ncam));
    std::vector<std::uint8_t> field(static_cast<std::size_t>(rig::kFieldBytes));
    std::vector<eyesim::fpga::Blob> blobs;
    std::vector<proto::FieldMarkers> msgs(64);
    std::array<std::uint8_t, proto::kMaxFrameBytes> frame_bytes{};
    std::vector<std::uint8_t> stream;
    proto::StreamParser parser;
    eyesim::firmware::LinkModel link;
    std::vector<eyesim::firmware::LinkModel> cam_links(static_cast<std::size_t>(ncam));
    const bool per_blob = opt.emit == "blob";
    // The device's field end: its last active pixel in and its last blob out of the pipeline (fpga_run.cpp).
    const auto end_cycle = [](const eyesim::fpga::FieldStats& st) {
        return std::max(st.last_emit_cycle, st.last_active_line_end_cycle);
    };
    std::mt19937_64 rng(opt.seed);
    std::normal_distribution<double> gauss(0.0, 1.0);
    std::uint16_t sequence = 0;
    proto::CaptureWriter capture;
    if (!opt.write_capture.empty() && !capture.create(opt.write_capture.c_str()))
        throw Error(opt.write_capture + ": cannot create capture file");
    long parse_errors = 0, fields_with_drops = 0;
    const double t_start = us_now();
    double fpga_us = 0, refine_us = 0;
    // Refinement stage on each blob's patch (eyesim/app/refine.hpp); the modelled link timing does not include it.
    std::unique_ptr<eyesim::app::BlobRefiner> refiner;
    const tr::SphereFitConfig fit_config = opt.refine ? eyesim::app::recording_sphere_fit_config(rec) : tr::SphereFitConfig{};
    if (opt.refine) refiner = std::make_unique<eyesim::app::BlobRefiner>(fit_config);
    // What hides part of a marker (its shaft, the eye) for the fits, from the chain's own newest poses (the fields
    // before this one); the first fields' from the poses a look ahead finds.
    tr::MarkerHintSource marker_hints(cfg.cameras, cfg.bodies);
    std::unique_ptr<eyesim::app::HintMotion> hint_motion;  // the instruments' hints at each field's time
    if (refiner && !opt.no_hints) {
        refiner->set_hints(&marker_hints);
        if (eyesim::app::hint_motion_for(fit_config)) hint_motion = std::make_unique<eyesim::app::HintMotion>(cfg);
        std::vector<int> all_cams(static_cast<std::size_t>(ncam));
        for (int c = 0; c < ncam; ++c) all_cams[static_cast<std::size_t>(c)] = c;
        try {
            eyesim::app::prime_marker_hints(opt.dir, all_cams, std::vector<eyesim::fpga::RegisterMap>(std::size_t(ncam)),
                                            fit_config, cfg, std::min(eyesim::app::kMaxPrimingFields, n), marker_hints);
        } catch (const rig::RigError& e) {
            throw Error(e.what());
        }
    }
    long refined = 0;
    Progress pr(progress, "validate", "fields");

    for (std::int64_t i = 0; i < n; ++i) {
        std::vector<Timed> fpga_msgs, truth_msgs;
        for (int c = 0; c < ncam; ++c) {
            const rig::FieldTiming ft = rec.field_timing(c, i);
            const int parity = ft.parity;
            const std::uint64_t start_us = std::uint64_t(std::llround(std::max(0.0, ft.start_us)));
            try {
                if (!rec.read_field(c, i, field.data()))  // a video field lost: warned, read as black
                    for (std::string& w : rec.take_warnings()) warn(std::move(w));
            } catch (const rig::RigError& e) {
                throw Error(e.what());
            }
            // --- FPGA model → wire messages → encoded frames → stream parser (what the host receives). ---
            const double f0 = us_now();
            eyesim::fpga::Pipeline& pipe = *pipes[std::size_t(c)];
            pipe.process_field(field.data(), rig::kFieldHeight, std::uint32_t(i), std::uint8_t(parity));
            blobs.clear();
            eyesim::fpga::Blob b;
            while (pipe.pop_blob(b)) blobs.push_back(b);
            fpga_us += us_now() - f0;
            if (refiner) {
                const double r0 = us_now();
                if (hint_motion)
                    if (const tr::TrackingFrame* lf = fpga_run.last_frame())
                        hint_motion->move_to_field(*lf, c, parity, start_us, marker_hints);
                refined += refiner->refine(field.data(), rig::kFieldHeight, blobs, c);
                refine_us += us_now() - r0;
            }
            const eyesim::fpga::FieldInfo info =
                eyesim::fpga::field_info(pipe.field_stats(), std::uint8_t(c), std::uint8_t(parity), start_us);
            if (info.blobs_dropped) ++fields_with_drops;
            std::size_t nm = 0;
            if (per_blob) {
                // Low-latency mode, as the firmware sends it (DeviceCore::flush_low_latency): each blob as soon as
                // the pipeline emits it, with the blobs already waiting in one frame, then a closing part at the
                // field's end. Each camera on a link of its own: frames take microseconds on it, so the cameras'
                // frames hardly ever wait for each other.
                if (msgs.size() < blobs.size() + 1) msgs.resize(blobs.size() + 1);
                eyesim::firmware::LinkModel& cl = cam_links[std::size_t(c)];
                std::uint64_t core_ns = 0;
                const auto emit_ns = [&](const eyesim::fpga::Blob& bl) {
                    return eyesim::fpga::device_time_us(start_us, bl.emit_cycle) * 1000ull;
                };
                const std::uint64_t end_ns = eyesim::fpga::device_time_us(start_us, end_cycle(pipe.field_stats())) * 1000ull;
                std::size_t k0 = 0;
                for (;;) {
                    const bool closing = k0 == blobs.size();
                    const std::uint64_t t = std::max<std::uint64_t>(closing ? end_ns : emit_ns(blobs[k0]), core_ns);
                    std::size_t k = 0;
                    while (!closing && k0 + k < blobs.size() && k < proto::kMaxMarkersPerMessage && emit_ns(blobs[k0 + k]) <= t)
                        ++k;
                    proto::FieldMarkers& fm = msgs[nm];
                    fm = proto::FieldMarkers{};
                    fm.camera_id = std::uint8_t(c);
                    fm.field_parity = std::uint8_t(parity);
                    fm.field_counter = std::uint32_t(i);
                    fm.flags = proto::kFieldFlagLowLatency;
                    if (!closing) fm.flags |= proto::kFieldFlagMoreFollows;
                    if (closing && info.blobs_dropped) fm.flags |= proto::kFieldFlagBlobsDropped;
                    fm.field_end_us = closing ? eyesim::fpga::field_end_us(start_us) : 0;
                    fm.part_index = std::uint16_t(nm);
                    fm.marker_count = std::uint8_t(k);
                    for (std::size_t q = 0; q < k; ++q) fm.markers[q] = eyesim::fpga::to_marker(blobs[k0 + q], start_us);
                    const std::size_t len = proto::encode_frame(fm, sequence++, frame_bytes);
                    if (len == 0) throw Error(fmt::format("camera {} field {}: message {} did not encode", c, i, nm));
                    core_ns = t + eyesim::firmware::frame_cost_ns(len, k);
                    const std::uint64_t written = cl.transmit(core_ns, len);
                    const std::span<const std::uint8_t> bytes(frame_bytes.data(), len);
                    if (!opt.write_capture.empty() && !capture.write(written / 1000, bytes))
                        throw Error(opt.write_capture + ": write failed");
                    parser.parse(bytes, [&](const proto::DecodedFrame& df) {
                        if (const auto* m = std::get_if<proto::FieldMarkers>(&df.message))
                            fpga_msgs.push_back({double(written) * 1e-3, *m});
                    });
                    ++nm;
                    k0 += k;
                    if (closing) break;
                }
            } else {
            nm = eyesim::fpga::to_field_markers(blobs.data(), blobs.size(), info, msgs.data(), msgs.size());
            stream.clear();
            std::uint64_t written_ns = 0;
            for (std::size_t k = 0; k < nm; ++k) {
                const std::size_t len = proto::encode_frame(msgs[k], sequence++, frame_bytes);
                if (len == 0) throw Error(fmt::format("camera {} field {}: message {} did not encode", c, i, k));
                stream.insert(stream.end(), frame_bytes.begin(), frame_bytes.begin() + std::ptrdiff_t(len));
                // Modelled device: all parts queued at the field end (per-field mode), then the USB link.
                const std::uint64_t queued_ns =
                    msgs[k].field_end_us * 1000ull + eyesim::firmware::frame_cost_ns(len, msgs[k].marker_count);
                written_ns = link.transmit(queued_ns, len);
            }
            const double received_us = double(written_ns) * 1e-3;
            if (!opt.write_capture.empty() && !stream.empty() && !capture.write(written_ns / 1000, stream))
                throw Error(opt.write_capture + ": write failed");
            parser.parse(stream, [&](const proto::DecodedFrame& df) {
                if (const auto* fm = std::get_if<proto::FieldMarkers>(&df.message)) fpga_msgs.push_back({received_us, *fm});
            });
            }
            CentroidStats& cs = cstats[std::size_t(c)];
            std::vector<rig::DetectedMarker> got;
            for (std::size_t k = 0; k < nm; ++k)
                for (int m = 0; m < msgs[k].marker_count; ++m) {
                    const proto::Marker& mk = msgs[k].markers[std::size_t(m)];
                    got.push_back({mk.colour_class, Eigen::Vector2d(double(mk.x_q16) / proto::kCoordScale,
                                                                    double(mk.y_q16) / proto::kCoordScale)});
                }
            cs.blobs += long(got.size());
            if (!have_truth) continue;
            // --- Centroid error against the rendered intensity centroid of each visible marker. ---
            std::vector<bool> used;
            rig::match_markers(
                truth[std::size_t(i)], c, got, 1.5,
                [](const rig::MarkerTruth&, const rig::MarkerCameraTruth& v) {
                    return v.visible && !(v.occluded_fraction > 0.0);
                },
                [&](const rig::MarkerMatch& m) {
                    if (m.detection < 0) {
                        if (m.view->area_px >= 4.0) ++cs.missed;
                        return;
                    }
                    ++cs.matched;
                    cs.err_px.push_back(m.distance_px);
                },
                used);
            for (std::size_t k = 0; k < got.size(); ++k) {
                if (used[k]) continue;
                bool near_truth = false;  // partly occluded markers are not scored but are not spurious either
                for (const rig::MarkerTruth& mt : truth[std::size_t(i)].markers) {
                    const rig::MarkerCameraTruth& ct = mt.cams[std::size_t(c)];
                    if (ct.visible && mt.colour_class == got[k].colour_class &&
                        (got[k].centroid_px - ct.centroid_px).norm() < 3.0)
                        near_truth = true;
                }
                if (!near_truth) ++cs.spurious;
            }
            // The same blobs by `eyesim fpga`'s rule (kCentroidRules), for the report's comparison.
            rig::match_markers(
                truth[std::size_t(i)], c, got, 3.0,
                [](const rig::MarkerTruth&, const rig::MarkerCameraTruth& v) { return v.visible && !(v.area_px < 2.0); },
                [&](const rig::MarkerMatch& m) {
                    if (m.detection < 0) ++cs.fpga_rule_missed;
                    else cs.fpga_rule_err_px.push_back(m.distance_px);
                },
                used);
            // --- The same field from truth centroids + Gaussian noise (isolates the tracking error). ---
            proto::FieldMarkers tm;
            tm.camera_id = std::uint8_t(c);
            tm.field_parity = std::uint8_t(parity);
            tm.field_counter = std::uint32_t(i);
            tm.field_end_us = start_us + std::uint64_t(end_after_start_us);
            for (const rig::MarkerTruth& mt : truth[std::size_t(i)].markers) {
                const rig::MarkerCameraTruth& ct = mt.cams[std::size_t(c)];
                if (!ct.visible || ct.area_px < 4.0) continue;
                const Eigen::Vector2d base = opt.truth_projected ? ct.projected_px : ct.centroid_px;
                const Eigen::Vector2d p = base + opt.truth_noise_px * Eigen::Vector2d(gauss(rng), gauss(rng));
                if (p.x() < 0 || p.y() < 0 || p.x() > 719 || p.y() > 287) continue;
                proto::Marker& mk = tm.markers[tm.marker_count++];
                mk.colour_class = std::uint8_t(mt.colour_class);
                mk.x_q16 = std::uint32_t(std::llround(p.x() * proto::kCoordScale));
                mk.y_q16 = std::uint32_t(std::llround(p.y() * proto::kCoordScale));
                mk.area_px = std::uint32_t(std::max(1.0, ct.area_px));
                mk.complete_us = tm.field_end_us;
                if (tm.marker_count == proto::kMaxMarkersPerMessage) {  // more follow in another part
                    tm.flags = proto::kFieldFlagMoreFollows;
                    truth_msgs.push_back({double(tm.field_end_us), tm});
                    tm.flags = 0;
                    tm.marker_count = 0;
                    ++tm.part_index;
                }
            }
            truth_msgs.push_back({double(tm.field_end_us), tm});
        }
        fpga_run.push(fpga_msgs);  // in receive order now
        if (hint_motion)
            for (const Timed& t : fpga_msgs) hint_motion->push(t.msg, t.received_us);
        if (const tr::TrackingFrame* f = fpga_run.last_frame()) marker_hints.update(*f);
        if (have_truth) truth_run.push(truth_msgs);
        pr.update(long(i + 1), long(n));
    }
    parser.finish([&](const proto::DecodedFrame&) {});
    if (!opt.write_capture.empty()) capture.close();
    parse_errors = long(parser.stats().errors());
    const double end_us = 1e300;
    fpga_run.finish(end_us);
    if (have_truth) truth_run.finish(end_us);
    pr.end();
    const double wall_s = (us_now() - t_start) * 1e-6;
    const RunStats& fs = fpga_run.stats();
    const RunStats& ts = truth_run.stats();
    const tr::TruthFreeStats& tf = fpga_run.truth_free();

    // ---- Nothing to score is an error, not a perfect score; a body never measured is a warning ----
    long found = 0, at_truth = 0, assigned = 0;
    for (const CentroidStats& cs : cstats) found += cs.blobs, at_truth += cs.matched;
    for (const tr::MarkerResiduals& m : tf.markers()) assigned += m.frames_assigned;
    if (found == 0)
        throw Error(fmt::format("{}: no marker found in {} fields: the FPGA model found no blob in any of the {} "
                                "cameras", opt.dir, n, ncam));
    if (have_truth && fs.marker_err_um.empty() && fs.marker_err_occluded_um.empty())
        throw Error(fmt::format("{}: no marker matched in {} fields: the FPGA model found {} blobs ({} at a truth "
                                "centroid), no triangulated marker was within reach of a truth marker",
                                opt.dir, n, found, at_truth));
    if (!have_truth && assigned == 0)
        throw Error(fmt::format("{}: no marker assigned to a body in {} fields: the FPGA model found {} blobs, {} "
                                "triangulated markers, none fitted a body", opt.dir, n, found, tf.unassigned_markers()));
    // Each chain says when it never measured a body (the other chain's count beside it tells an FPGA fault from a
    // body out of view). Without truth, the eye alone: the instruments in view are not known.
    const auto unmeasured = [&](const std::string& body, std::size_t fpga_measured, std::size_t truth_measured) {
        if (fpga_measured == 0)
            warn(fmt::format("{}: {} not measured in any of the {} scored frames (FPGA chain; from truth centroids "
                             "in {}): its figures are not measured", opt.dir, body, fs.frame_t_s.size(),
                             truth_measured));
        else if (truth_measured == 0)
            warn(fmt::format("{}: {} not measured in any of the {} scored frames (truth-centroid chain; FPGA chain in "
                             "{}): its truth-centroid figures are not measured", opt.dir, body, ts.frame_t_s.size(),
                             fpga_measured));
    };
    if (have_truth) {
        unmeasured("eye", fs.eye_err_deg.size(), ts.eye_err_deg.size());
        // An instrument none of whose markers the truth shows in two cameras in any scored field is out of view
        // (a wand recording lifts both out): nothing to warn about, its figures are null.
        std::set<std::string> in_view;
        for (std::int64_t i = 0; i < n; ++i)
            for (const rig::MarkerTruth& mt : truth[std::size_t(i)].markers) {
                int seen = 0;
                for (const rig::MarkerCameraTruth& v : mt.cams) seen += v.visible ? 1 : 0;
                if (seen >= 2) in_view.insert(mt.body);
            }
        for (int b = 0; b < cfg.bodies.instrument_count; ++b) {
            const std::size_t k = std::size_t(b);
            if (!in_view.count(cfg.bodies.instruments[k].name)) continue;
            unmeasured(cfg.bodies.instruments[k].name, fs.frame_t_s.size() - std::size_t(fs.tip_held[k]),
                       ts.frame_t_s.size() - std::size_t(ts.tip_held[k]));
        }
    } else if (tf.bodies().front().measured_frames == 0) {
        warn(fmt::format("{}: eye not measured in any of the {} frames (no truth): its figures are not measured",
                         opt.dir, tf.frames()));
    }

    // ---- Summaries ----
    nlohmann::json j;
    j["recording"] = opt.dir;
    j["rig"] = rig_path;
    j["truth"] = have_truth;
    j["fields"] = n;
    j["cameras"] = ncam;
    j["fields_per_s"] = double(n * ncam) / std::max(wall_s, 1e-9);
    j["sync"] = opt.sync;
    j["emit"] = opt.emit;
    j["report_delay_ms"] = opt.report_delay_ms;
    j["trocar_constraint"] = !opt.no_trocar;
    j["marker_image_model"] = !opt.no_image_model;
    nlohmann::json cams = nlohmann::json::array();
    std::vector<double> all_c;
    for (int c = 0; c < ncam; ++c) {
        CentroidStats& cs = cstats[std::size_t(c)];
        all_c.insert(all_c.end(), cs.err_px.begin(), cs.err_px.end());
        const nlohmann::json s = summary_json(cs.err_px);
        nlohmann::json cj{{"camera", c}, {"blobs", cs.blobs}, {"lost_fields", rec.lost_fields(c)}};
        if (have_truth) {
            cj.update({{"centroid_rms_px", s["rms"]},
                       {"centroid_p95_px", s["p95"]},
                       {"centroid_max_px", s["max"]},
                       {"matched", cs.matched},
                       {"missed_visible_markers", cs.missed},
                       {"spurious_blobs", cs.spurious},
                       {"fpga_rule",
                        {{"centroid_rms_px", rms(cs.fpga_rule_err_px)},
                         {"matched", cs.fpga_rule_err_px.size()},
                         {"missed", cs.fpga_rule_missed}}}});
        } else {
            for (const char* k : {"centroid_rms_px", "centroid_p95_px", "centroid_max_px"}) cj[k] = nullptr;
        }
        cams.push_back(cj);
    }
    j["per_camera"] = cams;
    j["centroid_rms_px"] = rms(all_c);
    j["fields_with_dropped_blobs"] = fields_with_drops;
    j["fpga_us_per_field"] = fpga_us / double(n * ncam);
    if (refiner) {
        j["refined"] = refined;
        j["refused"] = refiner->refusals_json();
        j["hinted_fits"] = refiner->hinted_fits();
        j["refine_us_per_field"] = refine_us / double(n * ncam);
    }
    // Headline keys: the full chain from the FPGA model (null without truth).
    const nlohmann::json fj = run_json(fs, cfg.bodies);
    for (const char* k : {"marker3d_rms_um", "marker3d_all_rms_um", "tip_rms_um", "tip_in_eye_rms_um", "eye_rot_rms_deg",
                          "latency_us", "exposure_to_pose_us", "display_prediction"})
        j[k] = fj[k];
    j["fpga_chain"] = fj;
    if (have_truth) {
        j["truth_centroids"] = run_json(ts, cfg.bodies);
        j["truth_centroids"]["noise_px"] = opt.truth_noise_px;
    } else {
        j["truth_centroids"] = nullptr;
    }
    j["truth_free"] = truth_free_json(tf);
    j["errors"] = parse_errors;
    j["warnings"] = warnings;

    if (!opt.report.empty()) {
        make_report_dir(opt.report);
        const std::string d = opt.report + "/";
        long step = 0;
        const long steps = 6 + (have_truth ? 6 : 0) + 1;
        Progress rp(progress, "validate: writing report", "files");
        const auto tf_plots = plot_truth_free(d, tf, rp, step, steps);
        std::string body = html_truth_free(j["truth_free"], tf_plots);
        if (have_truth) {
            std::vector<std::pair<std::string, std::vector<double>>> cset;
            for (int c = 0; c < ncam; ++c) cset.push_back({fmt::format("camera {}", c), cstats[std::size_t(c)].err_px});
            plot_histogram(d + "centroid_error_hist.png", "FPGA centroid error vs rendered centroid", "error (field px)",
                           cset);
            rp.update(++step, steps);
            plot_histogram(d + "marker3d_error_hist.png", "3D marker error", "error (um)",
                           {{"FPGA chain", fs.marker_err_um}, {"truth centroids + noise", ts.marker_err_um}});
            rp.update(++step, steps);
            plot_histogram(d + "tip_error_hist.png", "Instrument tip error (rig frame)", "error (um)",
                           {{"FPGA chain", fs.tip_err_um}, {"truth centroids + noise", ts.tip_err_um}});
            rp.update(++step, steps);
            std::vector<std::pair<std::string, std::vector<double>>> series{
                {"3D marker RMS per frame (um)", fs.frame_marker_rms_um}};
            for (int b = 0; b < cfg.bodies.instrument_count; ++b)
                series.push_back({cfg.bodies.instruments[std::size_t(b)].name + " tip error (um)",
                                  fs.frame_tip_um[std::size_t(b)]});
            plot_series(d + "error_over_time.png", "FPGA chain: error over time (red ticks: not measured)", "um",
                        fs.frame_t_s, series);
            rp.update(++step, steps);
            plot_series(d + "eye_error_over_time.png", "FPGA chain: eye rotation error over time", "deg", fs.frame_t_s,
                        {{"eye rotation error (deg)", fs.frame_eye_deg}});
            rp.update(++step, steps);
            plot_volume(d + "marker_error_volume.png", fs.marker_pos_mm, fs.marker_pos_err_um);
            rp.update(++step, steps);
            body += html_truth(
                j, {{"centroid_error_hist.png", "FPGA centroid error against the rendered centroid, per camera"}},
                {{"marker3d_error_hist.png", "3D marker error"},
                 {"tip_error_hist.png", "Instrument tip error (rig frame)"},
                 {"error_over_time.png", "FPGA chain: 3D marker RMS and tip error per frame"},
                 {"eye_error_over_time.png", "FPGA chain: eye rotation error per frame"},
                 {"marker_error_volume.png", "3D marker error across the working volume"}});
        }
        body += html_chain(fj, fields_with_drops, parse_errors);
        const std::string intro = fmt::format(
            "Recording <b>{}</b>: {} fields &times; {} cameras, FPGA model &rarr; packets &rarr; tracker. Cameras for "
            "tracking from <b>{}</b>{}. Sync {}, trocar constraint {}, centroid sigma assumed {} px{}. {}",
            html_escape(opt.dir), n, ncam, html_escape(rig_path),
            opt.rig.empty() ? "" : " (instead of the recording's rig.yaml; the FPGA model reads the recording's fields)",
            opt.sync, opt.no_trocar ? "off" : "on", opt.sigma_px, refiner ? ", refinement stage on" : "",
            have_truth ? "Ground truth: truth.jsonl." : "No truth.jsonl: truth-free figures only.");
        j["report"] = write_index(opt.report, "eyesim validate: " + opt.dir, intro, warnings, body);
        rp.update(steps, steps);
    }

    if (opt.json) {
        std::printf("%s\n", j.dump().c_str());
    } else {
        std::printf("%s: %lld fields x %d cameras (sync %s%s)%s\n", opt.dir.c_str(), static_cast<long long>(n), ncam,
                    opt.sync.c_str(), opt.rig.empty() ? "" : (", rig " + opt.rig).c_str(),
                    have_truth ? "" : "; no truth.jsonl: truth-free figures only");
        if (have_truth) {
            std::printf("  centroids (FPGA%s vs rendered): RMS %s\n", refiner ? " + refinement" : "",
                        figure(j["centroid_rms_px"], "{:.4f} px").c_str());
            for (const auto& [label, r] : std::vector<std::pair<std::string, nlohmann::json>>{
                     {"FPGA chain", fj},
                     {fmt::format("truth centroids + {} px", opt.truth_noise_px), j["truth_centroids"]}}) {
                const std::string marker = r["marker3d_rms_um"].is_null()
                                               ? "not measured"
                                               : fmt::format("{:.1f} um (p95 {:.1f})", r["marker3d_rms_um"].get<double>(),
                                                             r["marker3d_um"]["p95"].get<double>());
                std::printf("  %-28s 3D marker RMS %s, tip RMS %s, eye RMS %s, frames %ld\n", label.c_str(),
                            marker.c_str(), figure(r["tip_rms_um"], "{:.1f} um").c_str(),
                            figure(r["eye_rot_rms_deg"], "{:.4f} deg").c_str(), r["frames"].get<long>());
                std::printf("  %-28s 3D marker RMS over all %ld matched markers (flagged occluded included) %s\n", "",
                            r["marker3d_all_um"]["count"].get<long>(),
                            figure(r["marker3d_all_rms_um"], "{:.1f} um").c_str());
            }
        }
        print_truth_free(j["truth_free"], "FPGA chain");
        std::printf("  latency field end -> poses ready: p50 %s, p99 %s, max %s\n",
                    figure(fj["latency_us"]["p50"], "{:.0f} us").c_str(),
                    figure(fj["latency_us"]["p99"], "{:.0f} us").c_str(),
                    figure(fj["latency_us"]["max"], "{:.0f} us").c_str());
        std::printf("  latency exposure mid -> poses ready: p50 %s, p99 %s, max %s\n",
                    figure(fj["exposure_to_pose_us"]["p50"], "{:.0f} us").c_str(),
                    figure(fj["exposure_to_pose_us"]["p99"], "{:.0f} us").c_str(),
                    figure(fj["exposure_to_pose_us"]["max"], "{:.0f} us").c_str());
        if (const nlohmann::json& dp = fj["display_prediction"]; !dp["horizon_us"].is_null())
            std::printf("  display-time prediction, %s ahead: tip RMS %s (held %s), eye RMS %s (held %s)\n",
                        figure(dp["horizon_us"], "{:.0f} us").c_str(), figure(dp["tip_rms_um"], "{:.1f} um").c_str(),
                        figure(dp["held_tip_rms_um"], "{:.1f} um").c_str(),
                        figure(dp["eye_rot_rms_deg"], "{:.4f} deg").c_str(),
                        figure(dp["held_eye_rot_rms_deg"], "{:.4f} deg").c_str());
        if (j.contains("report")) std::printf("  report: %s\n", j["report"].get<std::string>().c_str());
    }
    return 0;
}

eyesim::app::Registrar reg{"validate",
                           "Validate tracking (FPGA model -> packets -> tracker): against the truth of a recording "
                           "where there is one, and by truth-free checks (residuals, marker distances, eye centre, "
                           "dropouts) on any recording or capture",
                           [](CLI::App& sub) {
    auto opt = std::make_shared<ValidateOptions>();
    sub.add_option("--recording", opt->dir, "recording directory with rig.yaml, cam* streams and optionally truth.jsonl");
    sub.add_option("--capture", opt->capture, "capture file of FieldMarkers packets (eyesim fpga --out, a device): "
                                              "truth-free figures only; needs --rig");
    sub.add_option("--rig", opt->rig, "rig.yaml the tracker uses (a recording: instead of its own rig.yaml; the FPGA "
                                      "model still reads the recording's fields)");
    sub.add_option("--report", opt->report, "write index.html with tables and PNG plots into this directory");
    sub.add_flag("--json", opt->json, "print one JSON summary object on stdout");
    sub.add_option("--max-fields", opt->max_fields, "use at most this many fields (0: all)")
        ->check(eyesim::app::finite_in(0.0, 1e9));
    sub.add_option("--sync", opt->sync,
                   "camera time alignment: interpolate | extrapolate | nearest | async (per-body filters updated by "
                   "each camera field at its own time)")
        ->check(CLI::IsMember({"interpolate", "extrapolate", "nearest", "async"}));
    sub.add_option("--emit", opt->emit,
                   "how the modelled device sends a field's markers: field (all at the field's end) | blob (each as "
                   "soon as the FPGA emits it, the low-latency mode; with --sync async each part is fused at once)")
        ->check(CLI::IsMember({"field", "blob"}));
    eyesim::app::add_report_delay_option(sub, opt->report_delay_ms, tr::AsyncOptions::kMaxReportDelayUs * 1e-3);
    sub.add_flag("--no-trocar", opt->no_trocar, "do not use the trocar as a point on the instrument shaft");
    sub.add_flag("--no-image-model", opt->no_image_model,
                 "move each marker's centroid back by a uniform disc less its shaft only, not by the shaded sphere's "
                 "image less its shaft sampled on the field's lines (the eye's correction at its outline stays)");
    sub.add_option("--truth-noise-px", opt->truth_noise_px, "noise added to truth centroids in the comparison run")
        ->check(eyesim::app::finite_in(0.0, 10.0));
    sub.add_flag("--truth-projected", opt->truth_projected,
                 "comparison run from projected marker centres instead of rendered centroids");
    sub.add_option("--sigma-px", opt->sigma_px, "centroid noise assumed for the covariance (frame px)")
        ->check(eyesim::app::finite_in(1e-4, 10.0));
    sub.add_option("--bodies", opt->bodies, "marker bodies JSON (default: scenes/bodies.json)");
    sub.add_flag("--refine", opt->refine,
                 "refine each blob's centroid by the refinement stage (a marker model fit on its patch) before packing");
    sub.add_flag("--no-hints", opt->no_hints,
                 "with --refine: fit every marker as a whole sphere (by default a marker's fit leaves out what hides "
                 "part of it, its instrument's shaft or the eye, placed from the chain's newest poses)");
    sub.add_option("--seed", opt->seed, "seed of the truth-centroid noise")->check(eyesim::app::unsigned_integer());
    sub.add_option("--write-capture", opt->write_capture,
                   "also write the FPGA chain's packets as a capture file (modelled receive times)");
    return [opt]() -> int { return run_validate(*opt); };
}};

}  // namespace
