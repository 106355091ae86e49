#include "eyesim/app/run_scene.hpp"

#include "eyesim/app/command.hpp"
#include "eyesim/app/frame_loop.hpp"
#include "eyesim/app/refine.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/scenario.hpp"
#include "eyesim/rig/truth.hpp"
#include "eyesim/sim/scenes/scene.hpp"
#include "eyesim/tracking/validation.hpp"
#include "eyesim/transport/transport.hpp"

#include <fmt/format.h>

#include <cmath>
#include <filesystem>

namespace eyesim::app {

namespace tr = eyesim::tracking;

namespace {

/// Accumulates tracking errors against truth, frame by frame.
struct AccuracyAccumulator {
    const std::vector<rig::FieldTruth>* truth = nullptr;
    const tr::BodySet* bodies = nullptr;
    std::vector<double> marker_um, tip_um, eye_deg;
    size_t frames = 0;

    void add(const tr::TrackingFrame& f) {
        if (!truth || f.reference_field >= truth->size()) return;
        const tr::FrameScore s = tr::score_frame(f, *bodies, (*truth)[f.reference_field]);
        ++frames;
        for (const auto& m : s.markers)
            if (m.id >= 0) marker_um.push_back(m.error_mm * 1e3);
        for (double e : s.tip_error_mm)
            if (e >= 0) tip_um.push_back(e * 1e3);
        if (s.eye_error_deg >= 0) eye_deg.push_back(s.eye_error_deg);
    }
    AccuracySummary summary() {
        AccuracySummary a;
        if (!truth || frames == 0) return a;
        a.available = true;
        a.frames = frames;
        const tr::ErrorSummary m = tr::summarise(marker_um), t = tr::summarise(tip_um), e = tr::summarise(eye_deg);
        a.marker3d_rms_um = m.rms;
        a.marker3d_p95_um = m.p95;
        a.tip_rms_um = t.rms;
        a.tip_p95_um = t.p95;
        a.eye_rot_rms_deg = e.rms;
        return a;
    }
};

int count_sources(const SourceSpec& s) {
    return int(!s.connect.empty()) + int(!s.capture.empty()) + int(!s.recording.empty()) + int(!s.scenario.empty());
}

}  // namespace

int run_scene(const SceneRunRequest& req) {
    if (count_sources(req.source) != 1)
        throw Error("give exactly one source: --connect, --capture, --recording or --scenario", 2);
    if (!req.source.connect.empty()) {  // a malformed URI is a usage error (a device that is not there: exit 1)
        try {
            transport::check_transport_uri(req.source.connect);
        } catch (const transport::UriError& e) {
            throw Error(std::string("--connect: ") + e.what(), 2);
        }
    }
    if (req.precision && req.source.connect.empty() && req.source.capture.empty())
        throw Error("--precision refines markers on a device's patches: it needs --connect or --capture", 2);
    if (req.no_hints && !req.precision) throw Error("--no-hints needs --precision", 2);
    sim::scenes::Scene scene;
    try {
        scene = sim::scenes::load_scene(req.scene_path);
    } catch (const sim::scenes::SceneError& e) {
        throw Error(e.what());
    }
    rig::Bodies bodies;
    try {
        bodies = rig::load_bodies(rig::default_bodies_path());
    } catch (const rig::RigError& e) {
        throw Error(e.what());
    }
    Simulator sim(scene);
    RunReport report;
    RunStats stats;
    report.title = req.title;
    report.sim = &sim;

    // Snapshots: spread over the expected run length, taken after the frame that crosses each time.
    std::unique_ptr<Snapshotter> snapper;
    std::vector<double> snap_times;
    size_t next_snap = 0;
    const double expected_s = req.expected_s > 0 ? req.expected_s : req.seconds > 0 ? req.seconds : scene.duration_s;
    if (!req.report_dir.empty() && req.snapshots > 0) {
        snapper = std::make_unique<Snapshotter>(640, 480);
        snapper->set_objects(scene.collision.convex_objects);
        if (!snapper->available()) report.warnings.push_back("no pictures: " + snapper->error());
        else report.renderer = snapper->renderer_name();
        for (int k = 0; k < req.snapshots; ++k) snap_times.push_back(expected_s * (k + 1) / (req.snapshots + 1));
    }
    // Snapshots: the state is copied during the run and rendered after it, so pictures never delay tracking.
    std::vector<SceneCopy> copies, movie;
    const bool animate = !req.report_dir.empty() && req.animation_fps > 0;
    double next_movie_s = 0.0;
    auto maybe_snap = [&](double t_s) {
        if (animate && t_s >= next_movie_s) {
            // Copied now, rendered after the run (like the snapshots); a few frames per second of the run.
            next_movie_s = (std::floor(t_s * req.animation_fps + 1e-6) + 1.0) / req.animation_fps - 1e-6;  // on a grid
            movie.push_back(copy_scene(sim));
        }
        if (!snapper || !snapper->available() || next_snap >= snap_times.size() || t_s < snap_times[next_snap]) return;
        ++next_snap;
        copies.push_back(copy_scene(sim));
    };
    auto render_snaps = [&] {
        for (const SceneCopy& c : copies) {
            const std::string file = fmt::format("stereo_{:05.2f}s.png", c.time_s);
            const double t0 = host_now_us();
            if (snapper->snap(c, req.report_dir + "/" + file)) report.snapshots.push_back({c.time_s, file});
            else report.warnings.push_back("snapshot failed: " + snapper->error());
            sim.record_render_us(c.frame, host_now_us() - t0);
        }
    };
    if (!req.report_dir.empty()) {
        std::error_code ec;
        std::filesystem::create_directories(req.report_dir, ec);
        if (ec) throw Error(req.report_dir + ": cannot create report folder: " + ec.message());
    }

    if (!req.source.scenario.empty()) {
        // Truth poses straight into the simulator: no cameras, no tracking (fast scripted runs).
        report.source = "scenario '" + req.source.scenario + "' (truth poses, no tracking)";
        rig::Scenario sc = [&] {
            try {
                return rig::Scenario::make(req.source.scenario, req.seed, expected_s * 1e6, bodies);
            } catch (const rig::RigError& e) {
                throw Error(e.what());
            }
        }();
        const int frames = int(std::lround(expected_s * 50.0));
        for (int k = 0; k < frames; ++k) {
            const FramePoses p = poses_from_truth(sc.state_at(k * 20000.0));
            sim.step(p);
            maybe_snap(p.time_s);
        }
    } else {
        // Cameras and truth.
        std::vector<rig::CameraModel> cams;
        std::vector<rig::FieldTruth> truth;
        std::vector<tr::SceneInstrument> instruments;
        std::unique_ptr<rig::Recording> rec;
        std::string truth_path = req.truth_path;
        try {
            if (!req.source.recording.empty()) {
                rec = std::make_unique<rig::Recording>(rig::Recording::open(req.source.recording));
                for (std::string& w : rec->take_warnings()) report.warnings.push_back(std::move(w));
                cams = rec->cameras();
                if (truth_path.empty()) truth_path = rec->truth_path();
            }
            if (!req.rig_path.empty()) cams = rig::load_rig_yaml(req.rig_path);
            if (cams.empty()) cams = rig::default_rig();
            if (!truth_path.empty()) truth = rig::read_truth(truth_path);
        } catch (const rig::RigError& e) {
            throw Error(e.what());
        }
        if (!truth.empty())
            for (const auto& it : truth[0].instruments) instruments.push_back({it.kind, it.trocar});
        if (instruments.empty()) instruments = tr::all_instruments(bodies);
        tr::TrackerConfig cfg = tracker_config(cams, bodies, instruments);
        try {
            cfg.sync.mode = tr::sync_mode_from_name(req.sync);
            cfg.async.report_delay_us = 1000.0 * req.report_delay_ms;
        } catch (const std::invalid_argument& e) {
            throw Error(e.what());
        }
        const tr::BodySet tracked_bodies = cfg.bodies;  // cfg moves into the tracker
        AccuracyAccumulator acc;
        if (!truth.empty()) {
            acc.truth = &truth;
            acc.bodies = &tracked_bodies;
        }
        HostRun run(std::move(cfg), sim);
        constexpr uint8_t kAllClasses = 0xF;  // precision mode: every camera's patches of every class
        if (req.precision)
            run.enable_precision(frame::patch_fit_config(rig_sphere_fit_config()), kAllClasses, !req.no_hints);
        run.set_hook([&](const tr::TrackingFrame& f, const FramePoses& p) {
            acc.add(f);
            maybe_snap(p.time_s);
        });
        if (rec) {
            report.source = "recording " + req.source.recording + " (FPGA model in-process)";
            run_recording(*rec, run, req.seconds > 0 ? int64_t(std::lround(req.seconds * 50)) : 0);
            for (std::string& w : rec->take_warnings()) report.warnings.push_back(std::move(w));  // fields lost
        } else if (!req.source.capture.empty()) {
            report.source = "capture " + req.source.capture;
            run_capture(req.source.capture, run, report.warnings);
        } else {
            report.source = "device " + req.source.connect;
            frame::LiveOptions lo;
            lo.max_seconds = req.seconds;
            lo.stall_seconds = req.stall_seconds;
            if (req.precision) lo.patch_enable = kAllClasses;
            const frame::LiveResult live = run_live(req.source.connect, run, lo);
            report.link_end = live.end;
            for (const std::string& w : live.warnings) report.warnings.push_back(w);
        }
        if (const std::string lost = frame::loss_summary(run.stats().loss); !lost.empty())
            report.warnings.push_back(report.source + ": " + lost);
        report.accuracy = acc.summary();
        if (run.stats().frames == 0) throw Error(report.source + ": no tracking frames (no markers received)");
        stats = run.stats();
        report.stats = &stats;
    }
    render_snaps();
    if (animate && !movie.empty()) {
        // Half the snapshots' size per view: the animation is for following the procedure, the PNGs for detail.
        Snapshotter small(320, 240);
        small.set_objects(scene.collision.convex_objects);
        std::string error;
        if (!small.available()) report.warnings.push_back("no animation: " + small.error());
        else if (write_animation(req.report_dir + "/animation.mp4", movie, req.animation_fps, small, error)) {
            report.animation = "animation.mp4";
            report.animation_frames = movie.size();
        } else {
            report.warnings.push_back("no animation: " + error);
        }
    }
    // Warnings go to stderr, one line each; stdout keeps the report (the JSON object also lists them).
    for (const std::string& w : report.warnings) std::fprintf(stderr, "eyesim: warning: %s\n", w.c_str());
    if (req.json) std::printf("%s\n", report_json(report).dump().c_str());
    else print_report(stdout, report);
    if (!req.report_dir.empty()) {
        const std::string index = write_report(req.report_dir, report);
        if (!req.json) std::printf("\nreport: %s\n", index.c_str());
    }
    return 0;
}

}  // namespace eyesim::app
