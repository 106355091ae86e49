// `eyesim validate`: FPGA model → FieldMarkers packets (the firmware's wire conversion, encoded and parsed) →
// tracking, over a recording with ground truth; accuracy, latency and drop statistics, optional report.
#include "eyesim/app/command.hpp"
#include "eyesim/app/refine.hpp"

#include "eyesim/firmware/latency.hpp"
#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/fpga/register_map.hpp"
#include "eyesim/fpga/timing.hpp"
#include "eyesim/fpga/wire.hpp"
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
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

namespace tr = eyesim::tracking;
namespace rig = eyesim::rig;
namespace proto = eyesim::protocol;
using eyesim::app::Error;

struct ValidateOptions {
    std::string dir;
    std::string report;
    bool json = false;
    int max_fields = 0;
    std::string sync = "interpolate";
    bool no_trocar = false;
    double truth_noise_px = 0.02;
    bool truth_projected = false;
    std::string write_capture;
    double sigma_px = 0.05;
    std::string bodies;
    std::uint64_t seed = 1;
    bool refine = false;
};

/// Everything collected from one tracking run.
struct RunStats {
    std::string name;
    std::vector<double> marker_err_um, marker_err_eye_um, marker_err_inst_um, marker_err_occluded_um;
    std::vector<double> tip_err_um, tip_eye_err_um, axis_err_deg, insertion_err_um, eye_err_deg;
    std::vector<double> latency_end_to_ready_us, latency_end_to_received_us, latency_sample_to_ready_us;
    std::vector<double> compute_us;
    // Per frame, for the time plot: time (s), marker RMS (µm), tip error per instrument (µm, −1 if none).
    std::vector<double> frame_t_s, frame_marker_rms_um, frame_eye_deg;
    std::vector<std::vector<double>> frame_tip_um;
    // Per scored marker, for the volume plot.
    std::vector<Eigen::Vector3d> marker_pos_mm;
    std::vector<double> marker_pos_err_um;
    long frames = 0, two_view_frames = 0, too_few_camera_frames = 0, ghosts = 0, images_dropped_sync = 0,
         images_unmatched = 0, markers_unassigned = 0, truth_visible2 = 0, eye_held = 0;
    std::vector<long> tip_held;
};

/// Per-camera centroid comparison (FPGA path only).
struct CentroidStats {
    std::vector<double> err_px;
    long blobs = 0, matched = 0, missed = 0, spurious = 0, fields_with_drops = 0;
};

