// Firmware core: camera lines → pipelines → blobs → frames → bounded queue → sink; commands → replies.
#include "eyesim/firmware/device_core.hpp"

#include "eyesim/firmware/registers.hpp"

#include "eyesim/fpga/timing.hpp"
#include "eyesim/fpga/wire.hpp"
#include "eyesim/protocol/codec.hpp"

namespace eyesim::firmware {

using protocol::Command;
using protocol::NackReason;
using protocol::Opcode;
using protocol::Reply;
using protocol::ReplyStatus;

namespace {

/// send_patches: no limit on the blob index.
constexpr std::size_t kAllPatches = ~std::size_t{0};

/// Frame bytes besides the payload: header and CRC.
constexpr std::size_t kFrameOverheadBytes = protocol::kFrameHeaderBytes + protocol::kFrameCrcBytes;

/// Device time (ns) of a pipeline cycle of the field that started at `field_start_us`.
std::uint64_t cycle_time_ns(std::uint64_t field_start_us, std::uint32_t cycle) noexcept {
    return field_start_us * 1000u + fpga::cycles_to_ns(cycle);
}

Reply nack(Reply r, NackReason why) noexcept {
    r.status = static_cast<std::uint8_t>(ReplyStatus::Nack);
    r.reason = static_cast<std::uint8_t>(why);
    return r;
}

NackReason reason_of(fpga::RegWriteResult w) noexcept {
    switch (w) {
        case fpga::RegWriteResult::kOk: return NackReason::None;
        case fpga::RegWriteResult::kUnknownAddress:
        case fpga::RegWriteResult::kMisaligned: return NackReason::BadAddress;
        case fpga::RegWriteResult::kBadWidth: return NackReason::Malformed;
        case fpga::RegWriteResult::kReadOnly: return NackReason::ReadOnly;
        case fpga::RegWriteResult::kTooWide:
        case fpga::RegWriteResult::kOutOfRange: return NackReason::BadRange;
    }
    return NackReason::Malformed;
}

}  // namespace

DeviceCore::DeviceCore(const DeviceHal& hal, const CoreConfig& config) noexcept
    : hal_(hal),
      config_(config),
      streaming_(config.stream_on_start),
      low_latency_(config.low_latency),
      status_period_ms_(config.status_period_ms),
      pedal_period_ms_(config.pedal_period_ms) {
    for (std::size_t c = 0; c < kCameras; ++c) {
        cams_[c].pipeline.set_sink(&DeviceCore::blob_sink, this);
        cams_[c].capture.set_sink(&DeviceCore::patch_sink, this);
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Pixel side: never waits for the host. Everything below runs in bounded time per line.
// ---------------------------------------------------------------------------------------------------------------

StepStatus DeviceCore::step_cameras() noexcept {
    bool any = false;
    std::size_t finished = 0;
    for (std::size_t c = 0; c < kCameras; ++c)
        if (cams_[c].finished || hal_.cameras[c] == nullptr) ++finished;
    for (std::size_t step = 0; step < kCameras && finished < kCameras; ++step) {
        // Fill every camera's slot, then run the earliest item (a field end or end of stream right after its
        // camera's last line).
        std::size_t pick = kCameras;
        for (std::size_t c = 0; c < kCameras; ++c) {
            Camera& cam = cams_[c];
            if (cam.finished || hal_.cameras[c] == nullptr) continue;
            HeldItem& h = held_[c];
            if (!h.valid) {
                h.status = hal_.cameras[c]->next_line(h.line);
                if (h.status == LineStatus::idle) continue;
                h.valid = true;
                h.t_ns = h.status == LineStatus::line
                             ? cycle_time_ns(h.line.field_start_us, fpga::active_line_end_cycle(h.line.line))
                             : last_line_ns_[c] + 1;
            }
            if (pick == kCameras || h.t_ns < held_[pick].t_ns) pick = c;
        }
        if (pick == kCameras) break;  // every camera idle
        const HeldItem item = held_[pick];
        held_[pick].valid = false;
        if (item.status == LineStatus::line) {
            last_line_ns_[pick] = item.t_ns;
            if (hal_.clock != nullptr) hal_.clock->line_run_us(item.t_ns / 1000u);
        }
        run_item(pick, item, finished);
        any = true;
    }
    flush_low_latency();
    if (finished == kCameras) return StepStatus::finished;
    return any ? StepStatus::active : StepStatus::idle;
}

void DeviceCore::run_item(std::size_t c, const HeldItem& item, std::size_t& finished) noexcept {
    Camera& cam = cams_[c];
    const CameraLine& line = item.line;
    switch (item.status) {
        case LineStatus::line:
            if (!cam.in_field || line.field != cam.field) {
                if (cam.in_field) end_field(c);  // the source skipped the field end: close it anyway
                begin_field(c, line);
            }
            if (line.width_px == fpga::kActivePixelsPerLine && line.uyvy != nullptr) {
                sink_camera_ = c;
                // The patch buffers take the line first: a blob the pipeline completes on it finds it there.
                cam.capture.push_line(line.uyvy, line.line);
                cam.pipeline.push_line(line.uyvy, line.line);
            }
            break;
        case LineStatus::field_end:
            if (cam.in_field) end_field(c);
            break;
        case LineStatus::idle: break;
        case LineStatus::end_of_stream:
            if (cam.in_field) end_field(c);
            cam.finished = true;
            ++finished;
            break;
    }
}

void DeviceCore::begin_field(std::size_t camera, const CameraLine& line) noexcept {
    Camera& cam = cams_[camera];
    cam.in_field = true;
    cam.field = line.field;
    cam.parity = line.parity;
    cam.field_start_us = line.field_start_us;
    cam.part_index = 0;
    cam.blobs_dropped = false;
    cam.low_latency = low_latency_;
    cam.closed = false;
    cam.abandoned = false;
    cam.sent = 0;
    cam.blobs.clear();
    cam.pending.clear();
    cam.pipeline.begin_field(line.field, line.parity);
    cam.capture.begin_field(cam.pipeline.params(), line.field, line.parity);
    cam.patches.clear();
    cam.patches_next = 0;
    cam.patch_pool_used = 0;
    cam.patch_wire_bytes = 0;
}

void DeviceCore::blob_sink(void* context, const fpga::Blob& blob) {
    auto* self = static_cast<DeviceCore*>(context);
    self->on_blob(self->sink_camera_, blob);
}

void DeviceCore::on_blob(std::size_t camera, const fpga::Blob& blob) noexcept {
    Camera& cam = cams_[camera];
    if (!streaming_ || cam.abandoned) return;
    const PendingBlob p{cycle_time_ns(cam.field_start_us, blob.last_pixel_cycle),
                        cycle_time_ns(cam.field_start_us, blob.emit_cycle), blob.index};
    // The blob waits in the FPGA's output FIFO until the soft core takes it (flush_low_latency / end_field).
    if (!cam.blobs.push_back(blob) || !cam.pending.push_back(p)) {
        cam.blobs_dropped = true;
        ++blobs_dropped_;
        return;
    }
    // Its marker's position in the field's FieldMarkers names the patch (blob_index on the wire).
    const std::uint64_t too_large = cam.capture.stats().too_large;
    cam.capture.add_blob(blob, static_cast<std::uint16_t>(cam.blobs.size() - 1));
    counters_.patches_too_large += cam.capture.stats().too_large - too_large;
}

void DeviceCore::patch_sink(void* context, const fpga::Patch& patch) {
    auto* self = static_cast<DeviceCore*>(context);
    self->on_patch(self->sink_camera_, patch);
}

void DeviceCore::on_patch(std::size_t camera, const fpga::Patch& patch) noexcept {
    Camera& cam = cams_[camera];
    if (!streaming_ || cam.abandoned) return;
    // The field's patch budget, counted in wire bytes; the samples wait in the camera's pool of the same size.
    const std::size_t bytes = patch.bytes();
    const std::size_t wire =
        bytes + protocol::patch_fragment_count(bytes) * (kFrameOverheadBytes + protocol::kBlobPatchHeaderBytes);
    if (cam.patch_wire_bytes + wire > kPatchBudgetBytesPerField || cam.patch_pool_used + bytes > cam.patch_pool.size() ||
        cam.patches.full()) {
        ++counters_.patches_dropped;
        return;
    }
    StoredPatch s;
    s.class_id = patch.class_id;
    s.flags = patch.flags;
    s.blob_index = patch.blob_index;
    s.origin_x = patch.origin_x;
    s.origin_y = patch.origin_y;
    s.width_px = patch.width_px;
    s.height_px = patch.height_px;
    s.offset = cam.patch_pool_used;
    s.ready_ns = cycle_time_ns(cam.field_start_us,
                               fpga::active_line_end_cycle(static_cast<std::uint32_t>(patch.origin_y + patch.height_px - 1)));
    for (std::size_t i = 0; i < bytes; ++i) cam.patch_pool[s.offset + i] = patch.samples[i];
    cam.patch_pool_used += bytes;
    cam.patch_wire_bytes += wire;
    cam.patches.push_back(s);
}

void DeviceCore::send_patches(std::size_t camera, std::uint64_t ready_ns, std::size_t below_index) noexcept {
    Camera& cam = cams_[camera];
    // In capture order (the blobs' order); a patch waits until its marker is queued (blob_index < below_index).
    for (; cam.patches_next < cam.patches.size() && cam.patches[cam.patches_next].blob_index < below_index;
         ++cam.patches_next) {
        const StoredPatch& s = cam.patches[cam.patches_next];
        const std::uint64_t ready = s.ready_ns > ready_ns ? s.ready_ns : ready_ns;
        const std::size_t bytes = protocol::patch_bytes(s.width_px, s.height_px);
        const std::size_t fragments = protocol::patch_fragment_count(bytes);
        const std::size_t wire = bytes + fragments * (kFrameOverheadBytes + protocol::kBlobPatchHeaderBytes);
        // A patch never pushes markers out of the queue: it goes whole, or not at all, and leaves room.
        if (queue_.bytes() + wire + kTxQueueReserveBytes > TxQueue::byte_capacity() ||
            queue_.packets() + fragments + kTxQueueReservePackets > TxQueue::packet_capacity()) {
            ++counters_.patches_dropped;
            continue;
        }
        protocol::BlobPatch& m = patch_msg_;
        m.camera_id = static_cast<std::uint8_t>(camera);
        m.field_parity = cam.parity;
        m.colour_class = s.class_id;
        m.flags = s.flags;
        m.field_counter = cam.field;
        m.blob_index = s.blob_index;
        m.origin_x = s.origin_x;
        m.origin_y = s.origin_y;
        m.width_px = s.width_px;
        m.height_px = s.height_px;
        m.fragment_count = static_cast<std::uint8_t>(fragments);
        for (std::size_t f = 0; f < fragments; ++f) {
            m.fragment_index = static_cast<std::uint8_t>(f);
            const std::size_t first = f * protocol::kPatchFragmentBytes, n = m.sample_bytes();
            for (std::size_t i = 0; i < n; ++i) m.samples[i] = cam.patch_pool[s.offset + first + i];
            const std::size_t sent = queue_message(protocol::Message{m}, 0);
            if (sent == 0) continue;  // cannot happen for a captured patch (valid by construction)
            ++counters_.patch_frames;
            counters_.patch_bytes += sent;
            // Modelled timeline, as for markers: the soft core copies the frame, then the link sends it.
            const std::uint64_t start_ns = ready > core_free_ns_ ? ready : core_free_ns_;
            core_free_ns_ = start_ns + frame_cost_ns(sent, 0);
            link_.transmit(core_free_ns_, sent);
        }
        ++counters_.patches_sent;
    }
}

void DeviceCore::end_field(std::size_t camera) noexcept {
    Camera& cam = cams_[camera];
    sink_camera_ = camera;
    cam.pipeline.end_field();  // may deliver the blobs touching the last line through blob_sink
    cam.capture.end_field();   // cuts the patches still waiting for their halo lines
    cam.in_field = false;
    ++cam.fields_processed;
    const fpga::FieldStats& st = cam.pipeline.field_stats();
    if (st.table_overflows > 0) ++blob_table_overflows_;
    if (st.dropped_blobs > 0) {
        blobs_dropped_ += st.dropped_blobs;
        cam.blobs_dropped = true;
    }
    if (!streaming_ || cam.abandoned) return;
    // The field is over once its last active pixel is in and the last blob has left the pipeline.
    const std::uint32_t end_cycle =
        st.last_emit_cycle > st.last_active_line_end_cycle ? st.last_emit_cycle : st.last_active_line_end_cycle;
    cam.field_end_us = fpga::field_end_us(cam.field_start_us);
    const std::uint64_t ready_ns = cycle_time_ns(cam.field_start_us, end_cycle);
    if (cam.low_latency) {
        cam.closed = true;
        cam.close_ready_ns = ready_ns;
        flush_low_latency();  // sends the closing part before the next field can begin
        return;
    }
    // One message train per field, exactly as `eyesim fpga` writes it (shared conversion in fpga/wire.hpp).
    fpga::FieldInfo info = fpga::field_info(st, static_cast<std::uint8_t>(camera), cam.parity, cam.field_start_us);
    info.blobs_dropped = info.blobs_dropped || cam.blobs_dropped;
    const std::size_t n = fpga::to_field_markers(cam.blobs.data(), cam.blobs.size(), info, parts_.data(), parts_.size());
    std::size_t first = 0;
    for (std::size_t p = 0; p < n; ++p) {
        send_part(camera, parts_[p], cam.pending.data() + first, ready_ns);
        first += parts_[p].marker_count;
    }
    send_patches(camera, ready_ns, kAllPatches);  // precision mode: after the field's markers
}

void DeviceCore::flush_low_latency() noexcept {
    // The soft core serves the three cameras' blob FIFOs in completion order. When it gets to a camera, every blob
    // already waiting in that camera's FIFO goes into one frame (up to 14): bursts share one frame's overhead.
    constexpr std::uint64_t kNever = ~std::uint64_t{0};
    if (!streaming_) return;
    for (;;) {
        std::size_t pick = kCameras;
        std::uint64_t key = kNever;
        for (std::size_t c = 0; c < kCameras; ++c) {
            const Camera& cam = cams_[c];
            if (!cam.low_latency) continue;
            std::uint64_t k = kNever;
            if (cam.sent < cam.pending.size()) k = cam.pending[cam.sent].complete_ns;
            else if (cam.closed) k = cam.close_ready_ns;
            if (k < key) key = k, pick = c;
        }
        if (pick == kCameras) {
            // Precision mode: the patches cut since, whose markers are out, follow at once (low latency).
            for (std::size_t c = 0; c < kCameras; ++c)
                if (cams_[c].low_latency) send_patches(c, 0, cams_[c].sent);
            return;
        }
        Camera& cam = cams_[pick];
        const std::uint64_t t = key > core_free_ns_ ? key : core_free_ns_;
        std::size_t k = 0;
        while (cam.sent + k < cam.pending.size() && k < protocol::kMaxMarkersPerMessage &&
               cam.pending[cam.sent + k].complete_ns <= t)
            ++k;
        const bool last = cam.closed && cam.sent + k == cam.pending.size();
        protocol::FieldMarkers& fm = parts_[0];
        fm = protocol::FieldMarkers{};
        fm.camera_id = static_cast<std::uint8_t>(pick);
        fm.field_parity = cam.parity;
        fm.field_counter = cam.field;
        fm.flags = protocol::kFieldFlagLowLatency;
        if (!last) fm.flags |= protocol::kFieldFlagMoreFollows;
        const fpga::FieldStats& st = cam.pipeline.field_stats();
        if (last && (cam.blobs_dropped || st.table_overflows != 0 || st.dropped_blobs != 0))
            fm.flags |= protocol::kFieldFlagBlobsDropped;
        fm.field_end_us = last ? cam.field_end_us : 0;
        fm.marker_count = static_cast<std::uint8_t>(k);
        for (std::size_t i = 0; i < k; ++i) fm.markers[i] = fpga::to_marker(cam.blobs[cam.sent + i], cam.field_start_us);
        const std::uint64_t ready = last && cam.close_ready_ns > t ? cam.close_ready_ns : t;
        send_part(pick, fm, cam.pending.data() + cam.sent, ready);
        cam.sent += k;
        if (last) {
            cam.closed = false, cam.low_latency = false;  // done with this field
            send_patches(pick, ready, kAllPatches);      // precision mode: the rest, after the closing part
        } else {
            send_patches(pick, ready, cam.sent);         // precision mode: those whose markers are now out
        }
    }
}

void DeviceCore::send_part(std::size_t camera, protocol::FieldMarkers& fm, const PendingBlob* pending,
                           std::uint64_t ready_ns) noexcept {
    Camera& cam = cams_[camera];
    fm.part_index = cam.part_index++;
    const std::size_t count = fm.marker_count;
    const std::uint8_t flags = fm.flags;
    const std::size_t bytes = queue_message(protocol::Message{fm}, static_cast<std::uint32_t>(count));
    if (bytes == 0) return;
    counters_.blobs_sent += count;
    // Modelled timeline: the soft core handles frames one at a time, then the link sends them in order.
    const std::uint64_t start_ns = ready_ns > core_free_ns_ ? ready_ns : core_free_ns_;
    const std::uint64_t queued_ns = start_ns + frame_cost_ns(bytes, count);
    core_free_ns_ = queued_ns;
    const std::uint64_t written_ns = link_.transmit(queued_ns, bytes);
    if (hal_.latency == nullptr) return;
    for (std::size_t i = 0; i < count; ++i) {
        BlobLatency r;
        r.camera = static_cast<std::uint8_t>(camera);
        r.low_latency = (flags & protocol::kFieldFlagLowLatency) ? 1 : 0;
        r.blob_index = pending[i].index;
        r.field_counter = cam.field;
        r.last_pixel_ns = pending[i].last_pixel_ns;
        r.complete_ns = pending[i].complete_ns;
        r.queued_ns = queued_ns;
        r.written_ns = written_ns;
        hal_.latency->on_blob(r);
    }
}

std::size_t DeviceCore::queue_message(const protocol::Message& m, std::uint32_t blobs) noexcept {
    const std::size_t n = protocol::encode_frame(m, tx_sequence_, frame_);
    if (n == 0) return 0;  // an invalid message is a firmware bug; never put garbage on the wire
    ++tx_sequence_;
    ++counters_.frames_queued;
    // The tag remembers how many blobs a frame carries, so a dropped frame is counted in blobs_dropped too.
    queue_.push(frame_.data(), n, blobs, [this](std::uint32_t tag) { blobs_dropped_ += tag; });
    return n;
}

// ---------------------------------------------------------------------------------------------------------------
// Host side.
// ---------------------------------------------------------------------------------------------------------------

void DeviceCore::service() noexcept {
    handle_rx();
    send_periodic();
    pump_tx();
}

void DeviceCore::close_fields_for_stop() noexcept {
    // Blobs already taken from the FIFOs go out first (step_cameras normally has sent them already).
    flush_low_latency();
    const std::uint64_t now_us = hal_.clock->now_us();
    for (std::size_t c = 0; c < kCameras; ++c) {
        Camera& cam = cams_[c];
        // A low-latency field the host has seen parts of gets its last part now: no markers, more_follows clear,
        // blobs_dropped set (the rest of the field is not sent), field_end_us = the stop time.
        if (cam.low_latency && cam.part_index > 0) {
            protocol::FieldMarkers& fm = parts_[0];
            fm = protocol::FieldMarkers{};
            fm.camera_id = static_cast<std::uint8_t>(c);
            fm.field_parity = cam.parity;
            fm.field_counter = cam.field;
            fm.flags = protocol::kFieldFlagLowLatency | protocol::kFieldFlagBlobsDropped;
            fm.field_end_us = now_us;
            fm.marker_count = 0;
            send_part(c, fm, cam.pending.data(), now_us * 1000u);
        }
        cam.low_latency = false;
        cam.closed = false;
        // Nothing more of a field in progress is sent, even if streaming starts again before it ends.
        if (cam.in_field) cam.abandoned = true;
    }
}

void DeviceCore::host_disconnected() noexcept {
    // The fields in progress are not continued towards the next host (their first parts went to this one).
    for (Camera& cam : cams_) {
        cam.low_latency = false;
        cam.closed = false;
        if (cam.in_field) cam.abandoned = true;
    }
    streaming_ = config_.stream_on_start;
    queue_.clear();
    tx_len_ = tx_off_ = 0;
    parser_.reset();
}

void DeviceCore::handle_rx() noexcept {
    if (hal_.source == nullptr) return;
    std::size_t commands = 0;
    while (commands < kMaxCommandsPerService) {
        const std::size_t n = hal_.source->read_some(rx_.data(), rx_.size());
        if (n == 0) break;
        parser_.parse(std::span<const std::uint8_t>(rx_.data(), n), [&](const protocol::DecodedFrame& f) {
            if (const auto* c = std::get_if<Command>(&f.message)) {
                const Reply r = execute(*c);
                queue_message(protocol::Message{r}, 0);
                ++commands;
            } else {
                ++parse_errors_other_;  // the host sends commands only
            }
        });
    }
}

void DeviceCore::send_periodic() noexcept {
    if (!streaming_) return;
    const std::uint64_t now = hal_.clock->now_us();
    if (hal_.pedal != nullptr && (!pedal_sampled_once_ || now - last_pedal_sample_us_ >= kPedalSampleUs)) {
        last_pedal_sample_us_ = now;
        pedal_sampled_once_ = true;
        const PedalReading in = hal_.pedal->read();
        protocol::PedalState p;
        p.device_us = now;
        bool changed = in.buttons != last_pedal_.buttons;
        for (std::size_t a = 0; a < protocol::kPedalAxisCount; ++a) {
            p.axes[a] = in.axes[a];
            const int d = static_cast<int>(in.axes[a]) - static_cast<int>(last_pedal_.axes[a]);
            changed = changed || d >= kPedalDeadbandCounts || -d >= kPedalDeadbandCounts ||
                      ((in.axes[a] == 0 || in.axes[a] == 0xFFFF) && d != 0);  // the end stops are always sent
        }
        p.buttons = in.buttons;
        if (!pedal_sent_once_ || changed || now - last_pedal_us_ >= pedal_period_ms_ * 1000ull) {
            queue_message(protocol::Message{p}, 0);
            last_pedal_ = p;
            last_pedal_us_ = now;
            pedal_sent_once_ = true;
        }
    }
    if (!status_sent_once_ || now - last_status_us_ >= status_period_ms_ * 1000ull) {
        queue_message(protocol::Message{status()}, 0);
        last_status_us_ = now;
        status_sent_once_ = true;
    }
}

void DeviceCore::pump_tx() noexcept {
    if (hal_.sink == nullptr) return;
    if (!hal_.sink->connected()) {
        // Nobody listens: what would be written is lost anyway; keep the queue from filling with stale data.
        queue_.clear();
        tx_len_ = tx_off_ = 0;
        return;
    }
    for (;;) {
        if (tx_off_ == tx_len_) {
            tx_len_ = queue_.pop(tx_.data(), tx_.size());
            tx_off_ = 0;
            if (tx_len_ == 0) return;
        }
        const std::size_t n = hal_.sink->write_some(tx_.data() + tx_off_, tx_len_ - tx_off_);
        if (n == 0) return;  // the link is busy: try again on the next service call, never wait
        tx_off_ += n;
        bytes_sent_ += n;
        if (tx_off_ == tx_len_) ++counters_.frames_written;
    }
}

protocol::DeviceStatus DeviceCore::status() const noexcept {
    protocol::DeviceStatus s;
    s.device_us = hal_.clock->now_us();
    s.uptime_us = s.device_us;
    for (std::size_t c = 0; c < kCameras; ++c) s.fields_processed[c] = cams_[c].fields_processed;
    s.blobs_dropped = blobs_dropped_;
    s.blob_table_overflows = blob_table_overflows_;
    s.queue_overflows = static_cast<std::uint32_t>(queue_.stats().dropped_packets);
    s.bytes_sent = bytes_sent_;
    s.crc_errors = static_cast<std::uint32_t>(parser_.stats().crc_errors);
    s.parse_errors = static_cast<std::uint32_t>(parser_.stats().errors() - parser_.stats().crc_errors) +
                     parse_errors_other_;
    return s;
}

// ---------------------------------------------------------------------------------------------------------------
// Commands: every field validated; a refused command changes nothing and gets a Nack with the reason.
// ---------------------------------------------------------------------------------------------------------------

Reply DeviceCore::execute(const Command& c) noexcept {
    ++counters_.commands;
    Reply r;
    r.command_id = c.command_id;
    r.opcode = c.opcode;
    r.host_us = c.host_us;
    r.device_us = hal_.clock->now_us();
    switch (static_cast<Opcode>(c.opcode)) {
        case Opcode::RegisterWrite: r = write_register(c, r); break;
        case Opcode::RegisterRead:
            r = c.value != 0 ? nack(r, NackReason::Malformed) : read_register(c, r);
            break;
        case Opcode::StreamStart:
        case Opcode::StreamStop:
        case Opcode::Ping:
            if (c.address != 0 || c.value != 0) {
                r = nack(r, NackReason::Malformed);
            } else if (static_cast<Opcode>(c.opcode) == Opcode::StreamStart) {
                if (!streaming_) {
                    status_sent_once_ = pedal_sent_once_ = pedal_sampled_once_ = false;  // first status and pedal at once
                }
                streaming_ = true;
            } else if (static_cast<Opcode>(c.opcode) == Opcode::StreamStop) {
                if (streaming_) close_fields_for_stop();  // queued before this command's Reply
                streaming_ = false;
            }
            break;
        case Opcode::SetLowLatency:
            if (c.address != 0) r = nack(r, NackReason::Malformed);
            else if (c.value > 1) r = nack(r, NackReason::BadRange);
            else low_latency_ = c.value == 1, r.value = c.value;
            break;
        default: r = nack(r, NackReason::BadOpcode); break;
    }
    if (r.status != static_cast<std::uint8_t>(ReplyStatus::Ack)) ++counters_.nacks;
    return r;
}

Reply DeviceCore::write_register(const Command& c, Reply r) noexcept {
    const std::uint32_t a = c.address;
    if (a % 4 != 0 || a > 0xFFFF) return nack(r, NackReason::BadAddress);
    if (a >= kFwRegBase) {
        switch (a) {
            case fwreg::kId:
            case fwreg::kVersion:
            case fwreg::kStreaming: return nack(r, NackReason::ReadOnly);
            case fwreg::kStatusPeriodMs:
                if (c.value < 10 || c.value > 10000) return nack(r, NackReason::BadRange);
                status_period_ms_ = c.value;
                break;
            case fwreg::kPedalPeriodMs:
                if (c.value < 1 || c.value > 1000) return nack(r, NackReason::BadRange);
                pedal_period_ms_ = c.value;
                break;
            case fwreg::kLowLatency:
                if (c.value > 1) return nack(r, NackReason::BadRange);
                low_latency_ = c.value == 1;
                break;
            default: return nack(r, NackReason::BadAddress);
        }
        r.value = c.value;
        return r;
    }
    const std::uint32_t target = a & kRegTargetMask;
    const auto offset = static_cast<std::uint16_t>(a & kRegOffsetMask);
    if (target > kRegCameraBase * kCameras) return nack(r, NackReason::BadAddress);
    const std::size_t first = target == 0 ? 0 : target / kRegCameraBase - 1;
    const std::size_t last = target == 0 ? kCameras : first + 1;
    // Validate on every target first, so a broadcast write is all-or-nothing.
    for (std::size_t cam = first; cam < last; ++cam) {
        const fpga::RegWriteResult w = cams_[cam].regs.check_write(offset, c.value);
        if (w != fpga::RegWriteResult::kOk) return nack(r, reason_of(w));
    }
    // The pipelines sample their map at begin_field: the write takes effect with the next field.
    for (std::size_t cam = first; cam < last; ++cam) cams_[cam].regs.write(offset, c.value);
    r.value = cams_[first].regs.get(offset);
    return r;
}

Reply DeviceCore::read_register(const Command& c, Reply r) noexcept {
    const std::uint32_t a = c.address;
    if (a % 4 != 0 || a > 0xFFFF) return nack(r, NackReason::BadAddress);
    if (a >= kFwRegBase) {
        switch (a) {
            case fwreg::kId: r.value = kFirmwareId; break;
            case fwreg::kVersion: r.value = kFirmwareVersion; break;
            case fwreg::kStatusPeriodMs: r.value = status_period_ms_; break;
            case fwreg::kPedalPeriodMs: r.value = pedal_period_ms_; break;
            case fwreg::kLowLatency: r.value = low_latency_ ? 1 : 0; break;
            case fwreg::kStreaming: r.value = streaming_ ? 1 : 0; break;
            default: return nack(r, NackReason::BadAddress);
        }
        return r;
    }
    const std::uint32_t target = a & kRegTargetMask;
    if (target > kRegCameraBase * kCameras) return nack(r, NackReason::BadAddress);
    const std::size_t cam = target == 0 ? 0 : target / kRegCameraBase - 1;
    std::uint32_t v = 0;
    if (!cams_[cam].regs.read(static_cast<std::uint16_t>(a & kRegOffsetMask), v)) return nack(r, NackReason::BadAddress);
    r.value = v;
    return r;
}

}  // namespace eyesim::firmware
