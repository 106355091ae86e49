// Recorded pedal track played on the device clock.
#include "eyesim/firmware/pc/pedal_track.hpp"

#include <algorithm>
#include <cmath>

namespace eyesim::firmware::pc {

namespace {
std::uint16_t counts(double unit) noexcept {
    if (!(unit > 0.0)) return 0;  // also NaN
    if (unit >= 1.0) return 0xFFFF;
    return static_cast<std::uint16_t>(std::lround(unit * 65535.0));
}
}  // namespace

PedalReading to_reading(const PedalSample& s) noexcept {
    PedalReading r;
    r.axes[0] = counts(s.axes[0]);
    r.axes[1] = counts(0.5 * (s.axes[1] + 1.0));
    r.axes[2] = counts(0.5 * (s.axes[2] + 1.0));
    r.buttons = s.buttons;
    return r;
}

PedalTrack::PedalTrack(std::vector<PedalSample> samples, const Clock* clock)
    : samples_(std::move(samples)), clock_(clock) {}

PedalReading PedalTrack::read() const noexcept {
    const double t = clock_ ? static_cast<double>(clock_->now_us()) - static_cast<double>(epoch_us_) : 0.0;
    return at(t);
}

PedalReading PedalTrack::at(double t_us) const noexcept {
    if (samples_.empty()) {
        PedalSample rest;
        return to_reading(rest);
    }
    if (t_us <= samples_.front().t_us) return to_reading(samples_.front());
    if (t_us >= samples_.back().t_us) return to_reading(samples_.back());
    // Interval [i, i+1] holding t: from the last one forward (playback), else by bisection.
    std::size_t i = hint_ < samples_.size() - 1 && samples_[hint_].t_us <= t_us ? hint_ : 0;
    if (i + 1 < samples_.size() && samples_[i + 1].t_us <= t_us) {
        if (i + 2 < samples_.size() && samples_[i + 2].t_us > t_us) {
            ++i;
        } else {
            const auto it = std::upper_bound(samples_.begin(), samples_.end(), t_us,
                                             [](double t, const PedalSample& s) { return t < s.t_us; });
            i = static_cast<std::size_t>(it - samples_.begin()) - 1;
        }
    }
    hint_ = i;
    const PedalSample& a = samples_[i];
    const PedalSample& b = samples_[i + 1];
    const double u = b.t_us > a.t_us ? (t_us - a.t_us) / (b.t_us - a.t_us) : 0.0;
    PedalSample s = a;
    for (int k = 0; k < 3; ++k) s.axes[k] = a.axes[k] + u * (b.axes[k] - a.axes[k]);
    return to_reading(s);
}

protocol::PedalState PedalTrack::message_at(double t_us, std::uint64_t device_us) const noexcept {
    const PedalReading r = at(t_us);
    protocol::PedalState m;
    m.device_us = device_us;
    for (std::size_t a = 0; a < protocol::kPedalAxisCount; ++a) m.axes[a] = r.axes[a];
    m.buttons = r.buttons;
    return m;
}

}  // namespace eyesim::firmware::pc
