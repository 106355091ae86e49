#include "eyesim/protocol/capture_replay.hpp"

namespace eyesim::protocol {

bool CaptureReplay::open(const char* path) noexcept {
    parser_.reset();
    sent_parser_.reset();
    pending_ = sent_pending_ = {};
    rx_us_ = sent_us_ = records_ = sent_records_ = 0;
    status_ = CaptureStatus::Ok;
    ended_ = false;
    return reader_.open(path);
}

bool CaptureReplay::next(DecodedFrame& out, std::uint64_t& host_rx_us) noexcept {
    bool sent = false;
    while (next(out, host_rx_us, sent))
        if (!sent) return true;
    return false;
}

bool CaptureReplay::next(DecodedFrame& out, std::uint64_t& host_rx_us, bool& sent) noexcept {
    for (;;) {
        if (parser_.next(out)) {
            host_rx_us = rx_us_;
            sent = false;
            return true;
        }
        if (sent_parser_.next(out)) {
            host_rx_us = sent_us_;
            sent = true;
            return true;
        }
        if (ended_) return false;
        if (!pending_.empty()) {
            pending_ = pending_.subspan(parser_.feed(pending_));
            continue;
        }
        if (!sent_pending_.empty()) {
            sent_pending_ = sent_pending_.subspan(sent_parser_.feed(sent_pending_));
            continue;
        }
        CaptureRecord rec;
        const CaptureStatus s = reader_.next(rec);
        if (s == CaptureStatus::Ok) {
            ++records_;
            if (rec.direction == CaptureDirection::Sent) {
                ++sent_records_;
                sent_us_ = rec.host_rx_us;
                sent_pending_ = rec.bytes;
            } else {
                rx_us_ = rec.host_rx_us;
                pending_ = rec.bytes;
            }
            continue;
        }
        if (s == CaptureStatus::Corrupt) continue;  // a damaged stretch was skipped; the reader counts it
        status_ = s;
        ended_ = true;
        parser_.end_stream();  // frames still in the buffer come out of the next parser_.next() calls
        sent_parser_.end_stream();
    }
}

}  // namespace eyesim::protocol
