#include "eyesim/frame/session.hpp"

#include "eyesim/firmware/capacity.hpp"
#include "eyesim/firmware/latency.hpp"
#include "eyesim/firmware/registers.hpp"
#include "eyesim/firmware/pc/pedal_track.hpp"
#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/fpga/register_map.hpp"
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
    const double end_after_start_us = double(fpga::field_end_us(0));
    for (size_t c = 0; c < cams.size(); ++c) {
        cfg.cameras.push_back(tr::camera_geometry(cams[c]));
        if (!cfg.cameras.back().valid()) throw SourceError(fmt::format("rig.yaml: camera {}: invalid intrinsics or pose", c));
        tr::CameraTiming t;
        t.end_to_sample_us = {end_after_start_us + 0.5 * cams[c].exposure_us, end_after_start_us + 0.5 * cams[c].exposure_us};
        cfg.timing.push_back(t);
    }
    return cfg;
}

void Samples::add(double x) {
    max = count == 0 ? x : std::max(max, x);
    ++count;
    if (v.size() < kMaxSamples) {
        v.push_back(x);
        return;
    }
    rng_ ^= rng_ << 13, rng_ ^= rng_ >> 7, rng_ ^= rng_ << 17;  // xorshift64
    const uint64_t k = rng_ % count;                           // keep with probability kMaxSamples / count
    if (k < kMaxSamples) v[size_t(k)] = x;
}

HostRun::HostRun(tr::TrackerConfig config, Simulator& sim) : HostRun(std::move(config)) {
    sim_ = &sim;
}

HostRun::HostRun(tr::TrackerConfig config) : adapter_(config.bodies) {
    step_once_per_time_ = config.sync.mode == tr::SyncMode::Async;
    marker_hints_ = tr::MarkerHintSource(config.cameras, config.bodies);
    try {
        tracker_ = std::make_unique<tr::Tracker>(std::move(config));
    } catch (const std::invalid_argument& e) {
        throw SourceError(e.what());
    }
}

void HostRun::set_clock_offset_us(double offset) {
    tracker_->set_clock_offset_us(offset);
    clock_fixed_ = clock_known_ = true;
}

void HostRun::enable_precision(const tr::SphereFitConfig& config, uint8_t class_mask, bool occlusion_hints) {
    precision_ = std::make_unique<PatchRefiner>(config, class_mask,
                                                [this](const proto::FieldMarkers& part) { push_markers(part); });
    if (occlusion_hints) precision_->set_hints(&marker_hints_);
    stats_.precision = true;
}

void HostRun::push_markers(const proto::FieldMarkers& part) { tracker_->push(part, push_rx_us_); }

void HostRun::set_parser_stats(const proto::ParserStats& s) {
    loss_.set_parser(s);
    stats_.parser = s;
    stats_.parse_errors = s.errors();
    stats_.loss = loss_.counts();
}

void HostRun::link_dropped() {
    if (precision_) precision_->flush();  // the parts' patches will not come now
    loss_.link_dropped();
    stats_.loss = loss_.counts();
}

void HostRun::on_pong(const proto::Reply& r, double rx_host_us) {
    if (clock_fixed_ || r.host_us == 0) return;
    // The device stamps one time (execution) for receive and send alike.
    const transport::PingSample s{int64_t(r.host_us), int64_t(r.device_us), int64_t(r.device_us), int64_t(rx_host_us)};
    if (!clock_.add(s)) return;
    tracker_->set_clock_offset_us(clock_.offset_us());
    clock_known_ = true;
    if (!have_pong_) {
        have_pong_ = true;
        pong0_dev_ = double(r.device_us);
        pong0_host_ = rx_host_us;
    }
    pong1_dev_ = double(r.device_us);
    pong1_host_ = rx_host_us;
    // The device clock's rate against the host's, first to latest pong of the segment, over at least a second: a
    // paced device that lags for a moment under load (milliseconds) stays near 1; one that plays as fast as it
    // can does not.
    if (pong1_host_ - pong0_host_ > 1e6) stats_.device_clock_rate = (pong1_dev_ - pong0_dev_) / (pong1_host_ - pong0_host_);
}

double HostRun::next_due_host_us() const { return tracker_->next_report_host_us(); }

