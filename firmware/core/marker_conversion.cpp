// Blob → Marker: Q8 centroid to Q16, border flags, completion time from the PAL cycle model.
#include "eyesim/firmware/marker_conversion.hpp"

#include "eyesim/fpga/timing.hpp"

namespace eyesim::firmware {

protocol::Marker to_marker(const fpga::Blob& b, std::uint64_t field_start_us) noexcept {
    protocol::Marker m;
    m.colour_class = b.class_id;
    const std::uint8_t border = fpga::kBlobTouchesLeft | fpga::kBlobTouchesRight | fpga::kBlobTouchesTop |
                                fpga::kBlobTouchesBottom;
    if (b.flags & border) m.flags |= protocol::kMarkerFlagTouchesBorder;
    if (b.flags & fpga::kBlobIncomplete) m.flags |= protocol::kMarkerFlagSaturated;
    m.bbox_x0 = b.x_min;
    m.bbox_y0 = b.y_min;
    m.bbox_x1 = b.x_max;
    m.bbox_y1 = b.y_max;
    m.x_q16 = b.cx_q16;
    m.y_q16 = b.cy_q16;
    m.area_px = b.area_px;
    m.intensity_sum = b.sum_w > 0xFFFFFFFFu ? 0xFFFFFFFFu : static_cast<std::uint32_t>(b.sum_w);
    m.complete_us = (field_start_us * 1000u + fpga::cycles_to_ns(b.emit_cycle)) / 1000u;
    return m;
}

}  // namespace eyesim::firmware
