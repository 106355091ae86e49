#pragma once
/// \file
/// Device clock of the PC build: modelled time that the camera sources advance with the PAL pixel clock, so
/// every timestamp the core produces is deterministic (independent of the PC's speed and load).

#include "eyesim/firmware/hal.hpp"

#include <cstdint>

namespace eyesim::firmware::pc {

/// A Clock whose time is set by the simulation, never by the wall clock. Monotonic: advance_to never goes back.
class ModelledClock final : public Clock {
public:
    /// Current modelled device time, µs.
    std::uint64_t now_us() const noexcept override { return now_us_; }
    /// Moves time forward to `t_us` (no effect when `t_us` is in the past).
    void advance_to(std::uint64_t t_us) noexcept {
        if (t_us > now_us_) now_us_ = t_us;
    }
    /// Follows the lines the core runs (PAL pixel clock).
    void line_run_us(std::uint64_t t_us) noexcept override { advance_to(t_us); }

private:
    std::uint64_t now_us_ = 0;
};

}  // namespace eyesim::firmware::pc