void HostRun::on_frame(const proto::DecodedFrame& f, double rx_host_us) {
    // A replay on the modelled clock: a frame that fell due before this message went at its own time (the live
    // loop's timer: run_live).
    if (run_clock_ != RunClock::kHost)
        for (double due = tracker_->next_report_host_us(); due < rx_host_us; due = tracker_->next_report_host_us())
            drain(due);
    ++stats_.messages;
    last_rx_us_ = rx_host_us;
    push_rx_us_ = rx_host_us;
    loss_.observe(f);
    if (const auto* fm = std::get_if<proto::FieldMarkers>(&f.message)) {
        ++stats_.field_markers;
        if (!(fm->flags & proto::kFieldFlagMoreFollows)) ++stats_.fields;
        // Device time of this message: the field end, or (a low-latency part) its newest blob.
        double t_us = double(fm->field_end_us);
        for (uint8_t k = 0; t_us == 0.0 && k < fm->marker_count; ++k)
            t_us = std::max(t_us, double(fm->markers[k].complete_us));
        if (t_us > 0.0 && newest_device_us_ >= 0.0 && t_us + kTimeJumpUs < newest_device_us_) {
            // Time went back by more than kTimeJumpUs: a new segment (device restarted, captures joined). The old
            // segment's frames are built with what it had; the new one starts afresh, clock offset included.
            if (precision_) precision_->flush();
            tracker_->finish();
            drain(run_clock_ == RunClock::kHost ? host_now_us() : rx_host_us);
            tracker_->restart();
            loss_.add_time_jump();
            newest_device_us_ = -1.0;
            if (!clock_fixed_) {
                clock_ = transport::ClockOffsetEstimator{};
                clock_known_ = have_pong_ = false;
            }
        }
        if (t_us > 0.0) newest_device_us_ = std::max(newest_device_us_, t_us);
        if (precision_) {
            const double r0 = host_now_us();
            precision_->on_markers(*fm);
            refine_wall_us_ += host_now_us() - r0;
        } else {
            tracker_->push(*fm, rx_host_us);
        }
    } else if (const auto* bp = std::get_if<proto::BlobPatch>(&f.message)) {
        if (precision_) {
            const double r0 = host_now_us();
            precision_->on_patch(*bp);
            refine_wall_us_ += host_now_us() - r0;
        }
    } else if (const auto* ped = std::get_if<proto::PedalState>(&f.message)) {
        tracker_->push(*ped, rx_host_us);
    } else if (const auto* r = std::get_if<proto::Reply>(&f.message)) {
        if (r->opcode == uint8_t(proto::Opcode::Ping) && r->status == uint8_t(proto::ReplyStatus::Ack))
            on_pong(*r, rx_host_us);
    }
    stats_.loss = loss_.counts();
    if (precision_) stats_.patches = precision_->stats();
    drain(run_clock_ == RunClock::kHost ? host_now_us() : rx_host_us);
}

void HostRun::finish() {
    if (precision_) {
        precision_->flush();
        stats_.patches = precision_->stats();
    }
    tracker_->finish();
    drain(run_clock_ == RunClock::kHost ? host_now_us() : last_rx_us_);
    stats_.loss = loss_.counts();
    if (stats_.device_clock_rate != 0.0 && std::abs(stats_.device_clock_rate - 1.0) > kMaxClockRateError) {
        stats_.latency_note = fmt::format(
            "device clock ran at {:.3g}× the host clock (not at real-time pace): field-end latencies not measured",
            stats_.device_clock_rate);
        stats_.latency_us.clear();
        stats_.transfer_us.clear();
        stats_.exposure_to_pose_us.clear();
    } else if (stats_.frames > 0 && stats_.latency_us.empty()) {
        stats_.latency_note = "no ping replies: the device clock could not be placed on the host clock";
    }
}

