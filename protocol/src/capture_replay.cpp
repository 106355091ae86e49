#include "eyesim/protocol/capture_replay.hpp"

namespace eyesim::protocol {

bool CaptureReplay::open(const char* path) noexcept {
    parser_.reset();
    pending_ = {};
    rx_us_ = records_ = 0;
    status_ = CaptureStatus::Ok;
    ended_ = false;
    return reader_.open(path);
}

bool CaptureReplay::next(DecodedFrame& out, std::uint64_t& host_rx_us) noexcept {
    for (;;) {
        if (parser_.next(out)) {
            host_rx_us = rx_us_;
            return true;
        }
        if (ended_) return false;
        if (!pending_.empty()) {
            pending_ = pending_.subspan(parser_.feed(pending_));
            continue;
        }
        CaptureRecord rec;
        const CaptureStatus s = reader_.next(rec);
        if (s == CaptureStatus::Ok) {
            ++records_;
            rx_us_ = rec.host_rx_us;
            pending_ = rec.bytes;
            continue;
        }
        if (s == CaptureStatus::Corrupt) continue;  // a damaged stretch was skipped; the reader counts it
        status_ = s;
        ended_ = true;
        parser_.end_stream();  // frames still in the buffer come out of the next parser_.next() calls
    }
}

}  // namespace eyesim::protocol
