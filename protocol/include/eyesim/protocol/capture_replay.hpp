#pragma once
/// \file
/// Replays a capture file (or raw stream) as decoded frames with their host receive times: a CaptureReader
/// feeding a StreamParser behind one pull call, for the host tracker and tools.

#include "eyesim/protocol/capture.hpp"
#include "eyesim/protocol/stream_parser.hpp"

#include <cstdint>
#include <span>

namespace eyesim::protocol {

/// Pull-style replay: `while (replay.next(frame, rx_us)) ...`. Holds ~36 KiB of buffers (allocate it, or keep
/// it off small stacks). No allocation per frame. The host's own commands (Sent records, capture version 2) are
/// a second byte stream with its own parser; the two-argument next() leaves them out.
class CaptureReplay {
public:
    /// Opens `path` (capture or raw stream); false when it cannot be opened (see CaptureReader::open).
    bool open(const char* path) noexcept;

    /// The next decoded frame and the receive time (µs) of the record that completed it (0 for raw streams);
    /// false at the end of the file (after a torn tail) or on a read error (see status()). Damaged stretches in
    /// the middle are skipped (reader().corrupt_regions()) and replay goes on after them.
    bool next(DecodedFrame& out, std::uint64_t& host_rx_us) noexcept;
    /// As next(out, host_rx_us), with the host's own commands as well, in file order: `sent` says which stream the
    /// frame is from (host_rx_us is then the host's send time).
    bool next(DecodedFrame& out, std::uint64_t& host_rx_us, bool& sent) noexcept;

    /// How reading ended: End, Torn or IoError (Ok while records remain).
    CaptureStatus status() const noexcept { return status_; }
    /// Capture or raw stream.
    CaptureKind kind() const noexcept { return reader_.kind(); }
    /// Records (or raw chunks) read so far.
    std::uint64_t records() const noexcept { return records_; }
    /// The reader (bad_offset(), dropped_bytes() after a torn tail; corrupt_regions(), corrupt_bytes()).
    const CaptureReader& reader() const noexcept { return reader_; }
    /// Parser counters of the received stream (final once next() returned false).
    const ParserStats& stats() const noexcept { return parser_.stats(); }
    /// Parser counters of the host's sent stream.
    const ParserStats& sent_stats() const noexcept { return sent_parser_.stats(); }
    /// Sent records read so far (included in records()).
    std::uint64_t sent_records() const noexcept { return sent_records_; }

private:
    CaptureReader reader_;
    StreamParser parser_, sent_parser_;
    std::span<const std::uint8_t> pending_, sent_pending_;
    std::uint64_t rx_us_ = 0, sent_us_ = 0;
    std::uint64_t records_ = 0, sent_records_ = 0;
    CaptureStatus status_ = CaptureStatus::Ok;
    bool ended_ = false;
};

}  // namespace eyesim::protocol