void HostRun::drain(double now_us) {
    while (tracker_->pop(frame_, now_us)) {
        if (precision_) marker_hints_.update(frame_);
        frame_.timing.compute_us += refine_wall_us_;
        refine_wall_us_ = 0.0;
        adapter_.convert(frame_, poses_);
        if (sim_ && !(step_once_per_time_ && frame_.time_device_us == last_step_time_us_)) {
            // The tracking stage's time includes the parts fused since the last step (the rest of the previous
            // field's): the frame budget counts all tracking work, one step per field.
            poses_.tracking_us += unstepped_tracking_us_;
            unstepped_tracking_us_ = 0.0;
            sim_->step(poses_);
            last_step_time_us_ = frame_.time_device_us;
        } else if (sim_) {
            unstepped_tracking_us_ += poses_.tracking_us;
        }
        ++stats_.frames;
        const auto& t = frame_.timing;
        stats_.compute_us.add(t.compute_us);
        if (t.received_host_us > 0) stats_.ready_us.add(t.poses_ready_host_us - t.received_host_us);
        if (clock_known_ && t.sample_host_us > 0) stats_.exposure_to_pose_us.add(t.poses_ready_host_us - t.sample_host_us);
        if (clock_known_ && t.field_end_host_us > 0) {
            stats_.latency_us.add(t.poses_ready_host_us - t.field_end_host_us);
            stats_.transfer_us.add(t.received_host_us - t.field_end_host_us);
        }
        if (hook_) hook_(frame_, poses_);
    }
}

void for_each_recording_frame(rig::Recording& rec, int64_t max_fields,
                              const std::function<void(std::span<const uint8_t>, double)>& on_bytes) {
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
    firmware::LinkModel link;
    uint16_t sequence = 0;
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
            // Through the same first-in first-out link as the markers, so receive times never go back.
            const uint64_t queued_ns = uint64_t(std::llround(t_us * 1000.0)) + firmware::frame_cost_ns(len, 0);
            on_bytes(std::span<const uint8_t>(bytes.data(), len), double(link.transmit(queued_ns, len)) * 1e-3);
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
                on_bytes(std::span<const uint8_t>(bytes.data(), len), double(link.transmit(queued_ns, len)) * 1e-3);
            }
        }
    }
}

void run_recording(rig::Recording& rec, HostRun& run, int64_t max_fields) {
    proto::StreamParser parser;
    run.set_run_clock(RunClock::kRecorded);
    run.set_clock_offset_us(0.0);  // receive times are modelled on the device clock itself
    for_each_recording_frame(rec, max_fields, [&](std::span<const uint8_t> bytes, double rx_us) {
        parser.parse(bytes, [&](const proto::DecodedFrame& df) { run.on_frame(df, rx_us); });
    });
    parser.finish([&](const proto::DecodedFrame& df) { run.on_frame(df, 0.0); });
    run.set_parser_stats(parser.stats());
    run.finish();
}

void run_capture(const std::string& path, HostRun& run, std::vector<std::string>& warnings, int64_t max_frames) {
    auto reader = std::make_unique<proto::CaptureReader>();  // buffers of ~16 KiB: keep them off the stack
    if (!reader->open(path.c_str())) throw SourceError(path + ": " + reader->open_error_message());
    run.set_run_clock(RunClock::kRecorded);
    proto::StreamParser parser;
    proto::CaptureRecord rec;
    double rx_us = 0.0, last_rx_us = -1.0;
    uint64_t records = 0, rx_backwards = 0;
    bool torn = false;
    auto deliver = [&](const proto::DecodedFrame& df) { run.on_frame(df, rx_us); };
    for (;;) {
        if (max_frames > 0 && int64_t(run.stats().frames) >= max_frames) break;
        const proto::CaptureStatus st = reader->next(rec);
        if (st == proto::CaptureStatus::End) break;
        if (st == proto::CaptureStatus::IoError) throw SourceError(path + ": read error");
        if (st == proto::CaptureStatus::Torn) {  // a crash mid-write: earlier records are good
            torn = true;
            break;
        }
        if (st == proto::CaptureStatus::Corrupt) {  // skipped; the records after it are good
            warnings.push_back(fmt::format("{}: damaged stretch at byte {} ({} bytes) skipped", path, reader->bad_offset(),
                                           reader->last_skipped_bytes()));
            continue;
        }
        ++records;
        if (rec.direction == proto::CaptureDirection::Sent) continue;  // the host's own commands: not the device's stream
        if (rec.has_time) {
            rx_us = double(rec.host_rx_us);
            // Receive times going back: the records are not in the order they arrived (files joined or reordered).
            if (last_rx_us >= 0.0 && rx_us < last_rx_us && ++rx_backwards <= 3)
                warnings.push_back(fmt::format("{}: receive time goes back {:.3f} s at byte {} (record {})", path,
                                               (last_rx_us - rx_us) * 1e-6, rec.file_offset, records));
            last_rx_us = rx_us;
        }
        const uint64_t jumps = run.time_jumps();
        parser.parse(rec.bytes, deliver);
        if (run.time_jumps() > jumps)
            warnings.push_back(fmt::format("{}: device time goes back at byte {} (record {}): replayed from there as a "
                                           "new segment", path, rec.file_offset, records));
    }
    parser.finish(deliver);
    run.set_parser_stats(parser.stats());
    run.finish();
    if (rx_backwards > 3)
        warnings.push_back(fmt::format("{}: receive time goes back at {} records in all", path, rx_backwards));
    if (torn)
        warnings.push_back(fmt::format("{}: torn tail at byte {} ({} bytes) skipped; {} good records used", path,
                                       reader->bad_offset(), reader->dropped_bytes(), records));
}

