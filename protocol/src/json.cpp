#include "eyesim/protocol/json.hpp"

#include <cinttypes>
#include <cstdarg>
#include <cstdio>

namespace eyesim::protocol {

namespace {

/// Appends printf-formatted text to a fixed buffer; remembers overflow.
class Out {
public:
    explicit Out(std::span<char> buf) noexcept : buf_(buf) {
        if (!buf_.empty()) buf_[0] = '\0';
    }
    [[gnu::format(printf, 2, 3)]] void add(const char* fmt, ...) noexcept {
        if (bad_) return;
        va_list ap;
        va_start(ap, fmt);
        const std::size_t room = buf_.size() - len_;
        const int n = std::vsnprintf(buf_.data() + len_, room, fmt, ap);
        va_end(ap);
        if (n < 0 || static_cast<std::size_t>(n) >= room) {
            bad_ = true;
            return;
        }
        len_ += static_cast<std::size_t>(n);
    }
    void u(const char* key, std::uint64_t v) noexcept { add(",\"%s\":%" PRIu64, key, v); }
    std::size_t result() const noexcept { return bad_ || buf_.empty() ? 0 : len_; }

private:
    std::span<char> buf_;
    std::size_t len_ = 0;
    bool bad_ = buf_.empty();
};

void body(Out& o, const FieldMarkers& m) noexcept {
    o.u("camera_id", m.camera_id);
    o.u("field_parity", m.field_parity);
    o.u("flags", m.flags);
    o.u("marker_count", m.marker_count);
    o.u("field_counter", m.field_counter);
    o.u("field_end_us", m.field_end_us);
    o.u("part_index", m.part_index);
    o.add(",\"markers\":[");
    for (std::size_t i = 0; i < m.marker_count && i < kMaxMarkersPerMessage; ++i) {
        const Marker& k = m.markers[i];
        o.add("%s{\"colour_class\":%u", i ? "," : "", static_cast<unsigned>(k.colour_class));
        o.u("flags", k.flags);
        o.u("bbox_x0", k.bbox_x0);
        o.u("bbox_y0", k.bbox_y0);
        o.u("bbox_x1", k.bbox_x1);
        o.u("bbox_y1", k.bbox_y1);
        o.u("x_q16", k.x_q16);
        o.u("y_q16", k.y_q16);
        o.u("area_px", k.area_px);
        o.u("intensity_sum", k.intensity_sum);
        o.u("complete_us", k.complete_us);
        o.add(",\"x_px\":%.6f,\"y_px\":%.6f}", k.x_q16 / static_cast<double>(kCoordScale),
              k.y_q16 / static_cast<double>(kCoordScale));
    }
    o.add("]");
}
void body(Out& o, const PedalState& m) noexcept {
    o.u("device_us", m.device_us);
    o.add(",\"axes\":[%u,%u,%u]", static_cast<unsigned>(m.axes[0]), static_cast<unsigned>(m.axes[1]),
          static_cast<unsigned>(m.axes[2]));
    o.u("buttons", m.buttons);
}
void body(Out& o, const DeviceStatus& m) noexcept {
    o.u("device_us", m.device_us);
    o.u("uptime_us", m.uptime_us);
    o.add(",\"fields_processed\":[%" PRIu32 ",%" PRIu32 ",%" PRIu32 "]", m.fields_processed[0],
          m.fields_processed[1], m.fields_processed[2]);
    o.u("blobs_dropped", m.blobs_dropped);
    o.u("blob_table_overflows", m.blob_table_overflows);
    o.u("queue_overflows", m.queue_overflows);
    o.u("bytes_sent", m.bytes_sent);
    o.u("crc_errors", m.crc_errors);
    o.u("parse_errors", m.parse_errors);
}
void body(Out& o, const Command& m) noexcept {
    o.u("command_id", m.command_id);
    o.u("opcode", m.opcode);
    o.u("address", m.address);
    o.u("value", m.value);
    o.u("host_us", m.host_us);
}
void body(Out& o, const Reply& m) noexcept {
    o.u("command_id", m.command_id);
    o.u("opcode", m.opcode);
    o.u("status", m.status);
    o.u("reason", m.reason);
    o.u("value", m.value);
    o.u("host_us", m.host_us);
    o.u("device_us", m.device_us);
}
void body(Out& o, const BlobPatch& m) noexcept {
    o.u("camera_id", m.camera_id);
    o.u("field_parity", m.field_parity);
    o.u("colour_class", m.colour_class);
    o.u("flags", m.flags);
    o.u("field_counter", m.field_counter);
    o.u("blob_index", m.blob_index);
    o.u("origin_x", m.origin_x);
    o.u("origin_y", m.origin_y);
    o.u("width_px", m.width_px);
    o.u("height_px", m.height_px);
    o.u("fragment_index", m.fragment_index);
    o.u("fragment_count", m.fragment_count);
    // The samples as one lower-case hex string (two digits per byte), in wire order.
    o.add(",\"samples_hex\":\"");
    const std::size_t n = m.sample_bytes();
    for (std::size_t i = 0; i < n; ++i) o.add("%02x", static_cast<unsigned>(m.samples[i]));
    o.add("\"");
}

}  // namespace

std::size_t format_json(const DecodedFrame& f, std::span<char> out, const std::uint64_t* host_rx_us) noexcept {
    Out o(out);
    o.add("{\"type\":\"%s\"", message_type_name(message_type(f.message)));
    o.u("version", f.header.version);
    o.u("sequence", f.header.sequence);
    o.u("payload_bytes", f.header.payload_bytes);
    if (host_rx_us) o.u("host_rx_us", *host_rx_us);
    std::visit([&](const auto& m) { body(o, m); }, f.message);
    o.add("}");
    return o.result();
}

std::size_t format_stats_json(const ParserStats& s, std::span<char> out) noexcept {
    Out o(out);
    o.add("{\"bytes_in\":%" PRIu64, s.bytes_in);
    o.u("frames", s.frames);
    o.u("skipped_bytes", s.skipped_bytes);
    o.u("resyncs", s.resyncs);
    o.u("bad_version", s.bad_version);
    o.u("unknown_type", s.unknown_type);
    o.u("bad_length", s.bad_length);
    o.u("crc_errors", s.crc_errors);
    o.u("truncated", s.truncated);
    o.u("bad_payload", s.bad_payload);
    o.u("sequence_gaps", s.sequence_gaps);
    o.add("}");
    return o.result();
}

}  // namespace eyesim::protocol
