#pragma once
/// \file
/// CameraSource of the PC build: fields come from a loader (recording file, synthetic renderer, memory), one
/// field buffer at a time, and are delivered line by line with PAL timing: field k of the stream starts at device
/// time epoch + k·20 000 µs and active line y ends at cycle active_line_end_cycle(y) of it (fpga/timing.hpp).
/// Each line's device time follows from its field's start (PAL timing model).

#include "eyesim/firmware/hal.hpp"
#include "eyesim/firmware/pc/modelled_clock.hpp"

#include <cstdint>
#include <functional>
#include <vector>

namespace eyesim::firmware::pc {

/// Loads field `index` (0-based) of a stream into `uyvy` (720×288×2 bytes) and sets its parity; returns false
/// when the stream has no field `index` (end of stream). `start_us` comes in as epoch + index·20 000 µs (the
/// genlocked PAL default) and may be changed (camera clock offsets, half-line offset of bottom fields).
using FieldLoader =
    std::function<bool(std::uint64_t index, std::uint8_t* uyvy, std::uint8_t& parity, std::uint64_t& start_us)>;

/// A camera's field stream with PAL timing (each line's time follows from its field's start; the core tells a
/// ModelledClock when it has run a line: Clock::line_run_us).
class FieldSource final : public CameraSource {
public:
    /// `lines` active lines of 720 px per field (288 for PAL); `epoch_us` is the device time of field 0's start.
    explicit FieldSource(FieldLoader loader, std::uint64_t epoch_us = 0, int lines = 288);

    /// The next line of the current field, its field end, or the end of the stream (loader returned false).
    LineStatus next_line(CameraLine& out) noexcept override;

    /// Fields delivered completely so far.
    std::uint64_t fields_delivered() const noexcept { return fields_done_; }
    /// Default device time at which field `k` of this stream starts (before the loader's adjustment), µs.
    std::uint64_t field_start_us(std::uint64_t k) const noexcept;

private:
    FieldLoader loader_;
    std::uint64_t epoch_us_;
    int lines_;
    std::vector<std::uint8_t> field_;  // one field, allocated at construction
    std::uint64_t index_ = 0;          // field being delivered
    int next_y_ = 0;                   // next line of it; lines_ = field end pending; -1 = load needed
    std::uint8_t parity_ = 0;
    std::uint64_t start_us_ = 0;       // device time of the loaded field's start
    bool ended_ = false;
    std::uint64_t fields_done_ = 0;
};

}  // namespace eyesim::firmware::pc
