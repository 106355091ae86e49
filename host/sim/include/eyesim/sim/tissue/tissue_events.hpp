#pragma once
/// \file
/// Warnings and damage reported by a tissue step, in a fixed-capacity list (no allocation per step).

#include <array>
#include <cstddef>
#include <cstdint>

namespace eyesim::sim::tissue {

/// Kind of a tissue event.
enum class TissueEventKind : uint8_t {
    kLiftOff = 0,        ///< force on a fixed rim node exceeded the lift-off limit (node, value = force nN)
    kTearWarning = 1,    ///< injection needle moved along the retina too fast (node = kNoIndex, value = mm/s)
    kSpringTorn = 2,     ///< tearing rule deleted a spring (node = overloaded node, other = other end,
                         ///< value = acceleration mm/s²)
    kTissueRemoved = 3,  ///< cutting removed tissue (node = first node cut, other = nodes removed,
                         ///< value = triangle area removed, mm²)
};

/// One event. `node`/`other` are vertex indices or 0xffffffff.
struct TissueEvent {
    TissueEventKind kind;  ///< what happened
    uint32_t node;         ///< node concerned
    uint32_t other;        ///< second node (torn spring), else 0xffffffff
    float value;           ///< kind-dependent magnitude (see TissueEventKind)
};

/// Events of one step call, fixed capacity; further events are counted in `dropped`.
/// Lift-off and tear warnings are merged: at most one of each per step call, holding the largest value.
class TissueEventList {
public:
    /// Capacity of the list.
    static constexpr size_t kCapacity = 128;

    /// Forgets all events.
    void clear() { size_ = 0; dropped_ = 0; }
    /// Appends an event, or counts it as dropped when full.
    void push(const TissueEvent& e) {
        if (size_ < kCapacity) events_[size_++] = e;
        else ++dropped_;
    }
    /// Keeps one event of `e.kind`: appended if none yet, else replaced when `e.value` is larger.
    void merge_max(const TissueEvent& e) {
        for (size_t i = 0; i < size_; ++i)
            if (events_[i].kind == e.kind) {
                if (e.value > events_[i].value) events_[i] = e;
                return;
            }
        push(e);
    }
    /// Number of stored events.
    size_t size() const { return size_; }
    /// Events that did not fit.
    size_t dropped() const { return dropped_; }
    /// Event i (i < size()).
    const TissueEvent& operator[](size_t i) const { return events_[i]; }
    /// Number of stored events of one kind.
    size_t count(TissueEventKind k) const {
        size_t n = 0;
        for (size_t i = 0; i < size_; ++i) n += events_[i].kind == k;
        return n;
    }
    /// Iteration.
    const TissueEvent* begin() const { return events_.data(); }
    /// Iteration.
    const TissueEvent* end() const { return events_.data() + size_; }

private:
    std::array<TissueEvent, kCapacity> events_{};
    size_t size_ = 0;
    size_t dropped_ = 0;
};

}  // namespace eyesim::sim::tissue
