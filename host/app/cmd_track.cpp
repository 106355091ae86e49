// `eyesim track`: FieldMarkers from a device (TCP or USB) or a capture file → tracking frames → poses.jsonl.
#include "eyesim/app/command.hpp"
#include "eyesim/app/frame_loop.hpp"

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
    std::string rig;
    std::string out;
    bool json = false;
    std::string bodies;
    std::string instruments;
    std::string sync = "interpolate";
    double seconds = 0.0;
    double stall_s = eyesim::app::kDefaultStallSeconds;
    long max_frames = 0;
};

double host_now_us() {
    return std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

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

/// Tracker + parser + output shared by the live and the capture paths.
class Session {
public:
    Session(const TrackOptions& opt, tr::TrackerConfig cfg) : tracker_(std::move(cfg)), bodies_(tracker_.config().bodies) {
        if (!opt.out.empty()) {
            out_.open(opt.out);
            if (!out_) throw Error(opt.out + ": cannot write");
        }
    }

    /// Parses received bytes; `host_us` is their receive time.
    void bytes(std::span<const std::uint8_t> data, double host_us) {
        parser_.parse(data, [&](const proto::DecodedFrame& f) { message(f.message, host_us); });
    }

    void finish(double host_us) {
        parser_.finish([&](const proto::DecodedFrame& f) { message(f.message, host_us); });
        tracker_.finish();
        drain(host_us);
    }

    eyesim::transport::ClockOffsetEstimator& clock() { return clock_; }
    long frames() const { return frames_; }
    long fields() const { return fields_; }
    bool done(long max_frames) const { return max_frames > 0 && frames_ >= max_frames; }

    nlohmann::json summary() {
        nlohmann::json j;
        j["frames"] = frames_;
        j["fields"] = fields_;
        j["latency_us"] = {{"p50", 0.0}, {"p99", 0.0}, {"max", 0.0}};
        if (!latency_.empty()) {
            const tr::ErrorSummary s = tr::summarise(latency_);
            j["latency_us"] = {{"p50", s.p50}, {"p99", s.p99}, {"max", s.max}};
        }
        if (!compute_.empty()) {
            const tr::ErrorSummary s = tr::summarise(compute_);
            j["tracking_compute_us"] = {{"p50", s.p50}, {"p99", s.p99}, {"max", s.max}};
        }
        j["eye_measured_frames"] = eye_measured_;
        nlohmann::json inst = nlohmann::json::object();
        for (int b = 0; b < bodies_.instrument_count; ++b)
            inst[bodies_.instruments[std::size_t(b)].name] = instrument_measured_[std::size_t(b)];
        j["instrument_measured_frames"] = inst;
        j["clock_offset_us"] = clock_.valid() ? clock_.offset_us() : 0.0;
        j["clock_samples"] = clock_.samples();
        j["errors"] = parser_.stats().errors();
        j["parser"] = {{"frames", parser_.stats().frames}, {"crc_errors", parser_.stats().crc_errors},
                       {"truncated", parser_.stats().truncated}, {"skipped_bytes", parser_.stats().skipped_bytes}};
        return j;
    }

private:
    void message(const proto::Message& m, double host_us) {
        if (const auto* fm = std::get_if<proto::FieldMarkers>(&m)) {
            if (!(fm->flags & proto::kFieldFlagMoreFollows)) ++fields_;
            tracker_.push(*fm, host_us);
            drain(host_us);
        } else if (const auto* ps = std::get_if<proto::PedalState>(&m)) {
            tracker_.push(*ps, host_us);
        } else if (const auto* rp = std::get_if<proto::Reply>(&m)) {
            if (rp->opcode == std::uint8_t(proto::Opcode::Ping) && rp->host_us != 0) {
                eyesim::transport::PingSample s;
                s.host_send_us = std::int64_t(rp->host_us);
                s.device_rx_us = s.device_tx_us = std::int64_t(rp->device_us);
                s.host_recv_us = std::int64_t(host_us);
                if (clock_.add(s)) tracker_.set_clock_offset_us(clock_.offset_us());
            }
        }
    }

    void drain(double host_us) {
        while (tracker_.pop(frame_, host_us)) {
            ++frames_;
            latency_.push_back(frame_.timing.poses_ready_host_us - frame_.timing.field_end_host_us);
            compute_.push_back(frame_.timing.compute_us);
            if (frame_.eye.measured()) ++eye_measured_;
            for (int b = 0; b < frame_.instrument_count; ++b)
                if (frame_.instruments[std::size_t(b)].measured()) ++instrument_measured_[std::size_t(b)];
            if (out_.is_open()) out_ << tr::frame_json_line(frame_, bodies_) << '\n';
        }
    }

    tr::Tracker tracker_;
    tr::BodySet bodies_;
    proto::StreamParser parser_;
    eyesim::transport::ClockOffsetEstimator clock_;
    tr::TrackingFrame frame_;
    std::ofstream out_;
    long frames_ = 0, fields_ = 0, eye_measured_ = 0;
    std::array<long, tr::kMaxInstruments> instrument_measured_{};
    std::vector<double> latency_, compute_;
};

std::size_t send_command(eyesim::transport::Transport& t, proto::Opcode op, std::uint32_t id, std::uint64_t host_us) {
    proto::Command c;
    c.command_id = id;
    c.opcode = std::uint8_t(op);
    c.host_us = host_us;
    std::array<std::uint8_t, proto::kMaxFrameBytes> buf{};
    const std::size_t n = proto::encode_frame(c, std::uint16_t(id), buf);
    if (n == 0) return 0;
    return t.write(std::span<const std::uint8_t>(buf.data(), n), 200).bytes;
}

int run_track(const TrackOptions& opt) {
    const int sources = int(!opt.connect.empty()) + int(opt.usb) + int(!opt.capture.empty());
    if (sources != 1) throw Error("track: give exactly one of --connect tcp://HOST:PORT, --usb, --capture FILE", 2);
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
    cfg.sync.mode = opt.sync == "extrapolate" ? tr::SyncMode::Extrapolate
                    : opt.sync == "nearest"   ? tr::SyncMode::Nearest
                                              : tr::SyncMode::Interpolate;
    std::unique_ptr<Session> session;
    try {
        session = std::make_unique<Session>(opt, cfg);
    } catch (const std::invalid_argument& e) {
        throw Error(opt.rig + ": " + e.what());
    }
    const bool progress = eyesim::app::show_progress(opt.json);
    const double t0 = host_now_us();
    std::string source;
    bool torn = false;
    std::string stall;  // why a live run ended early

    if (!opt.capture.empty()) {
        source = opt.capture;
        proto::CaptureReader reader;
        if (!reader.open(opt.capture.c_str())) throw Error(opt.capture + ": " + reader.open_error_message());
        proto::CaptureRecord rec;
        double last_us = 0;
        for (;;) {
            const proto::CaptureStatus st = reader.next(rec);
            if (st == proto::CaptureStatus::Torn) {  // a crash mid-write: earlier records are good
                torn = true;
                std::fprintf(stderr, "eyesim: warning: %s: torn tail at byte %llu (%llu bytes) skipped\n",
                             opt.capture.c_str(), static_cast<unsigned long long>(reader.bad_offset()),
                             static_cast<unsigned long long>(reader.dropped_bytes()));
                break;
            }
            if (st == proto::CaptureStatus::End) break;
            if (st == proto::CaptureStatus::Corrupt) {  // skipped; the records after it are good
                std::fprintf(stderr, "eyesim: warning: %s: damaged stretch at byte %llu (%llu bytes) skipped\n",
                             opt.capture.c_str(), static_cast<unsigned long long>(reader.bad_offset()),
                             static_cast<unsigned long long>(reader.last_skipped_bytes()));
                continue;
            }
            if (st == proto::CaptureStatus::IoError) throw Error(opt.capture + ": read error");
            last_us = rec.has_time ? double(rec.host_rx_us) : last_us;
            session->bytes(rec.bytes, last_us);
            if (session->done(opt.max_frames)) break;
        }
        session->finish(last_us);
    } else {
        std::unique_ptr<eyesim::transport::Transport> link;
        try {
            link = eyesim::transport::open_transport(opt.usb ? std::string("usb") : opt.connect);
        } catch (const eyesim::transport::UriError& e) {
            throw Error(std::string("--connect: ") + e.what(), 2);
        } catch (const eyesim::transport::TransportError& e) {
            throw Error(e.what());
        }
        source = link->describe();
        std::uint32_t id = 1;
        if (send_command(*link, proto::Opcode::StreamStart, id++, 0) == 0)
            throw Error(source + ": cannot send StreamStart: " + link->last_error());
        std::array<std::uint8_t, 8192> buf{};
        double next_ping = 0;
        double last_rx = host_now_us();
        for (;;) {
            const double now = host_now_us();
            if (opt.seconds > 0 && now - t0 > opt.seconds * 1e6) break;
            if (now - last_rx > opt.stall_s * 1e6) {  // a live device answers the pings even between fields
                stall = fmt::format("no bytes for {:.1f} s: device stalled", opt.stall_s);
                std::fprintf(stderr, "eyesim: warning: %s: %s, run ended\n", source.c_str(), stall.c_str());
                break;
            }
            if (session->done(opt.max_frames)) break;
            if (now >= next_ping) {  // ping/pong for the clock offset, 5 per second
                send_command(*link, proto::Opcode::Ping, id++, std::uint64_t(now));
                next_ping = now + 200000.0;
            }
            const auto r = link->read(buf, 50);
            if (r.bytes) {
                last_rx = host_now_us();
                session->bytes(std::span<const std::uint8_t>(buf.data(), r.bytes), last_rx);
            }
            if (r.status == eyesim::transport::IoStatus::closed) break;
            if (r.status == eyesim::transport::IoStatus::error)
                throw Error(source + ": " + link->last_error());
            if (progress && session->frames() % 50 == 0 && r.bytes)
                std::fprintf(stderr, "\rtrack: %ld frames", session->frames());
        }
        send_command(*link, proto::Opcode::StreamStop, id++, 0);
        session->finish(host_now_us());
        link->close();
    }
    if (progress) std::fprintf(stderr, "\n");
    const double wall_s = (host_now_us() - t0) * 1e-6;
    nlohmann::json j = session->summary();
    if (j["parser"]["frames"].get<std::uint64_t>() == 0)  // garbage or silence is not a result
        throw Error(fmt::format("{}: no protocol frames received ({} bytes skipped{})", source,
                                j["parser"]["skipped_bytes"].get<std::uint64_t>(), stall.empty() ? "" : "; " + stall));
    if (!stall.empty()) j["stalled"] = stall;
    j["source"] = source;
    if (!opt.capture.empty()) j["capture_torn"] = torn;
    j["fields_per_s"] = double(session->fields()) / std::max(wall_s, 1e-9);
    if (!opt.out.empty()) j["out"] = opt.out;
    if (opt.json) {
        std::printf("%s\n", j.dump().c_str());
    } else {
        std::printf("%s: %ld frames from %ld fields; latency field end -> poses p50 %.0f us, p99 %.0f us; eye measured "
                    "in %ld frames; %s\n",
                    source.c_str(), session->frames(), session->fields(), j["latency_us"]["p50"].get<double>(),
                    j["latency_us"]["p99"].get<double>(), j["eye_measured_frames"].get<long>(),
                    j["instrument_measured_frames"].dump().c_str());
    }
    return 0;
}

eyesim::app::Registrar reg{"track", "Track instruments and eye from a device or a capture file", [](CLI::App& sub) {
    auto opt = std::make_shared<TrackOptions>();
    sub.add_option("--connect", opt->connect, "device address, tcp://HOST:PORT");
    sub.add_flag("--usb", opt->usb, "read the device over USB (libusb)");
    sub.add_option("--capture", opt->capture, "replay a capture file");
    sub.add_option("--rig", opt->rig, "rig.yaml with the cameras")->required();
    sub.add_option("--out", opt->out, "write one JSON line per tracking frame (poses.jsonl)");
    sub.add_flag("--json", opt->json, "print one JSON summary object on stdout");
    sub.add_option("--bodies", opt->bodies, "marker bodies JSON (default: scenes/bodies.json)");
    sub.add_option("--instruments", opt->instruments, "instrument kinds to fit, comma separated (default: all)");
    sub.add_option("--sync", opt->sync, "camera time alignment: interpolate | extrapolate | nearest")
        ->check(CLI::IsMember({"interpolate", "extrapolate", "nearest"}));
    sub.add_option("--seconds", opt->seconds, "live: stop after this many seconds (0: until the device closes)")
        ->check(eyesim::app::finite_in(0.0, 1e6));
    sub.add_option("--stall-s", opt->stall_s, "live: end the run when the device sends nothing for this long")
        ->check(eyesim::app::finite_in(0.1, 3600.0))
        ->capture_default_str();
    sub.add_option("--max-frames", opt->max_frames, "stop after this many tracking frames (0: no limit)")
        ->check(eyesim::app::finite_in(0.0, 1e9));
    return [opt]() -> int { return run_track(*opt); };
}};

}  // namespace