namespace {

// Sends one command; with `capture`, records the sent frame in it too (a Sent record: the register reads and
// writes and their replies let a capture rebuild the device's register map).
bool send_command(transport::Transport& t, proto::Opcode op, uint32_t& id, uint16_t& seq,
                  proto::CaptureWriter* capture, uint64_t host_us = 0, uint32_t address = 0, uint32_t value = 0) {
    proto::Command c;
    c.command_id = id++;
    c.opcode = uint8_t(op);
    c.host_us = host_us;
    c.address = address;
    c.value = value;
    std::array<uint8_t, proto::kMaxFrameBytes> bytes{};
    const size_t len = proto::encode_frame(proto::Message{c}, seq++, bytes);
    const std::span<const uint8_t> frame(bytes.data(), len);
    if (len == 0 || t.write(frame, 1000).status != transport::IoStatus::ok) return false;
    if (capture) capture->write(uint64_t(host_now_us()), frame, proto::CaptureDirection::Sent);
    return true;
}

/// PATCH_ENABLE's address in the broadcast window: written to every camera (docs/protocol.md, register map).
constexpr uint32_t kPatchEnableAllCameras = 0x03C;

std::string seconds_text(double s) { return fmt::format("{:.1f} s", s); }

}  // namespace

LiveResult run_live(transport::Transport& link, HostRun& run, const LiveOptions& opt) {
    LiveResult res;
    res.source = link.describe();
    proto::StreamParser parser;
    uint16_t seq = 0;
    uint32_t id = 1;
    std::array<uint8_t, proto::kMaxCaptureRecordBytes> buf{};  // one read is one capture record
    proto::CaptureWriter capture;
    bool capturing = !opt.capture_out.empty();
    if (capturing && !capture.create(opt.capture_out.c_str()))
        throw SourceError(opt.capture_out + ": cannot create capture file");
    const double t0 = host_now_us();
    double rx_us = t0;
    auto deliver = [&](const proto::DecodedFrame& df) { run.on_frame(df, rx_us); };
    auto end = [&](std::string why, bool clean) {
        res.end = std::move(why);
        res.clean = clean;
    };
    auto sent_to_capture = [&]() -> proto::CaptureWriter* { return capturing ? &capture : nullptr; };
    // Precision mode: PATCH_ENABLE (0x03C: every camera's window) before each stream_start, since a device
    // that comes back after an unplug starts from its reset values. A capture also gets the device's whole
    // pipeline register map (a read of every register of every camera), so `eyesim compare` can re-run the model
    // with it.
    auto start_stream = [&] {
        if (opt.patch_enable != 0 && !send_command(link, proto::Opcode::RegisterWrite, id, seq, sent_to_capture(), 0,
                                                   kPatchEnableAllCameras, opt.patch_enable))
            return false;
        if (sent_to_capture())
            for (uint32_t cam = 0; cam < firmware::kCameras; ++cam)
                for (const fpga::RegisterInfo& r : fpga::register_table())
                    if (!send_command(link, proto::Opcode::RegisterRead, id, seq, sent_to_capture(), 0,
                                      (cam + 1) * firmware::kRegCameraBase + r.address))
                        return false;
        return send_command(link, proto::Opcode::StreamStart, id, seq, sent_to_capture());
    };
    bool streaming = start_stream();
    if (!streaming && !link.reconnects()) {
        end("cannot send stream_start: " + (link.last_error().empty() ? std::string("link closed") : link.last_error()), false);
    }
    double last_ping = 0.0, last_rx = t0, lost_at = 0.0;
    bool away = false;
    int64_t last_progress = -1;
    while (res.end.empty()) {
        const double now = host_now_us();
        if (opt.max_seconds > 0 && now - t0 > opt.max_seconds * 1e6) {
            end("time limit (" + seconds_text(opt.max_seconds) + ")", true);
            break;
        }
        if (opt.max_frames > 0 && int64_t(run.stats().frames) >= opt.max_frames) {
            end(fmt::format("frame limit ({} frames)", opt.max_frames), true);
            break;
        }
        if (now - last_rx > opt.stall_seconds * 1e6) {  // a live device answers pings even between fields
            end(away ? "device lost and not back within " + seconds_text(opt.stall_seconds)
                     : "no bytes for " + seconds_text(opt.stall_seconds) + ": device stalled",
                false);
            break;
        }
        if (!away && link.connected()) {
            if (!streaming) streaming = start_stream();
            // Pings for the clock offset: every 50 ms for the first half second, then every 200 ms.
            if (now - last_ping > (now - t0 < 500000.0 ? 50000.0 : 200000.0)) {
                send_command(link, proto::Opcode::Ping, id, seq, sent_to_capture(), uint64_t(now));
                last_ping = now;
            }
        }
        // Wake for a fixed-lag frame that falls due before the next bytes (Tracker::next_report_host_us).
        const double due_ms = (run.next_due_host_us() - host_now_us()) * 1e-3;
        const transport::IoResult r = link.read(buf, due_ms < 50.0 ? std::max(1, int(std::ceil(due_ms))) : 50);
        run.poll(host_now_us());
        if (r.bytes) {
            rx_us = last_rx = host_now_us();
            if (away) {  // back after an unplug: the device starts afresh and needs stream_start again
                away = false;
                res.warnings.push_back(fmt::format("{}: device back after {:.2f} s; stream restarted", res.source,
                                                   (rx_us - lost_at) * 1e-6));
            }
            if (capturing && !capture.write(uint64_t(rx_us), std::span<const uint8_t>(buf.data(), r.bytes))) {
                capturing = false;
                res.warnings.push_back(opt.capture_out + ": write failed; the capture ends there");
            }
            parser.parse(std::span<const uint8_t>(buf.data(), r.bytes), deliver);
        }
        if (r.status == transport::IoStatus::closed) {
            const std::string why = link.last_error();
            end(why.empty() ? "device closed the link" : why, why.empty());
        } else if (r.status == transport::IoStatus::error) {
            if (!link.reconnects()) {
                end(link.last_error().empty() ? "link failed" : link.last_error(), false);
            } else if (!away) {
                // Unplugged: what was received is delivered; the transport reconnects on the next reads.
                away = true;
                lost_at = host_now_us();
                last_rx = lost_at;
                streaming = false;
                res.warnings.push_back(res.source + ": " + link.last_error());
                rx_us = lost_at;
                parser.finish(deliver);
                run.link_dropped();
            }
        } else if (away && link.connected() && !streaming) {
            streaming = start_stream();
        }
        if (opt.progress && int64_t(run.stats().frames) / 50 != last_progress) {
            last_progress = int64_t(run.stats().frames) / 50;
            std::fprintf(stderr, "\r%s: %llu frames", res.source.c_str(), static_cast<unsigned long long>(run.stats().frames));
        }
    }
    if (opt.progress) std::fprintf(stderr, "\n");
    if (link.connected()) send_command(link, proto::Opcode::StreamStop, id, seq, sent_to_capture());
    rx_us = host_now_us();
    parser.finish(deliver);
    run.set_parser_stats(parser.stats());
    run.finish();
    link.close();
    res.wall_s = (host_now_us() - t0) * 1e-6;
    if (!res.clean) res.warnings.push_back(res.source + ": " + res.end + "; the run ended there, with every frame received");
    return res;
}

LiveResult run_live(const std::string& uri, HostRun& run, const LiveOptions& opt) {
    std::unique_ptr<transport::Transport> link;
    try {
        link = transport::open_transport(uri, 3000);
    } catch (const transport::UriError&) {
        throw;  // a usage error: the caller maps it
    } catch (const transport::TransportError& e) {
        throw SourceError(e.what());
    }
    return run_live(*link, run, opt);
}

}  // namespace eyesim::frame
