// `eyesim track`: FieldMarkers from a device (TCP or USB) or a capture file → tracking frames → poses.jsonl.
#include "eyesim/app/command.hpp"
#include "eyesim/app/frame_loop.hpp"
#include "eyesim/app/refine.hpp"
#include "eyesim/app/report.hpp"

#include "eyesim/protocol/capture.hpp"
#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/stream_parser.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/camera.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/tracking/pose_io.hpp"
#include "eyesim/tracking/rig_adapter.hpp"
#include "eyesim/tracking/tracker.hpp"
#include "eyesim/tracking/validation.hpp"
#include "eyesim/transport/clock_offset.hpp"
#include "eyesim/transport/transport.hpp"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <array>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace tr = eyesim::tracking;
namespace rig = eyesim::rig;
namespace proto = eyesim::protocol;
using eyesim::app::Error;

struct TrackOptions {
    std::string connect;
    bool usb = false;
    std::string capture;
    std::string capture_out;
    std::string rig;
    std::string out;
    bool json = false;
    std::string bodies;
    std::string instruments;
    std::string sync = "interpolate";
    double report_delay_ms = 19.0;
    double seconds = 0.0;
    double stall_s = eyesim::app::kDefaultStallSeconds;
    long max_frames = 0;
    bool precision = false;
    bool no_hints = false;  ///< precision mode without occlusion hints
};


/// The instruments to fit: named kinds ("pick,light_pipe"), or every kind of the bodies file.
std::vector<tr::SceneInstrument> scene_from(const std::string& list, const rig::Bodies& bodies) {
    if (list.empty()) return tr::all_instruments(bodies);
    std::vector<tr::SceneInstrument> out;
    std::stringstream ss(list);
    std::string name;
    while (std::getline(ss, name, ',')) {
        bool found = false;
        for (const rig::InstrumentBody& ib : bodies.instruments)
            if (ib.name == name) {
                out.push_back({ib.kind, ib.kind == rig::InstrumentKind::kLightPipe ? 1 : 0});
                found = true;
            }
        if (!found) {
            std::string known;
            for (const rig::InstrumentBody& ib : bodies.instruments) known += (known.empty() ? "" : ", ") + ib.name;
            throw Error("--instruments: unknown instrument \"" + name + "\" (known: " + known + ")", 2);
        }
    }
    return out;
}

