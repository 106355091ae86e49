// Field-at-a-time loader delivered line by line with PAL timing.
#include "eyesim/firmware/pc/field_source.hpp"

#include "eyesim/fpga/timing.hpp"

namespace eyesim::firmware::pc {

FieldSource::FieldSource(FieldLoader loader, std::uint64_t epoch_us, int lines)
    : loader_(std::move(loader)),
      epoch_us_(epoch_us),
      lines_(lines),
      field_(static_cast<std::size_t>(lines) * fpga::kActivePixelsPerLine * 2),
      next_y_(-1) {}

std::uint64_t FieldSource::field_start_us(std::uint64_t k) const noexcept {
    return epoch_us_ + k * fpga::kFieldPeriodUs;
}

LineStatus FieldSource::next_line(CameraLine& out) noexcept {
    if (ended_) return LineStatus::end_of_stream;
    if (next_y_ < 0) {
        // The loader may throw (file read errors in the PC build); a failed load ends the stream.
        bool ok = false;
        try {
            start_us_ = field_start_us(index_);
            ok = loader_(index_, field_.data(), parity_, start_us_);
        } catch (...) {
            ok = false;
        }
        if (!ok) {
            ended_ = true;
            return LineStatus::end_of_stream;
        }
        next_y_ = 0;
    }
    const std::uint64_t start_us = start_us_;
    if (next_y_ == lines_) {
        next_y_ = -1;
        ++index_;
        ++fields_done_;
        return LineStatus::field_end;
    }
    const int y = next_y_++;
    out.uyvy = field_.data() + static_cast<std::size_t>(y) * fpga::kActivePixelsPerLine * 2;
    out.width_px = static_cast<std::uint16_t>(fpga::kActivePixelsPerLine);
    out.line = static_cast<std::uint16_t>(y);
    out.field = static_cast<std::uint32_t>(index_);
    out.parity = parity_;
    out.field_start_us = start_us;
    return LineStatus::line;
}

}  // namespace eyesim::firmware::pc