double us_now() {
    return std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

tr::SyncMode parse_sync(const std::string& s) {
    if (s == "interpolate") return tr::SyncMode::Interpolate;
    if (s == "extrapolate") return tr::SyncMode::Extrapolate;
    return tr::SyncMode::Nearest;
}

/// One FieldMarkers message with its modelled host receive time.
struct Timed {
    double received_us;
    proto::FieldMarkers msg;
};

/// Feeds messages of one field index into the tracker (in receive order) and scores the frames that come out.
class Runner {
public:
    Runner(std::string name, const tr::TrackerConfig& cfg, const std::vector<rig::FieldTruth>& truth)
        : tracker_(cfg), bodies_(cfg.bodies), truth_(truth) {
        stats_.name = std::move(name);
        stats_.tip_held.assign(std::size_t(cfg.bodies.instrument_count), 0);
        stats_.frame_tip_um.resize(std::size_t(cfg.bodies.instrument_count));
    }

    void push(std::vector<Timed>& msgs) {
        std::stable_sort(msgs.begin(), msgs.end(),
                         [](const Timed& a, const Timed& b) { return a.received_us < b.received_us; });
        for (const Timed& t : msgs) {
            tracker_.push(t.msg, t.received_us);
            drain(t.received_us);
        }
    }

    void finish(double now_us) {
        tracker_.finish();
        drain(now_us);
    }

    RunStats& stats() { return stats_; }

private:
    void drain(double now_us) {
        while (tracker_.pop(frame_, now_us)) score();
    }

    void score() {
        RunStats& s = stats_;
        ++s.frames;
        if (frame_.flags & tr::kFrameTwoView) ++s.two_view_frames;
        if (frame_.flags & tr::kFrameTooFewCameras) ++s.too_few_camera_frames;
        s.images_dropped_sync += frame_.images_dropped_sync;
        s.images_unmatched += frame_.markers.unmatched_images;
        s.markers_unassigned += frame_.markers_unassigned;
        s.compute_us.push_back(frame_.timing.compute_us);
        s.latency_end_to_ready_us.push_back(frame_.timing.poses_ready_host_us - frame_.timing.field_end_host_us);
        s.latency_end_to_received_us.push_back(frame_.timing.received_host_us - frame_.timing.field_end_host_us);
        s.latency_sample_to_ready_us.push_back(frame_.timing.poses_ready_host_us - frame_.timing.sample_host_us);
        if (frame_.reference_field >= truth_.size()) return;
        const rig::FieldTruth& truth = truth_[frame_.reference_field];
        const tr::FrameScore fs = tr::score_frame(frame_, bodies_, truth);
        s.ghosts += fs.ghosts;
        s.truth_visible2 += fs.truth_markers_visible2;
        double ss = 0;
        for (const tr::MarkerScore& m : fs.markers) {
            const double e = m.error_mm * 1e3;
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
            s.tip_eye_err_um.push_back(fs.tip_eye_error_mm[b] * 1e3);
            s.axis_err_deg.push_back(fs.axis_error_deg[b]);
            if (fs.insertion_error_mm[b] >= 0) s.insertion_err_um.push_back(fs.insertion_error_mm[b] * 1e3);
        }
    }

    tr::Tracker tracker_;
    tr::BodySet bodies_;
    const std::vector<rig::FieldTruth>& truth_;
    tr::TrackingFrame frame_;
    RunStats stats_;
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
    j["tip_rms_um"] = rms(s.tip_err_um);
    j["tip_um"] = summary_json(s.tip_err_um);
    j["tip_eye_frame_um"] = summary_json(s.tip_eye_err_um);
    j["axis_deg"] = summary_json(s.axis_err_deg);
    j["insertion_um"] = summary_json(s.insertion_err_um);
    j["eye_rot_rms_deg"] = rms(s.eye_err_deg);
    j["eye_rot_deg"] = summary_json(s.eye_err_deg);
    j["latency_us"] = latency_json(s.latency_end_to_ready_us);
    j["latency_field_end_to_received_us"] = latency_json(s.latency_end_to_received_us);
    j["latency_exposure_to_poses_us"] = latency_json(s.latency_sample_to_ready_us);
    j["tracking_compute_us"] = latency_json(s.compute_us);
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
    nlohmann::json held = nlohmann::json::object();
    for (int b = 0; b < bodies.instrument_count; ++b)
        held[bodies.instruments[std::size_t(b)].name] = s.tip_held[std::size_t(b)];
    j["instrument_not_measured_frames"] = held;
    return j;
}

// ------------------------------------------------------------------------------------------------------------
// The command
// ------------------------------------------------------------------------------------------------------------

int run_validate(const ValidateOptions& opt) {
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
    for (const std::string& w : rec.warnings()) warn(w);
    const std::string truth_path = rec.truth_path();
    if (truth_path.empty()) throw Error(opt.dir + "/truth.jsonl: missing (validate needs ground truth)");
    std::vector<rig::FieldTruth> truth;
    rig::Bodies bodies;
    try {
        truth = rig::read_truth(truth_path);
        bodies = rig::load_bodies(opt.bodies.empty() ? rig::default_bodies_path() : opt.bodies);
    } catch (const rig::RigError& e) {
        throw Error(e.what());
    }
    if (truth.empty()) throw Error(truth_path + ": no lines");
    const int ncam = rec.camera_count();
    if (ncam < 2 || ncam > tr::kMaxCameras)
        throw Error(opt.dir + "/rig.yaml: camera_count: " + std::to_string(ncam) + " (need 2.." +
                    std::to_string(tr::kMaxCameras) + ")");
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
    if (std::int64_t(truth.size()) < streams)
        warn(fmt::format("{}: truth for {} fields, the streams have {}: the last {} fields are not scored", truth_path,
                         truth.size(), streams, streams - std::int64_t(truth.size())));
    const std::int64_t n = std::min<std::int64_t>(streams, std::int64_t(truth.size()));
    if (n < 3) throw Error(opt.dir + ": only " + std::to_string(n) + " fields with truth (need at least 3)");

    // Tracker configuration: rig cameras, the scene's instruments (from the truth), FPGA field timing.
    std::vector<tr::SceneInstrument> scene;
    for (const rig::InstrumentTruth& it : truth[0].instruments) scene.push_back({it.kind, it.trocar});
    tr::TrackerConfig cfg;
    try {
        cfg.bodies = tr::body_set(bodies, scene);
    } catch (const std::invalid_argument& e) {
        throw Error(std::string(e.what()));
    }
    const double end_after_start_us =
        double(eyesim::fpga::device_time_us(0, eyesim::fpga::active_line_end_cycle(eyesim::fpga::kActiveLinesPerField - 1)));
    for (const rig::CameraModel& cm : rec.cameras()) {
        cfg.cameras.push_back(tr::camera_geometry(cm));
        // Device field_end = field start (vertical sync = exposure end) + the FPGA's end-of-active-video time; the
        // frame's instant is the exposure mid-time, half a shutter before the start.
        tr::CameraTiming t;
        t.end_to_sample_us = {end_after_start_us + 0.5 * cm.exposure_us, end_after_start_us + 0.5 * cm.exposure_us};
        cfg.timing.push_back(t);
    }
    cfg.sync.mode = parse_sync(opt.sync);
    cfg.pose.trocar_constraint = !opt.no_trocar;
    cfg.centroid_sigma_px = opt.sigma_px;
    for (const auto& g : cfg.cameras)
        if (!g.valid()) throw Error(opt.dir + "/rig.yaml: a camera has invalid intrinsics or rotation");

    Runner fpga_run("fpga", cfg, truth);
    tr::TrackerConfig cfg_truth = cfg;
    cfg_truth.centroid_sigma_px = std::max(opt.truth_noise_px, 0.005);
    Runner truth_run("truth_centroids", cfg_truth, truth);

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
    if (opt.refine) refiner = std::make_unique<eyesim::app::BlobRefiner>();
    long refined = 0;

    for (std::int64_t i = 0; i < n; ++i) {
        std::vector<Timed> fpga_msgs, truth_msgs;
        for (int c = 0; c < ncam; ++c) {
            const rig::FieldTiming ft = rec.field_timing(c, i);
            const int parity = ft.parity;
            const std::uint64_t start_us = std::uint64_t(std::llround(std::max(0.0, ft.start_us)));
            try {
                rec.read_field(c, i, field.data());
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
                refined += refiner->refine(field.data(), rig::kFieldHeight, blobs);
                refine_us += us_now() - r0;
            }
            const eyesim::fpga::FieldInfo info =
                eyesim::fpga::field_info(pipe.field_stats(), std::uint8_t(c), std::uint8_t(parity), start_us);
            if (info.blobs_dropped) ++fields_with_drops;
            const std::size_t nm = eyesim::fpga::to_field_markers(blobs.data(), blobs.size(), info, msgs.data(), msgs.size());
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
            // --- Centroid error against the rendered intensity centroid of each visible marker. ---
            CentroidStats& cs = cstats[std::size_t(c)];
            std::vector<bool> used;
            std::vector<rig::DetectedMarker> got;
            for (std::size_t k = 0; k < nm; ++k)
                for (int m = 0; m < msgs[k].marker_count; ++m) {
                    const proto::Marker& mk = msgs[k].markers[std::size_t(m)];
                    got.push_back({mk.colour_class, Eigen::Vector2d(double(mk.x_q16) / proto::kCoordScale,
                                                                    double(mk.y_q16) / proto::kCoordScale)});
                }
            cs.blobs += long(got.size());
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
        fpga_run.push(fpga_msgs);
        truth_run.push(truth_msgs);
        if (progress && (i % 10 == 0 || i + 1 == n))
            std::fprintf(stderr, "\rvalidate: field %lld/%lld", static_cast<long long>(i + 1), static_cast<long long>(n));
    }
    parser.finish([&](const proto::DecodedFrame&) {});
    if (!opt.write_capture.empty()) capture.close();
    parse_errors = long(parser.stats().errors());
    const double end_us = 1e300;
    fpga_run.finish(end_us);
    truth_run.finish(end_us);
    if (progress) std::fprintf(stderr, "\n");
    const double wall_s = (us_now() - t_start) * 1e-6;
    const RunStats& fs = fpga_run.stats();
    const RunStats& ts = truth_run.stats();

    // ---- Nothing to score is an error, not a perfect score; a body never measured is a warning ----
    if (fs.marker_err_um.empty() && fs.marker_err_occluded_um.empty()) {
        long found = 0, at_truth = 0;
        for (const CentroidStats& cs : cstats) found += cs.blobs, at_truth += cs.matched;
        if (found == 0)
            throw Error(fmt::format("{}: no marker found in {} fields: the FPGA model found no blob in any of the {} "
                                    "cameras", opt.dir, n, ncam));
        throw Error(fmt::format("{}: no marker matched in {} fields: the FPGA model found {} blobs ({} at a truth "
                                "centroid), no triangulated marker was within reach of a truth marker",
                                opt.dir, n, found, at_truth));
    }
    const auto unmeasured = [&](const std::string& body, std::size_t fpga_measured, std::size_t truth_measured) {
        if (fpga_measured == 0)
            warn(fmt::format("{}: {} not measured in any of the {} scored frames (FPGA chain; from truth centroids "
                             "in {}): its figures are not measured", opt.dir, body, fs.frame_t_s.size(),
                             truth_measured));
    };
    unmeasured("eye", fs.eye_err_deg.size(), ts.eye_err_deg.size());
    for (int b = 0; b < cfg.bodies.instrument_count; ++b) {
        const std::size_t k = std::size_t(b);
        unmeasured(cfg.bodies.instruments[k].name, fs.frame_t_s.size() - std::size_t(fs.tip_held[k]),
                   ts.frame_t_s.size() - std::size_t(ts.tip_held[k]));
    }

    // ---- Summaries ----
    nlohmann::json j;
    j["recording"] = opt.dir;
    j["fields"] = n;
    j["cameras"] = ncam;
    j["fields_per_s"] = double(n * ncam) / std::max(wall_s, 1e-9);
    j["sync"] = opt.sync;
    j["trocar_constraint"] = !opt.no_trocar;
    nlohmann::json cams = nlohmann::json::array();
    std::vector<double> all_c;
    for (int c = 0; c < ncam; ++c) {
        CentroidStats& cs = cstats[std::size_t(c)];
        all_c.insert(all_c.end(), cs.err_px.begin(), cs.err_px.end());
        const nlohmann::json s = summary_json(cs.err_px);
        cams.push_back({{"camera", c},
                        {"centroid_rms_px", s["rms"]},
                        {"centroid_p95_px", s["p95"]},
                        {"centroid_max_px", s["max"]},
                        {"blobs", cs.blobs},
                        {"matched", cs.matched},
                        {"missed_visible_markers", cs.missed},
                        {"spurious_blobs", cs.spurious}});
    }
    j["per_camera"] = cams;
    j["centroid_rms_px"] = rms(all_c);
    j["fields_with_dropped_blobs"] = fields_with_drops;
    j["fpga_us_per_field"] = fpga_us / double(n * ncam);
    if (refiner) {
        j["refined"] = refined;
        j["refused"] = refiner->refusals_json();
        j["refine_us_per_field"] = refine_us / double(n * ncam);
    }
    // Headline keys: the full chain from the FPGA model.
    const nlohmann::json fj = run_json(fs, cfg.bodies);
    for (const char* k : {"marker3d_rms_um", "tip_rms_um", "eye_rot_rms_deg", "latency_us"}) j[k] = fj[k];
    j["fpga_chain"] = fj;
    j["truth_centroids"] = run_json(ts, cfg.bodies);
    j["truth_centroids"]["noise_px"] = opt.truth_noise_px;
    j["errors"] = parse_errors;
    j["warnings"] = warnings;

    if (!opt.report.empty()) {
        namespace fsys = std::filesystem;
        std::error_code ec;
        fsys::create_directories(opt.report, ec);
        if (ec) throw Error(opt.report + ": cannot create directory: " + ec.message());
        const std::string d = opt.report + "/";
        std::vector<std::pair<std::string, std::vector<double>>> cset;
        for (int c = 0; c < ncam; ++c) cset.push_back({fmt::format("camera {}", c), cstats[std::size_t(c)].err_px});
        plot_histogram(d + "centroid_error_hist.png", "FPGA centroid error vs rendered centroid", "error (field px)", cset);
        plot_histogram(d + "marker3d_error_hist.png", "3D marker error", "error (um)",
                       {{"FPGA chain", fs.marker_err_um}, {"truth centroids + noise", ts.marker_err_um}});
        plot_histogram(d + "tip_error_hist.png", "Instrument tip error (rig frame)", "error (um)",
                       {{"FPGA chain", fs.tip_err_um}, {"truth centroids + noise", ts.tip_err_um}});
        std::vector<std::pair<std::string, std::vector<double>>> series{{"3D marker RMS per frame (um)", fs.frame_marker_rms_um}};
        for (int b = 0; b < cfg.bodies.instrument_count; ++b)
            series.push_back({cfg.bodies.instruments[std::size_t(b)].name + " tip error (um)", fs.frame_tip_um[std::size_t(b)]});
        plot_series(d + "error_over_time.png", "FPGA chain: error over time (red ticks: not measured)", "um",
                    fs.frame_t_s, series);
        plot_series(d + "eye_error_over_time.png", "FPGA chain: eye rotation error over time", "deg", fs.frame_t_s,
                    {{"eye rotation error (deg)", fs.frame_eye_deg}});
        plot_volume(d + "marker_error_volume.png", fs.marker_pos_mm, fs.marker_pos_err_um);
        std::ofstream md(d + "report.md");
        if (!md) throw Error(d + "report.md: cannot write");
        const auto row = [&](const char* what, const nlohmann::json& a, const nlohmann::json& b, const char* unit) {
            md << fmt::format("| {} ({}) | {} | {} | {} | {} | {} | {} |\n", what, unit, figure(a["rms"], "{:.3f}"),
                              figure(a["p95"], "{:.3f}"), figure(a["max"], "{:.3f}"), figure(b["rms"], "{:.3f}"),
                              figure(b["p95"], "{:.3f}"), figure(b["max"], "{:.3f}"));
        };
        md << "# Tracking validation: " << opt.dir << "\n\n";
        md << fmt::format("{} fields x {} cameras, sync {}, trocar constraint {}, centroid sigma assumed {} px.\n\n", n,
                          ncam, opt.sync, opt.no_trocar ? "off" : "on", opt.sigma_px);
        md << "## Centroids (FPGA model vs rendered intensity centroid, field pixels)\n\n";
        md << "| camera | RMS | p95 | max | blobs | matched | missed | spurious |\n|---|---|---|---|---|---|---|---|\n";
        for (const auto& c : cams)
            md << fmt::format("| {} | {} | {} | {} | {} | {} | {} | {} |\n", c["camera"].get<int>(),
                              figure(c["centroid_rms_px"], "{:.4f}"), figure(c["centroid_p95_px"], "{:.4f}"),
                              figure(c["centroid_max_px"], "{:.4f}"), c["blobs"].get<long>(), c["matched"].get<long>(),
                              c["missed_visible_markers"].get<long>(), c["spurious_blobs"].get<long>());
        md << "\n![centroid error](centroid_error_hist.png)\n\n";
        md << "## Poses (FPGA chain | truth centroids + " << opt.truth_noise_px << " px noise)\n\n";
        md << "3D marker rows exclude markers the tracker flags as partly occluded (fewer than two unoccluded "
              "views); those are listed apart.\n\n";
        md << "| quantity | RMS | p95 | max | RMS | p95 | max |\n|---|---|---|---|---|---|---|\n";
        const nlohmann::json tj = j["truth_centroids"];
        row("3D marker error", fj["marker3d_um"], tj["marker3d_um"], "um");
        row("3D marker error, eye", fj["marker3d_eye_um"], tj["marker3d_eye_um"], "um");
        row("3D marker error, instruments", fj["marker3d_instrument_um"], tj["marker3d_instrument_um"], "um");
        row("3D error of markers flagged occluded", fj["marker3d_flagged_occluded_um"],
            tj["marker3d_flagged_occluded_um"], "um");
        row("tip error, rig frame", fj["tip_um"], tj["tip_um"], "um");
        row("tip error, eye frame", fj["tip_eye_frame_um"], tj["tip_eye_frame_um"], "um");
        row("axis error", fj["axis_deg"], tj["axis_deg"], "deg");
        row("insertion depth error", fj["insertion_um"], tj["insertion_um"], "um");
        row("eye rotation error", fj["eye_rot_deg"], tj["eye_rot_deg"], "deg");
        md << "\n![3D error](marker3d_error_hist.png)\n\n![tip error](tip_error_hist.png)\n\n";
        md << "![error over time](error_over_time.png)\n\n![eye error over time](eye_error_over_time.png)\n\n";
        md << "![error across the working volume](marker_error_volume.png)\n\n";
        md << "## Latency (modelled device and link, measured tracking), us\n\n| span | p50 | p99 | max |\n|---|---|---|---|\n";
        for (const auto& [name, key] : std::vector<std::pair<std::string, std::string>>{
                 {"field end -> packet received", "latency_field_end_to_received_us"},
                 {"field end -> poses ready", "latency_us"},
                 {"exposure mid -> poses ready", "latency_exposure_to_poses_us"},
                 {"tracking stage compute", "tracking_compute_us"}})
            md << fmt::format("| {} | {} | {} | {} |\n", name, figure(fj[key]["p50"], "{:.1f}"),
                              figure(fj[key]["p99"], "{:.1f}"), figure(fj[key]["max"], "{:.1f}"));
        md << "\n## Drops and rejections (FPGA chain)\n\n```\n" << fj["markers"].dump(1) << "\n"
           << "frames " << fj["frames"] << ", two-view frames " << fj["frames_two_view"]
           << ", eye not measured " << fj["eye_not_measured_frames"] << ", instruments not measured "
           << fj["instrument_not_measured_frames"].dump() << ", fields with dropped blobs " << fields_with_drops
           << ", parse errors " << parse_errors << "\n```\n";
        j["report"] = d + "report.md";
    }

    if (opt.json) {
        std::printf("%s\n", j.dump().c_str());
    } else {
        std::printf("%s: %lld fields x %d cameras (sync %s)\n", opt.dir.c_str(), static_cast<long long>(n), ncam,
                    opt.sync.c_str());
        std::printf("  centroids (FPGA%s vs rendered): RMS %s\n", refiner ? " + refinement" : "",
                    figure(j["centroid_rms_px"], "{:.4f} px").c_str());
        for (const auto& [label, r] : std::vector<std::pair<std::string, nlohmann::json>>{
                 {"FPGA chain", fj}, {fmt::format("truth centroids + {} px", opt.truth_noise_px), j["truth_centroids"]}}) {
            const std::string marker = r["marker3d_rms_um"].is_null()
                                           ? "not measured"
                                           : fmt::format("{:.1f} um (p95 {:.1f})", r["marker3d_rms_um"].get<double>(),
                                                         r["marker3d_um"]["p95"].get<double>());
            std::printf("  %-28s 3D marker RMS %s, tip RMS %s, eye RMS %s, frames %ld\n", label.c_str(),
                        marker.c_str(), figure(r["tip_rms_um"], "{:.1f} um").c_str(),
                        figure(r["eye_rot_rms_deg"], "{:.4f} deg").c_str(), r["frames"].get<long>());
        }
        std::printf("  latency field end -> poses ready: p50 %s, p99 %s, max %s\n",
                    figure(fj["latency_us"]["p50"], "{:.0f} us").c_str(),
                    figure(fj["latency_us"]["p99"], "{:.0f} us").c_str(),
                    figure(fj["latency_us"]["max"], "{:.0f} us").c_str());
        if (j.contains("report")) std::printf("  report: %s\n", j["report"].get<std::string>().c_str());
    }
    return 0;
}

eyesim::app::Registrar reg{"validate", "Validate tracking (FPGA model -> packets -> tracker) against recording truth",
                           [](CLI::App& sub) {
    auto opt = std::make_shared<ValidateOptions>();
    sub.add_option("--recording", opt->dir, "recording directory with rig.yaml, cam*.uyvy and truth.jsonl")->required();
    sub.add_option("--report", opt->report, "write report.md and PNG plots into this directory");
    sub.add_flag("--json", opt->json, "print one JSON summary object on stdout");
    sub.add_option("--max-fields", opt->max_fields, "use at most this many fields (0: all)")
        ->check(eyesim::app::finite_in(0.0, 1e9));
    sub.add_option("--sync", opt->sync, "camera time alignment: interpolate | extrapolate | nearest")
        ->check(CLI::IsMember({"interpolate", "extrapolate", "nearest"}));
    sub.add_flag("--no-trocar", opt->no_trocar, "do not use the trocar as a point on the instrument shaft");
    sub.add_option("--truth-noise-px", opt->truth_noise_px, "noise added to truth centroids in the comparison run")
        ->check(eyesim::app::finite_in(0.0, 10.0));
    sub.add_flag("--truth-projected", opt->truth_projected,
                 "comparison run from projected marker centres instead of rendered centroids");
    sub.add_option("--sigma-px", opt->sigma_px, "centroid noise assumed for the covariance (frame px)")
        ->check(eyesim::app::finite_in(1e-4, 10.0));
    sub.add_option("--bodies", opt->bodies, "marker bodies JSON (default: scenes/bodies.json)");
    sub.add_flag("--refine", opt->refine,
                 "refine each blob's centroid by the refinement stage (a marker model fit on its patch) before packing");
    sub.add_option("--seed", opt->seed, "seed of the truth-centroid noise")->check(eyesim::app::unsigned_integer());
    sub.add_option("--write-capture", opt->write_capture,
                   "also write the FPGA chain's packets as a capture file (modelled receive times)");
    return [opt]() -> int { return run_validate(*opt); };
}};

}  // namespace
