#include "eyesim/protocol/stream_parser.hpp"

#include "eyesim/protocol/schema.hpp"
#include "wire_io.hpp"

#include <cstring>

namespace eyesim::protocol {

std::size_t StreamParser::feed(std::span<const std::uint8_t> bytes) noexcept {
    const std::size_t room = buf_.size() - fill_;
    const std::size_t n = bytes.size() < room ? bytes.size() : room;
    if (n > 0) std::memcpy(buf_.data() + fill_, bytes.data(), n);
    fill_ += n;
    stats_.bytes_in += n;
    return n;
}

void StreamParser::bytes_in_direct(std::size_t n) noexcept { stats_.bytes_in += n; }

bool StreamParser::next(DecodedFrame& out) noexcept {
    bool got = false;
    if (fill_ > 0) {
        std::size_t used = 0;
        got = scan(buf_.data(), fill_, used, out);
        if (used > 0) {
            std::memmove(buf_.data(), buf_.data() + used, fill_ - used);
            fill_ -= used;
        }
    }
    if (!got && eos_) close();  // end of stream reached and everything decided
    return got;
}

void StreamParser::skip(std::size_t n) noexcept {
    if (n == 0) return;
    if (!skipping_) {
        skipping_ = true;
        ++stats_.resyncs;
    }
    stats_.skipped_bytes += n;
    pos_ += n;
    // Once the scan has passed a CRC-failed frame without finding a frame inside it, it was corrupted in place.
    if (crc_pending_ && pos_ >= damage_end_) {
        crc_pending_ = false;
        ++stats_.crc_errors;
    }
}

bool StreamParser::header_error_counted() const noexcept {
    // A false header inside the span of a frame already counted (or about to be counted) as damaged is not a
    // second error.
    return pos_ >= damage_end_;
}

bool StreamParser::scan(const std::uint8_t* data, std::size_t n, std::size_t& used, DecodedFrame& out) noexcept {
    std::size_t i = 0;
    for (;;) {
        // Hunt for the first sync byte; bytes before it are garbage.
        if (i < n && data[i] != kSync0) {
            const void* hit = std::memchr(data + i, kSync0, n - i);
            const std::size_t j = hit ? static_cast<std::size_t>(static_cast<const std::uint8_t*>(hit) - data) : n;
            skip(j - i);
            i = j;
        }
        if (i == n) break;
        if (n - i < 2) {                      // need the second sync byte
            if (!eos_) break;
            skip(1);
            ++i;
            continue;
        }
        if (data[i + 1] != kSync1) {          // lone 0xE7
            skip(1);
            ++i;
            continue;
        }
        if (n - i < kFrameHeaderBytes) {      // need the whole header
            if (!eos_) break;
            cut_short(pos_ + (n - i));        // its span: the rest of the stream
            ++i;
            continue;
        }
        const std::uint8_t* p = data + i;
        if (p[2] != kProtocolVersion) {
            if (header_error_counted()) ++stats_.bad_version;
            skip(1);
            ++i;
            continue;
        }
        if (p[3] < 1 || p[3] > kMessageTypeCount) {
            if (header_error_counted()) ++stats_.unknown_type;
            skip(1);
            ++i;
            continue;
        }
        const auto type = static_cast<MessageType>(p[3]);
        const std::size_t len = wire::get_u16(p + 6);
        if (len > kMaxPayloadBytes || !valid_payload_length(type, len)) {
            if (header_error_counted()) ++stats_.bad_length;
            skip(1);
            ++i;
            continue;
        }
        // A plausible header inside the span of a damaged frame marks where that frame was cut short: its span
        // ends here (a CRC-failed frame is truncated, not corrupted in place), and this header starts a candidate
        // of its own.
        if (pos_ < damage_end_) {
            if (crc_pending_) {
                crc_pending_ = false;
                ++stats_.truncated;
            }
            damage_end_ = pos_;
        }
        const std::size_t total = frame_size(len);
        if (n - i < total) {  // need the rest of the frame
            if (!eos_) break;
            cut_short(pos_ + total);
            ++i;
            continue;
        }
        const std::uint32_t crc = wire::get_u32(p + kFrameHeaderBytes + len);
        if (crc != frame_crc({p + 2, kFrameHeaderBytes - 2 + len}, schema_hash(type))) {
            // Corrupt in place, or cut short with the next frame's bytes inside: decided once the scan passes
            // the end of this span (crc_errors) or finds a plausible header inside it (truncated).
            crc_pending_ = true;
            damage_end_ = pos_ + total;
            skip(1);
            ++i;
            continue;
        }
        const DecodeError e = decode_payload(type, {p + kFrameHeaderBytes, len}, out.message);
        if (e != DecodeError::None) {
            ++stats_.bad_payload;  // the CRC vouches for the boundaries: drop the whole frame
            skip(total);
            i += total;
            continue;
        }
        // A good frame.
        skipping_ = false;
        out.header = FrameHeader{p[2], type, wire::get_u16(p + 4), static_cast<std::uint16_t>(len)};
        if (have_seq_ && out.header.sequence != static_cast<std::uint16_t>(last_seq_ + 1)) ++stats_.sequence_gaps;
        have_seq_ = true;
        last_seq_ = out.header.sequence;
        ++stats_.frames;
        pos_ += total;
        used = i + total;
        return true;
    }
    used = i;
    return false;
}

void StreamParser::cut_short(std::uint64_t claimed_end) noexcept {
    // Counted once; false headers inside its claimed span (up to a plausible header) are not counted again.
    if (header_error_counted()) {
        ++stats_.truncated;
        damage_end_ = claimed_end;
    }
    skip(1);
}

void StreamParser::close() noexcept {
    if (crc_pending_) {
        crc_pending_ = false;
        ++stats_.crc_errors;
    }
    damage_end_ = 0;  // a new stream starts undamaged
    skipping_ = false;
    eos_ = false;
}

}  // namespace eyesim::protocol
