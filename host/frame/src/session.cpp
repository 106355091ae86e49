#include "eyesim/frame/session.hpp"

#include "eyesim/firmware/latency.hpp"
#include "eyesim/firmware/pc/pedal_track.hpp"
#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/fpga/timing.hpp"
#include "eyesim/fpga/wire.hpp"
#include "eyesim/protocol/capture_replay.hpp"
#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/stream_parser.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/pal.hpp"
#include "eyesim/rig/truth.hpp"
#include "eyesim/transport/transport.hpp"

#include <fmt/format.h>

#include <array>
#include <chrono>
#include <cmath>

namespace eyesim::frame {

namespace proto = eyesim::protocol;
namespace tr = eyesim::tracking;

double host_now_us() {
    using namespace std::chrono;
    return double(duration_cast<nanoseconds>(steady_clock::now().time_since_epoch()).count()) * 1e-3;
}

tr::TrackerConfig tracker_config(const std::vector<rig::CameraModel>& cams, const rig::Bodies& bodies,
                                 const std::vector<tr::SceneInstrument>& instruments) {
    tr::TrackerConfig cfg;
    try {
        cfg.bodies = tr::body_set(bodies, instruments);
    } catch (const std::invalid_argument& e) {
        throw SourceError(e.what());
    }
    if (cams.size() < 2 || cams.size() > size_t(tr::kMaxCameras))
        throw SourceError(fmt::format("rig.yaml: camera_count: {} (need 2..{})", cams.size(), tr::kMaxCameras));
    // Device field end = field start (vertical sync, end of exposure) + the FPGA's end of active video; the
    // frame instant is the exposure mid-time, half a shutter before the start.
    const double end_after_start_us =
        double(fpga::device_time_us(0, fpga::active_line_end_cycle(fpga::kActiveLinesPerField - 1)));
    for (size_t c = 0; c < cams.size(); ++c) {
        cfg.cameras.push_back(tr::camera_geometry(cams[c]));
        if (!cfg.cameras.back().valid()) throw SourceError(fmt::format("rig.yaml: camera {}: invalid intrinsics or pose", c));
        tr::CameraTiming t;
        t.end_to_sample_us = {end_after_start_us + 0.5 * cams[c].exposure_us, end_after_start_us + 0.5 * cams[c].exposure_us};
        cfg.timing.push_back(t);
    }
    return cfg;
}

HostRun::HostRun(tr::TrackerConfig config, Simulator& sim)
    : sim_(sim), adapter_(config.bodies) {
    try {
        tracker_ = std::make_unique<tr::Tracker>(std::move(config));
    } catch (const std::invalid_argument& e) {
        throw SourceError(e.what());
    }
    stats_.latency_us.reserve(1 << 16);
    stats_.transfer_us.reserve(1 << 16);
}

void HostRun::on_frame(const proto::DecodedFrame& f, double rx_host_us) {
    ++stats_.messages;
    if (const auto* fm = std::get_if<proto::FieldMarkers>(&f.message)) {
        ++stats_.field_markers;
        tracker_->push(*fm, rx_host_us);
    } else if (const auto* ped = std::get_if<proto::PedalState>(&f.message)) {
        tracker_->push(*ped, rx_host_us);
    } else if (const auto* st = std::get_if<proto::DeviceStatus>(&f.message)) {
        stats_.device_queue_drops = st->queue_overflows;
    }
    drain();
}

void HostRun::finish() {
    tracker_->finish();
    drain();
}

void HostRun::drain() {
    while (tracker_->pop(frame_, host_now_us())) {
        adapter_.convert(frame_, poses_);
        sim_.step(poses_);
        ++stats_.frames;
        const auto& t = frame_.timing;
        if (clock_known_ && t.field_end_host_us > 0) {
            stats_.latency_us.push_back(t.poses_ready_host_us - t.field_end_host_us);
            stats_.transfer_us.push_back(t.received_host_us - t.field_end_host_us);
        }
        if (hook_) hook_(frame_, poses_);
    }
}

void run_recording(rig::Recording& rec, HostRun& run, int64_t max_fields) {
    const int ncam = rec.camera_count();
    int64_t n = rec.common_field_count();
    if (max_fields > 0) n = std::min(n, max_fields);
    std::vector<std::unique_ptr<fpga::RegisterMap>> regs;
    std::vector<std::unique_ptr<fpga::Pipeline>> pipes;
    for (int c = 0; c < ncam; ++c) {
        regs.push_back(std::make_unique<fpga::RegisterMap>());
        pipes.push_back(std::make_unique<fpga::Pipeline>(*regs.back()));
    }
    std::vector<uint8_t> field(size_t(rig::kFieldBytes));
    std::vector<fpga::Blob> blobs;
    blobs.reserve(256);
    std::vector<proto::FieldMarkers> msgs(64);
    std::array<uint8_t, proto::kMaxFrameBytes> bytes{};
    proto::StreamParser parser;
    firmware::LinkModel link;
    uint16_t sequence = 0;
    run.set_clock_offset_us(0.0);  // receive times are modelled on the device clock itself
    // The pedal, as eyesim-device sends it: the recording's truth.jsonl (a recording without one: pedal at rest).
    std::vector<firmware::pc::PedalSample> pedal_track;
    if (const std::string tp = rec.truth_path(); !tp.empty()) {
        try {
            pedal_track = firmware::pc::pedal_track_of(rig::read_truth(tp));
        } catch (const rig::RigError& e) {
            throw SourceError(e.what());
        }
    }
    const firmware::pc::PedalTrack pedal(std::move(pedal_track), nullptr);
    for (int64_t i = 0; i < n; ++i) {
        {
            // One PedalState per field period, stamped at camera 0's field start (before that field's markers).
            const double t_us = std::max(0.0, rec.field_timing(0, i).start_us);
            const proto::PedalState ps = pedal.message_at(t_us, uint64_t(std::llround(t_us)));
            const size_t len = proto::encode_frame(proto::Message{ps}, sequence++, bytes);
            parser.parse(std::span<const uint8_t>(bytes.data(), len),
                         [&](const proto::DecodedFrame& df) { run.on_frame(df, t_us); });
        }
        for (int c = 0; c < ncam; ++c) {
            const rig::FieldTiming ft = rec.field_timing(c, i);
            try {
                rec.read_field(c, i, field.data());
            } catch (const rig::RigError& e) {
                throw SourceError(e.what());
            }
            fpga::Pipeline& pipe = *pipes[size_t(c)];
            pipe.process_field(field.data(), rig::kFieldHeight, uint32_t(i), uint8_t(ft.parity));
            blobs.clear();
            fpga::Blob b;
            while (pipe.pop_blob(b)) blobs.push_back(b);
            const uint64_t start_us = uint64_t(std::llround(std::max(0.0, ft.start_us)));
            const fpga::FieldInfo info = fpga::field_info(pipe.field_stats(), uint8_t(c), uint8_t(ft.parity), start_us);
            const size_t nm = fpga::to_field_markers(blobs.data(), blobs.size(), info, msgs.data(), msgs.size());
            for (size_t k = 0; k < nm; ++k) {
                const size_t len = proto::encode_frame(msgs[k], sequence++, bytes);
                // Modelled device: parts queued at the field end, then the link; the host clock equals the device
                // clock here (offset 0).
                const uint64_t queued_ns = msgs[k].field_end_us * 1000ull + firmware::frame_cost_ns(len, msgs[k].marker_count);
                const double rx_us = double(link.transmit(queued_ns, len)) * 1e-3;
                parser.parse(std::span<const uint8_t>(bytes.data(), len),
                             [&](const proto::DecodedFrame& df) { run.on_frame(df, rx_us); });
            }
        }
    }
    run.set_parse_errors(parser.stats().errors());
    run.finish();
}

void run_capture(const std::string& path, HostRun& run, std::string& warning) {
    auto replay = std::make_unique<proto::CaptureReplay>();  // ~18 KiB: keep it off the stack
    if (!replay->open(path.c_str())) throw SourceError(path + ": " + replay->reader().open_error_message());
    proto::DecodedFrame f;
    uint64_t rx_us = 0;
    while (replay->next(f, rx_us)) run.on_frame(f, double(rx_us));
    run.set_parse_errors(replay->stats().errors());
    run.finish();
    if (replay->status() == proto::CaptureStatus::IoError) throw SourceError(path + ": read error");
    const proto::CaptureReader& reader = replay->reader();
    std::string what;
    if (reader.corrupt_regions() > 0)
        what = fmt::format("{} damaged stretch(es), {} bytes, skipped", reader.corrupt_regions(), reader.corrupt_bytes());
    if (replay->status() == proto::CaptureStatus::Torn)
        what += fmt::format("{}torn tail at byte {} ({} bytes) skipped", what.empty() ? "" : "; ", reader.bad_offset(),
                            reader.dropped_bytes());
    if (!what.empty()) warning = fmt::format("{}: {}; {} good records used", path, what, replay->records());
}

namespace {
bool send_command(transport::Transport& t, const proto::Command& cmd, uint16_t& seq) {
    std::array<uint8_t, proto::kMaxFrameBytes> bytes{};
    const size_t len = proto::encode_frame(proto::Message{cmd}, seq++, bytes);
    return len > 0 && t.write(std::span<const uint8_t>(bytes.data(), len), 1000).status == transport::IoStatus::ok;
}
}  // namespace

double run_live(const std::string& uri, HostRun& run, double max_seconds, std::string& warning, double stall_seconds) {
    std::unique_ptr<transport::Transport> link;
    try {
        link = transport::open_transport(uri, 3000);
    } catch (const transport::TransportError& e) {
        throw SourceError(e.what());
    }
    proto::StreamParser parser;
    transport::ClockOffsetEstimator clock;
    uint16_t seq = 0;
    uint32_t id = 1;
    std::array<uint8_t, 16384> buf{};
    auto ping = [&] {
        proto::Command c;
        c.command_id = id++;
        c.opcode = uint8_t(proto::Opcode::Ping);
        c.host_us = uint64_t(host_now_us());
        send_command(*link, c, seq);
    };
    auto handle = [&](const proto::DecodedFrame& df, double now) {
        if (const auto* r = std::get_if<proto::Reply>(&df.message)) {
            if (r->opcode == uint8_t(proto::Opcode::Ping) && r->status == uint8_t(proto::ReplyStatus::Ack)) {
                transport::PingSample s{int64_t(r->host_us), int64_t(r->device_us), int64_t(r->device_us), int64_t(now)};
                if (clock.add(s)) run.set_clock_offset_us(clock.offset_us());
            }
            return;
        }
        run.on_frame(df, now);
    };
    // The device clock is modelled and runs with the played fields, so the offset is estimated once the stream
    // runs: pings every 50 ms for the first half second, then every 500 ms (the minimum-delay sample wins).
    proto::Command start;
    start.command_id = id++;
    start.opcode = uint8_t(proto::Opcode::StreamStart);
    if (!send_command(*link, start, seq)) throw SourceError(uri + ": cannot send stream_start: " + link->last_error());
    const double t0 = host_now_us();
    double last_ping = 0.0;
    double last_rx = t0;
    while (true) {
        const double now0 = host_now_us();
        if (max_seconds > 0 && now0 - t0 > max_seconds * 1e6) break;
        if (now0 - last_rx > stall_seconds * 1e6) {  // a live device answers pings even between fields
            warning = fmt::format("{}: no bytes for {:.1f} s: device stalled, run ended", uri, stall_seconds);
            break;
        }
        if (now0 - last_ping > (now0 - t0 < 500000.0 ? 50000.0 : 500000.0)) {
            ping();
            last_ping = now0;
        }
        const auto r = link->read(buf, 100);
        if (r.bytes) {
            const double now = host_now_us();
            last_rx = now;
            parser.parse(std::span<const uint8_t>(buf.data(), r.bytes), [&](const proto::DecodedFrame& df) { handle(df, now); });
        }
        if (r.status == transport::IoStatus::closed) break;
        if (r.status == transport::IoStatus::error) throw SourceError(uri + ": " + link->last_error());
    }
    parser.finish([&](const proto::DecodedFrame& df) { handle(df, host_now_us()); });
    run.set_parse_errors(parser.stats().errors());
    run.finish();
    link->close();
    return clock.offset_us();
}

}  // namespace eyesim::frame
