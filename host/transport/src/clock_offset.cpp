// NTP-style clock offset: minimum-delay sample of a sliding window.
#include "eyesim/transport/clock_offset.hpp"

namespace eyesim::transport {

double ping_offset_us(const PingSample& s) {
    return 0.5 * (static_cast<double>(s.device_rx_us - s.host_send_us) +
                  static_cast<double>(s.device_tx_us - s.host_recv_us));
}

double ping_delay_us(const PingSample& s) {
    return static_cast<double>(s.host_recv_us - s.host_send_us) - static_cast<double>(s.device_tx_us - s.device_rx_us);
}

bool ClockOffsetEstimator::add(const PingSample& s) {
    if (s.host_recv_us < s.host_send_us || s.device_tx_us < s.device_rx_us || ping_delay_us(s) < 0) return false;
    window_[next_] = s;
    next_ = (next_ + 1) % kWindow;
    if (count_ < kWindow) ++count_;
    ++total_;
    return true;
}

const PingSample* ClockOffsetEstimator::best() const {
    const PingSample* b = nullptr;
    for (std::size_t i = 0; i < count_; ++i)
        if (!b || ping_delay_us(window_[i]) < ping_delay_us(*b)) b = &window_[i];
    return b;
}

double ClockOffsetEstimator::offset_us() const {
    const PingSample* b = best();
    return b ? ping_offset_us(*b) : 0.0;
}

double ClockOffsetEstimator::delay_us() const {
    const PingSample* b = best();
    return b ? ping_delay_us(*b) : 0.0;
}

}  // namespace eyesim::transport
