#pragma once
/// \file
/// PedalInput of the PC build: a recorded pedal track (from a recording's truth.jsonl or a rig scenario) played
/// on the device clock. The track is on the recording's clock; `epoch_us` is the device time of its 0.

#include "eyesim/firmware/hal.hpp"
#include "eyesim/protocol/messages.hpp"

#include <algorithm>
#include <array>
#include <cstdint>
#include <vector>

namespace eyesim::firmware::pc {

/// One pedal sample of a track, on the recording's clock.
struct PedalSample {
    double t_us = 0.0;                 ///< recording time
    std::array<double, 3> axes{};      ///< axis 0: 0 released .. 1 full travel; axes 1, 2: joystick −1 .. 1
    std::uint16_t buttons = 0;
};

/// A sample from a pedal record (the rig's PedalTruth or anything with `axes` [3] and `buttons`).
template <class Pedal>
PedalSample pedal_sample(double t_us, const Pedal& pedal) {
    return {t_us, {pedal.axes[0], pedal.axes[1], pedal.axes[2]}, static_cast<std::uint16_t>(pedal.buttons & 0xFFFFu)};
}

/// The pedal track of a recording's per-field truth records (anything with `t_us` and `pedal`), sorted by time.
template <class Records>
std::vector<PedalSample> pedal_track_of(const Records& records) {
    std::vector<PedalSample> track;
    for (const auto& r : records) track.push_back(pedal_sample(r.t_us, r.pedal));
    std::sort(track.begin(), track.end(), [](const PedalSample& a, const PedalSample& b) { return a.t_us < b.t_us; });
    return track;
}

/// Converts a sample's axes to PedalState counts (axis 0: 0..65535; joystick axes: −1..1 → 0..65535).
PedalReading to_reading(const PedalSample& s) noexcept;

/// Plays a track: axes interpolated linearly between samples, buttons held from the last sample; before the first
/// and after the last sample the pedal holds that sample. An empty track is a pedal at rest (released, centred).
class PedalTrack final : public PedalInput {
public:
    /// `samples` sorted by time (built at start-up; read() never allocates).
    PedalTrack(std::vector<PedalSample> samples, const Clock* clock);
    /// Device time of the track's t = 0 (the player moves it when playback starts or resumes).
    void set_epoch_us(std::uint64_t epoch_us) noexcept { epoch_us_ = epoch_us; }
    /// The pedal at device time clock->now_us().
    PedalReading read() const noexcept override;
    /// The pedal at recording time t_us.
    PedalReading at(double t_us) const noexcept;
    /// The PedalState a device sends for recording time t_us, stamped `device_us`.
    protocol::PedalState message_at(double t_us, std::uint64_t device_us) const noexcept;
    /// Samples in the track.
    std::size_t size() const noexcept { return samples_.size(); }

private:
    std::vector<PedalSample> samples_;
    const Clock* clock_;
    std::uint64_t epoch_us_ = 0;
    mutable std::size_t hint_ = 0;  // last interval used: reads move forward in time
};

}  // namespace eyesim::firmware::pc