int run_track(const TrackOptions& opt) {
    const int sources = int(!opt.connect.empty()) + int(opt.usb) + int(!opt.capture.empty());
    if (sources != 1) throw Error("track: give exactly one of --connect tcp://HOST:PORT, --usb, --capture FILE", 2);
    if (!opt.capture_out.empty() && !opt.capture.empty())
        throw Error("--capture-out records a live device (--connect or --usb), not a replay", 2);
    if (!opt.connect.empty()) {  // a malformed URI is a usage error, found before any file is read
        try {
            eyesim::transport::check_transport_uri(opt.connect);
        } catch (const eyesim::transport::UriError& e) {
            throw Error(std::string("--connect: ") + e.what(), 2);
        }
    }
    tr::TrackerConfig cfg;
    rig::Bodies bodies;
    try {
        const std::vector<rig::CameraModel> cams = rig::load_rig_yaml(opt.rig);
        bodies = rig::load_bodies(opt.bodies.empty() ? rig::default_bodies_path() : opt.bodies);
        for (const rig::CameraModel& cm : cams) {
            cfg.cameras.push_back(tr::camera_geometry(cm));
            cfg.timing.push_back(tr::camera_timing(cm));
        }
        cfg.bodies = tr::body_set(bodies, scene_from(opt.instruments, bodies));
    } catch (const rig::RigError& e) {
        throw Error(e.what());
    } catch (const std::invalid_argument& e) {
        throw Error(std::string(e.what()));
    }
    if (cfg.cameras.size() < 2 || cfg.cameras.size() > std::size_t(tr::kMaxCameras))
        throw Error(opt.rig + ": camera_count: " + std::to_string(cfg.cameras.size()) + " (need 2.." +
                    std::to_string(tr::kMaxCameras) + ")");
    cfg.sync.mode = tr::sync_mode_from_name(opt.sync);
    cfg.async.report_delay_us = 1000.0 * opt.report_delay_ms;
    const tr::BodySet body_set = cfg.bodies;
    std::unique_ptr<eyesim::frame::HostRun> run;
    try {
        run = std::make_unique<eyesim::frame::HostRun>(std::move(cfg));
    } catch (const eyesim::frame::SourceError& e) {
        throw Error(opt.rig + ": " + e.what());
    }
    // Precision mode: every class's patches from every camera (live: PATCH_ENABLE written before stream_start; a
    // capture: the patches it holds), each marker refined on its patch.
    constexpr uint8_t kAllClasses = 0xF;
    if (opt.no_hints && !opt.precision) throw eyesim::app::Error("--no-hints needs --precision", 2);
    if (opt.precision)
        run->enable_precision(eyesim::frame::patch_fit_config(eyesim::app::rig_sphere_fit_config()), kAllClasses,
                              !opt.no_hints);
    std::ofstream out;
    if (!opt.out.empty()) {
        out.open(opt.out);
        if (!out) throw Error(opt.out + ": cannot write");
    }
    long eye_measured = 0;
    std::array<long, tr::kMaxInstruments> instrument_measured{};
    run->set_hook([&](const tr::TrackingFrame& f, const eyesim::frame::FramePoses&) {
        if (f.eye.measured()) ++eye_measured;
        for (int b = 0; b < f.instrument_count; ++b)
            if (f.instruments[std::size_t(b)].measured()) ++instrument_measured[std::size_t(b)];
        if (out.is_open()) out << tr::frame_json_line(f, body_set) << '\n';
    });
    std::string source, end;
    bool clean = true;
    std::vector<std::string> warnings;
    double wall_s = 0.0;
    try {
        if (!opt.capture.empty()) {
            source = opt.capture;
            const double t0 = eyesim::frame::host_now_us();
            eyesim::frame::run_capture(opt.capture, *run, warnings, opt.max_frames);
            wall_s = (eyesim::frame::host_now_us() - t0) * 1e-6;
            end = "end of capture";
        } else {
            eyesim::frame::LiveOptions lo;
            lo.max_seconds = opt.seconds;
            lo.stall_seconds = opt.stall_s;
            lo.max_frames = opt.max_frames;
            lo.progress = eyesim::app::show_progress(opt.json);
            lo.capture_out = opt.capture_out;
            if (opt.precision) lo.patch_enable = kAllClasses;
            const eyesim::frame::LiveResult live =
                eyesim::frame::run_live(opt.usb ? std::string("usb") : opt.connect, *run, lo);
            source = live.source;
            end = live.end;
            clean = live.clean;
            wall_s = live.wall_s;
            warnings.insert(warnings.end(), live.warnings.begin(), live.warnings.end());
        }
    } catch (const eyesim::transport::UriError& e) {
        throw Error(std::string("--connect: ") + e.what(), 2);
    } catch (const eyesim::frame::SourceError& e) {
        throw Error(e.what());
    }
    const eyesim::frame::RunStats& st = run->stats();
    if (st.parser.frames == 0)  // garbage or silence is not a result
        throw Error(fmt::format("{}: no protocol frames received ({} bytes skipped; {})", source, st.parser.skipped_bytes, end));
    if (const std::string lost = eyesim::frame::loss_summary(st.loss); !lost.empty()) warnings.push_back(source + ": " + lost);
    for (const std::string& w : warnings) std::fprintf(stderr, "eyesim: warning: %s\n", w.c_str());

    nlohmann::json j;
    j["source"] = source;
    j["end"] = end;
    j["clean_end"] = clean;
    j["frames"] = st.frames;
    j["fields"] = st.fields;
    j.update(eyesim::app::latency_json(st));
    j["precision"] = eyesim::app::precision_json(st);
    if (!st.compute_us.empty()) {
        std::vector<double> compute = st.compute_us.v;  // summarise sorts
        const tr::ErrorSummary s = tr::summarise(compute);
        j["tracking_compute_us"] = {{"p50", s.p50}, {"p99", s.p99}, {"max", s.max}};
    }
    j["eye_measured_frames"] = eye_measured;
    nlohmann::json inst = nlohmann::json::object();
    for (int b = 0; b < body_set.instrument_count; ++b)
        inst[body_set.instruments[std::size_t(b)].name] = instrument_measured[std::size_t(b)];
    j["instrument_measured_frames"] = inst;
    j["clock_offset_us"] = run->clock().valid() ? run->clock().offset_us() : 0.0;
    j["clock_samples"] = run->clock().samples();
    j["errors"] = st.parser.errors();
    j["parser"] = {{"frames", st.parser.frames}, {"crc_errors", st.parser.crc_errors}, {"truncated", st.parser.truncated},
                   {"skipped_bytes", st.parser.skipped_bytes}, {"resyncs", st.parser.resyncs},
                   {"sequence_gaps", st.parser.sequence_gaps}};
    j["loss"] = eyesim::app::loss_json(st.loss);
    j["warnings"] = warnings;
    j["fields_per_s"] = double(st.fields) / std::max(wall_s, 1e-9);
    if (!opt.out.empty()) j["out"] = opt.out;
    if (!opt.capture_out.empty()) j["capture_out"] = opt.capture_out;
    if (opt.json) {
        std::printf("%s\n", j.dump().c_str());
    } else {
        const std::string lat = eyesim::app::latency_line(st);
        const std::string lost = eyesim::frame::loss_summary(st.loss);
        if (const std::string p = eyesim::app::precision_line(st); !p.empty()) std::printf("%s\n", p.c_str());
        std::printf("%s: %llu frames from %llu fields; eye measured in %ld frames; %s\n%s\nLink: %s; ended: %s\n",
                    source.c_str(), static_cast<unsigned long long>(st.frames), static_cast<unsigned long long>(st.fields),
                    eye_measured, inst.dump().c_str(), lat.empty() ? "Latency: no frames" : lat.c_str(),
                    lost.empty() ? "nothing lost" : lost.c_str(), end.c_str());
    }
    return 0;
}

