#pragma once
/// \file
/// Device↔host clock offset from ping/pong exchanges (the NTP estimate). For one exchange the host sends at
/// t0 (host clock), the device receives at t1 and replies at t2 (device clock), the host receives at t3:
///   offset = ((t1 - t0) + (t2 - t3)) / 2   (device minus host)
///   delay  = (t3 - t0) - (t2 - t1)         (round trip spent on the link)
/// The estimate with the smallest delay is the tightest (its error is at most delay/2), so the estimator keeps
/// the minimum-delay sample of a sliding window.

#include <array>
#include <cstddef>
#include <cstdint>

namespace eyesim::transport {

/// One ping/pong exchange, all in µs.
struct PingSample {
    std::int64_t host_send_us = 0;    ///< t0: host clock when the ping left
    std::int64_t device_rx_us = 0;    ///< t1: device clock when the ping arrived
    std::int64_t device_tx_us = 0;    ///< t2: device clock when the pong left
    std::int64_t host_recv_us = 0;    ///< t3: host clock when the pong arrived
};

/// Offset (device − host, µs) of one exchange.
double ping_offset_us(const PingSample& s);
/// Link round-trip delay (µs) of one exchange, device processing excluded.
double ping_delay_us(const PingSample& s);

/// Keeps the last `kWindow` exchanges and answers with the offset of the one with the smallest delay.
class ClockOffsetEstimator {
public:
    /// Exchanges remembered.
    static constexpr std::size_t kWindow = 16;

    /// Adds one exchange; samples with a negative delay (clock went backwards, corrupt pong) are refused.
    bool add(const PingSample& s);
    /// True once at least one sample was accepted.
    bool valid() const { return count_ > 0; }
    /// Best offset (device − host), µs; 0 before the first sample.
    double offset_us() const;
    /// Round-trip delay of the sample the offset comes from; bounds its error to ± delay/2.
    double delay_us() const;
    /// Device time → host time with the current offset.
    double device_to_host_us(double device_us) const { return device_us - offset_us(); }
    /// Host time → device time with the current offset.
    double host_to_device_us(double host_us) const { return host_us + offset_us(); }
    /// Accepted samples so far (also those that left the window).
    std::size_t samples() const { return total_; }

private:
    const PingSample* best() const;
    std::array<PingSample, kWindow> window_{};
    std::size_t next_ = 0;
    std::size_t count_ = 0;
    std::size_t total_ = 0;
};

}  // namespace eyesim::transport
