#pragma once
/// \file
/// What a run lost, counted from what it received: every decoded frame's sequence number (frames lost on the
/// device or the link, repeated, or late), every FieldMarkers' field counter (fields of which no part arrived,
/// fields out of order), the device's own DeviceStatus counters (transmit-queue overflows, dropped blobs) and
/// the stream parser's (resyncs, damaged frames). One object per stream; allocation-free, fixed size.

#include "eyesim/protocol/frame.hpp"
#include "eyesim/protocol/stream_parser.hpp"

#include <array>
#include <cstdint>
#include <string>

namespace eyesim::frame {

/// The counters of one stream (see LossCounter).
struct LossCounts {
    std::uint64_t frames = 0;                  ///< frames delivered by the parser
    std::uint64_t sequence_gaps = 0;           ///< frames whose sequence ≠ previous + 1 (docs/protocol.md §5)
    std::uint64_t frames_lost = 0;             ///< sequence numbers never received (device queue or link)
    std::uint64_t frames_repeated = 0;         ///< frames whose sequence number had already arrived
    std::uint64_t frames_late = 0;             ///< frames that arrived after a later sequence number
    std::uint64_t fields_lost = 0;             ///< camera fields of which no part arrived (field counter gaps)
    std::uint64_t fields_out_of_order = 0;     ///< camera fields older than one already received
    std::uint64_t time_jumps = 0;              ///< device time went back by more than kTimeJumpUs (new segment)
    std::uint64_t resyncs = 0;                 ///< parser: runs of skipped bytes
    std::uint64_t skipped_bytes = 0;           ///< parser: bytes not in any delivered frame
    std::uint64_t parse_errors = 0;            ///< parser: damaged frames (ParserStats::errors())
    std::uint64_t device_queue_overflows = 0;  ///< device: frames its transmit queue dropped during the run
    std::uint64_t device_blobs_dropped = 0;    ///< device: blobs found but not sent during the run
    std::uint64_t link_drops = 0;              ///< the link went away and came back (USB unplug)

    /// True when anything was lost, damaged, repeated or out of order.
    bool any() const noexcept;
};

/// A backward step of device time larger than this is a new stream segment (the device restarted, two captures
/// were joined or their halves swapped): five field periods, more than the tracker keeps, so no field that old
/// could be used as a late packet anyway.
inline constexpr double kTimeJumpUs = 100000.0;

/// Counts losses of one device → host stream.
class LossCounter {
public:
    /// Sequence numbers remembered for telling late and repeated frames from lost ones.
    static constexpr int kWindow = 1024;

    /// One delivered frame.
    void observe(const protocol::DecodedFrame& f) noexcept;
    /// The parser's counters at the end of (or during) the stream.
    void set_parser(const protocol::ParserStats& s) noexcept;
    /// A backward time step the tracker handled as a new segment.
    void add_time_jump() noexcept { ++counts_.time_jumps; }
    /// The link dropped and reconnected; sequence numbers and field counters restart.
    void link_dropped() noexcept;
    /// The counters so far.
    const LossCounts& counts() const noexcept { return counts_; }

private:
    bool seen(std::uint16_t seq) const noexcept;
    void mark(std::uint16_t seq, bool on) noexcept;

    LossCounts counts_{};
    bool have_seq_ = false;
    std::uint16_t last_seq_ = 0;      // previous frame's (sequence_gaps, as the parser counts them)
    std::uint16_t highest_seq_ = 0;   // newest sequence number received (modulo 2^16)
    std::array<std::uint64_t, kWindow / 64> window_{};  // bit k: highest − k received
    std::array<bool, protocol::kCameraCount> have_field_{};
    std::array<std::uint32_t, protocol::kCameraCount> highest_field_{};
    bool have_status_ = false;
    std::uint32_t first_overflows_ = 0, first_blobs_dropped_ = 0;
};

/// One line naming every non-zero loss counter ("7 frames lost (sequence gaps 3), 2 resyncs, …"); empty when
/// nothing was lost.
std::string loss_summary(const LossCounts& c);

}  // namespace eyesim::frame
