#include "eyesim/frame/loss.hpp"

#include <fmt/format.h>

#include <variant>

namespace eyesim::frame {

bool LossCounts::any() const noexcept {
    return sequence_gaps || frames_lost || frames_repeated || frames_late || fields_lost || fields_out_of_order ||
           time_jumps || resyncs || parse_errors || device_queue_overflows || device_blobs_dropped || link_drops;
}

bool LossCounter::seen(std::uint16_t back) const noexcept {
    return (window_[back / 64] >> (back % 64)) & 1u;
}

void LossCounter::mark(std::uint16_t back, bool on) noexcept {
    const std::uint64_t bit = std::uint64_t(1) << (back % 64);
    if (on) window_[back / 64] |= bit;
    else window_[back / 64] &= ~bit;
}

void LossCounter::observe(const protocol::DecodedFrame& f) noexcept {
    ++counts_.frames;
    const std::uint16_t s = f.header.sequence;
    if (have_seq_ && s != static_cast<std::uint16_t>(last_seq_ + 1)) ++counts_.sequence_gaps;
    last_seq_ = s;
    const std::uint16_t d = static_cast<std::uint16_t>(s - highest_seq_);
    if (!have_seq_ || (d >= 0x8000 && 0x10000 - d >= kWindow)) {
        // First frame, or a step back beyond the window: a new sequence (the device restarted).
        have_seq_ = true;
        highest_seq_ = s;
        window_.fill(0);
        mark(0, true);
    } else if (d == 0) {
        ++counts_.frames_repeated;
    } else if (d < 0x8000) {
        // Forward by d: the d − 1 numbers skipped are lost until they turn up late.
        counts_.frames_lost += d - 1u;
        if (d >= kWindow) {
            window_.fill(0);
        } else {
            const int words = d / 64, bits = d % 64;
            for (int w = int(window_.size()) - 1; w >= 0; --w) {
                std::uint64_t v = w - words >= 0 ? window_[std::size_t(w - words)] << bits : 0;
                if (bits && w - words - 1 >= 0) v |= window_[std::size_t(w - words - 1)] >> (64 - bits);
                window_[std::size_t(w)] = v;
            }
        }
        highest_seq_ = s;
        mark(0, true);
    } else {
        const std::uint16_t back = static_cast<std::uint16_t>(0x10000 - d);
        if (seen(back)) {
            ++counts_.frames_repeated;
        } else {
            ++counts_.frames_late;
            if (counts_.frames_lost > 0) --counts_.frames_lost;  // counted lost when the later one came
            mark(back, true);
        }
    }
    if (const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message)) {
        const std::size_t c = fm->camera_id;
        if (c < have_field_.size()) {
            const std::uint32_t step = fm->field_counter - highest_field_[c];
            if (!have_field_[c] || (step >= 0x80000000u && 0u - step > 64u)) {  // first, or a restarted counter
                have_field_[c] = true;
                highest_field_[c] = fm->field_counter;
            } else if (step != 0 && step < 0x80000000u) {
                counts_.fields_lost += step - 1u;
                highest_field_[c] = fm->field_counter;
            } else if (step != 0) {
                ++counts_.fields_out_of_order;
            }
        }
    } else if (const auto* st = std::get_if<protocol::DeviceStatus>(&f.message)) {
        // The device counts since power-up; the run's share is the growth since its first report.
        if (!have_status_) {
            have_status_ = true;
            first_overflows_ = st->queue_overflows;
            first_blobs_dropped_ = st->blobs_dropped;
        }
        counts_.device_queue_overflows = std::uint32_t(st->queue_overflows - first_overflows_);
        counts_.device_blobs_dropped = std::uint32_t(st->blobs_dropped - first_blobs_dropped_);
    }
}

void LossCounter::set_parser(const protocol::ParserStats& s) noexcept {
    counts_.resyncs = s.resyncs;
    counts_.skipped_bytes = s.skipped_bytes;
    counts_.parse_errors = s.errors();
}

void LossCounter::link_dropped() noexcept {
    ++counts_.link_drops;
    have_seq_ = false;
    have_field_.fill(false);
    have_status_ = false;  // a re-plugged device may have restarted its counters
    first_overflows_ = first_blobs_dropped_ = 0;
}

std::string loss_summary(const LossCounts& c) {
    std::string s;
    auto add = [&](std::uint64_t n, const char* what) {
        if (n == 0) return;
        s += fmt::format("{}{} {}", s.empty() ? "" : ", ", n, what);
    };
    add(c.frames_lost, "frames lost (sequence numbers never received)");
    add(c.sequence_gaps, "sequence gaps");
    add(c.frames_repeated, "frames repeated");
    add(c.frames_late, "frames late");
    add(c.fields_lost, "camera fields lost");
    add(c.fields_out_of_order, "camera fields out of order");
    add(c.time_jumps, "backward time jumps (new segments)");
    add(c.device_queue_overflows, "device transmit-queue overflows");
    add(c.device_blobs_dropped, "blobs dropped on the device");
    add(c.parse_errors, "damaged frames");
    add(c.resyncs, "resyncs");
    add(c.link_drops, "link drops");
    return s;
}

}  // namespace eyesim::frame
