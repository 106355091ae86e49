#include "eyesim/fpga/wire.hpp"

#include "eyesim/fpga/timing.hpp"

namespace eyesim::fpga {

uint64_t device_time_us(uint64_t field_start_us, uint32_t cycle) {
    return field_start_us + static_cast<uint64_t>(cycle) * 1'000'000ull / kPixelClockHz;
}

uint64_t field_end_us(uint64_t field_start_us) {
    return device_time_us(field_start_us, active_line_end_cycle(kActiveLinesPerField - 1));
}

protocol::Marker to_marker(const Blob& b, uint64_t field_start_us) {
    protocol::Marker m;
    m.colour_class = b.class_id;
    uint8_t f = 0;
    if (b.flags & (kBlobTouchesLeft | kBlobTouchesRight | kBlobTouchesTop | kBlobTouchesBottom))
        f |= protocol::kMarkerFlagTouchesBorder;
    if (b.flags & kBlobMerged) f |= protocol::kMarkerFlagMerged;
    if (b.flags & kBlobClippedByRoi) f |= protocol::kMarkerFlagClippedByRoi;
    if (b.flags & kBlobIncomplete) f |= protocol::kMarkerFlagSaturated;
    m.flags = f;
    m.bbox_x0 = b.x_min;
    m.bbox_y0 = b.y_min;
    m.bbox_x1 = b.x_max;
    m.bbox_y1 = b.y_max;
    static_assert(kCentroidFracBits == 16 && protocol::kCoordScale == 65536, "same fixed-point scale");
    m.x_q16 = b.cx_q16;
    m.y_q16 = b.cy_q16;
    m.area_px = b.area_px;
    m.intensity_sum = static_cast<uint32_t>(b.sum_w);  // Σw has 27 bits
    m.complete_us = device_time_us(field_start_us, b.last_pixel_cycle);
    return m;
}

FieldInfo field_info(const FieldStats& stats, uint8_t camera, uint8_t parity, uint64_t field_start_us) {
    FieldInfo info;
    info.camera = camera;
    info.parity = parity;
    info.field_counter = stats.field_counter;
    info.field_start_us = field_start_us;
    info.blobs_dropped = stats.table_overflows != 0 || stats.dropped_blobs != 0;
    return info;
}

size_t to_field_markers(const Blob* blobs, size_t n, const FieldInfo& info, protocol::FieldMarkers* out,
                        size_t max_out) {
    const size_t parts = field_markers_messages(n);
    if (max_out < parts || out == nullptr) return 0;
    const uint64_t end_us = field_end_us(info.field_start_us);
    size_t next = 0;
    for (size_t p = 0; p < parts; ++p) {
        protocol::FieldMarkers& m = out[p];
        m = protocol::FieldMarkers{};
        m.camera_id = info.camera;
        m.field_parity = info.parity;
        m.field_counter = info.field_counter;
        m.field_end_us = end_us;
        m.part_index = static_cast<uint16_t>(p);
        m.flags = static_cast<uint8_t>((p + 1 < parts ? protocol::kFieldFlagMoreFollows : 0) |
                                       (info.blobs_dropped ? protocol::kFieldFlagBlobsDropped : 0));
        size_t k = 0;
        for (; k < protocol::kMaxMarkersPerMessage && next < n; ++k, ++next)
            m.markers[k] = to_marker(blobs[next], info.field_start_us);
        m.marker_count = static_cast<uint8_t>(k);
    }
    return parts;
}

}  // namespace eyesim::fpga