eyesim::app::Registrar reg{"track", "Track instruments and eye from a device or a capture file", [](CLI::App& sub) {
    auto opt = std::make_shared<TrackOptions>();
    sub.add_option("--connect", opt->connect, "device address, tcp://HOST:PORT");
    sub.add_flag("--usb", opt->usb, "read the device over USB (libusb)");
    sub.add_option("--capture", opt->capture, "replay a capture file");
    sub.add_option("--capture-out", opt->capture_out,
                   "live: also write what the device sends to this capture file (host receive times)");
    sub.add_option("--rig", opt->rig, "rig.yaml with the cameras")->required();
    sub.add_option("--out", opt->out, "write one JSON line per tracking frame (poses.jsonl)");
    sub.add_flag("--json", opt->json, "print one JSON summary object on stdout");
    sub.add_option("--bodies", opt->bodies, "marker bodies JSON (default: scenes/bodies.json)");
    sub.add_option("--instruments", opt->instruments, "instrument kinds to fit, comma separated (default: all)");
    sub.add_option("--sync", opt->sync,
                   "camera time alignment: interpolate | extrapolate | nearest | async (per-body filters updated by "
                   "each camera field at its own time)")
        ->check(CLI::IsMember({"interpolate", "extrapolate", "nearest", "async"}));
    eyesim::app::add_report_delay_option(sub, opt->report_delay_ms, tr::AsyncOptions::kMaxReportDelayUs * 1e-3);
    sub.add_option("--seconds", opt->seconds, "live: stop after this many seconds (0: until the device closes)")
        ->check(eyesim::app::finite_in(0.0, 1e6));
    sub.add_option("--stall-s", opt->stall_s, "live: end the run when the device sends nothing for this long")
        ->check(eyesim::app::finite_in(0.1, 3600.0))
        ->capture_default_str();
    sub.add_flag("--precision", opt->precision,
                 "precision mode: the device sends every marker's pixel patch (PATCH_ENABLE, all cameras and classes) "
                 "and each marker's centroid becomes the sphere fit on it where the fit accepts");
    sub.add_flag("--no-hints", opt->no_hints,
                 "with --precision: fit every marker as a whole sphere (by default a marker's fit leaves out what the "
                 "newest poses say hides part of it: its shaft, the eye)");
    sub.add_option("--max-frames", opt->max_frames, "stop after this many tracking frames (0: no limit)")
        ->check(eyesim::app::finite_in(0.0, 1e9));
    return [opt]() -> int { return run_track(*opt); };
}};

}  // namespace
