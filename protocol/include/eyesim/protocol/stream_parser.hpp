#pragma once
/// \file
/// Incremental stream parser: feed byte chunks of any size (USB bulk transfers, TCP reads, capture records) and
/// take out decoded frames. It resynchronises after garbage, bit flips, truncated frames and oversize lengths,
/// counts each kind of error, never allocates and never throws. A rejected candidate frame is skipped one byte at
/// a time, so an intact frame that starts inside garbage or inside a damaged frame is always found.

#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/frame.hpp"

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

namespace eyesim::protocol {

/// Error and traffic counters of a StreamParser (all since construction or reset()).
struct ParserStats {
    std::uint64_t bytes_in = 0;         ///< bytes fed
    std::uint64_t frames = 0;           ///< frames decoded and delivered
    std::uint64_t skipped_bytes = 0;    ///< bytes discarded: garbage and the bytes of rejected frames
    std::uint64_t resyncs = 0;          ///< runs of skipped bytes (each loss of sync counts once)
    std::uint64_t bad_version = 0;      ///< headers with an unknown protocol version
    std::uint64_t unknown_type = 0;     ///< headers with an unknown message type
    std::uint64_t bad_length = 0;       ///< headers with an oversize length or one invalid for the type
    std::uint64_t crc_errors = 0;       ///< full-length frames whose CRC failed (bit flips, other schema)
    std::uint64_t truncated = 0;        ///< frames cut short: the next frame began inside them, or the stream
                                        ///< ended inside them
    std::uint64_t bad_payload = 0;      ///< frames with a good CRC but a field out of range
    std::uint64_t sequence_gaps = 0;    ///< delivered frames whose sequence was not previous + 1

    /// Sum of the error counters (everything except bytes_in, frames, skipped_bytes, resyncs, sequence_gaps).
    std::uint64_t errors() const noexcept {
        return bad_version + unknown_type + bad_length + crc_errors + truncated + bad_payload;
    }
    friend bool operator==(const ParserStats&, const ParserStats&) = default;
};

/// The incremental parser. Holds at most kParserBufferBytes of undecided input.
class StreamParser {
public:
    /// Buffer capacity: two maximum frames.
    static constexpr std::size_t kParserBufferBytes = 2 * kMaxFrameBytes;

    /// Copies as many of `bytes` as fit into the buffer; returns how many were taken (call next() until it
    /// returns false, then feed the rest).
    std::size_t feed(std::span<const std::uint8_t> bytes) noexcept;

    /// Takes the next decoded frame out of the buffered bytes; false when more input is needed.
    bool next(DecodedFrame& out) noexcept;

    /// Feeds all of `bytes` and calls `on_frame(const DecodedFrame&)` for every frame completed. Frames lying
    /// wholly inside `bytes` are decoded in place (no copy).
    template <class F>
    void parse(std::span<const std::uint8_t> bytes, F&& on_frame) noexcept {
        DecodedFrame frame;
        // Drain the buffer first: it holds the start of a frame from earlier chunks.
        while (fill_ > 0 && !bytes.empty()) {
            const std::size_t n = feed(bytes);
            bytes = bytes.subspan(n);
            while (next(frame)) on_frame(static_cast<const DecodedFrame&>(frame));
        }
        // Then decode straight from the caller's bytes; only an unfinished tail is copied.
        while (!bytes.empty()) {
            std::size_t used = 0;
            const bool got = scan(bytes.data(), bytes.size(), used, frame);
            bytes_in_direct(used);
            bytes = bytes.subspan(used);
            if (got) {
                on_frame(static_cast<const DecodedFrame&>(frame));
            } else {
                feed(bytes);  // the undecided tail: shorter than one frame
                bytes = {};
            }
        }
        while (next(frame)) on_frame(static_cast<const DecodedFrame&>(frame));
    }

    /// Declares the end of the stream: frames still recoverable from the buffered bytes are delivered to
    /// `on_frame`, a candidate cut short by the end counts as truncated, the rest as skipped bytes. The parser
    /// is then ready for a new stream (counters kept).
    template <class F>
    void finish(F&& on_frame) noexcept {
        end_stream();
        DecodedFrame frame;
        while (next(frame)) on_frame(static_cast<const DecodedFrame&>(frame));
    }

    /// Pull-style finish: declares the end of the stream; then call next() until it returns false (the last
    /// false leaves the buffer empty and the counters final, as finish() does). Feed nothing in between.
    void end_stream() noexcept { eos_ = true; }

    /// The counters.
    const ParserStats& stats() const noexcept { return stats_; }

    /// Bytes buffered and not yet decided.
    std::size_t buffered() const noexcept { return fill_; }

    /// Drops buffered bytes and zeroes the counters.
    void reset() noexcept { *this = StreamParser{}; }

private:
    bool scan(const std::uint8_t* data, std::size_t n, std::size_t& used, DecodedFrame& out) noexcept;
    void skip(std::size_t n) noexcept;
    void bytes_in_direct(std::size_t n) noexcept;
    bool header_error_counted() const noexcept;
    void cut_short(std::uint64_t claimed_end) noexcept;
    void close() noexcept;

    std::array<std::uint8_t, kParserBufferBytes> buf_{};
    std::size_t fill_ = 0;          // bytes in buf_
    std::uint64_t pos_ = 0;         // stream offset of the next undecided byte
    bool skipping_ = false;         // inside a run of skipped bytes
    std::uint64_t damage_end_ = 0;  // stream offset just past the span of the last frame counted as damaged
                                    // (header errors before it are not counted again); cut back to where a
                                    // plausible header starts inside it
    bool crc_pending_ = false;      // that frame failed its CRC and awaits classification (crc vs truncated)
    bool eos_ = false;              // finishing: incomplete candidates are truncated, not awaited
    bool have_seq_ = false;
    std::uint16_t last_seq_ = 0;
    ParserStats stats_{};
};

}  // namespace eyesim::protocol
