#pragma once
/// \file
/// Bounded drop-oldest queue of whole packets. Packets are copied into one byte ring (wrapping) and described
/// by a ring of descriptors; when a new packet does not fit, the OLDEST whole packets are dropped and counted
/// until it does. Pushing never blocks and never allocates, so the pixel side never stalls on a slow host.

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>

namespace eyesim::firmware {

/// Outcome of PacketQueue::push.
enum class PushResult : std::uint8_t {
    queued,             ///< stored, nothing dropped
    queued_after_drop,  ///< stored after dropping one or more older packets
    rejected_too_large  ///< larger than the whole queue (or empty): not stored, counted as dropped
};

/// Counters of a PacketQueue since construction (or reset_stats()).
struct PacketQueueStats {
    std::uint64_t pushed_packets = 0;   ///< packets accepted by push
    std::uint64_t popped_packets = 0;   ///< packets taken out by pop
    std::uint64_t dropped_packets = 0;  ///< oldest packets dropped to make room, plus rejected ones
    std::uint64_t dropped_bytes = 0;    ///< bytes of those packets
    std::uint32_t high_water_bytes = 0;    ///< most bytes ever queued at once
    std::uint32_t high_water_packets = 0;  ///< most packets ever queued at once
};

/// A FIFO of at most `PacketCapacity` packets totalling at most `ByteCapacity` bytes. Each packet carries a
/// 32-bit tag chosen by the producer (the firmware uses it to follow a packet's latency record).
template <std::size_t ByteCapacity, std::size_t PacketCapacity>
class PacketQueue {
    static_assert(ByteCapacity > 0 && PacketCapacity > 0, "empty queue");
    static_assert(ByteCapacity < (std::size_t{1} << 31), "byte offsets are 32-bit");

public:
    /// Largest total of queued bytes.
    static constexpr std::size_t byte_capacity() noexcept { return ByteCapacity; }
    /// Largest number of queued packets.
    static constexpr std::size_t packet_capacity() noexcept { return PacketCapacity; }

    /// Copies `len` bytes in as one packet, dropping the oldest packets first when it would not fit.
    /// `on_drop(tag)` is called for each dropped packet (pass a no-op lambda when not needed).
    template <typename OnDrop>
    PushResult push(const std::uint8_t* data, std::size_t len, std::uint32_t tag, OnDrop&& on_drop) noexcept {
        if (len == 0 || len > ByteCapacity) {
            ++stats_.dropped_packets;
            stats_.dropped_bytes += len;
            on_drop(tag);
            return PushResult::rejected_too_large;
        }
        bool dropped = false;
        while (count_ == PacketCapacity || ByteCapacity - used_bytes_ < len) {
            const Descriptor& d = descs_[head_];
            ++stats_.dropped_packets;
            stats_.dropped_bytes += d.length;
            on_drop(d.tag);
            remove_head();
            dropped = true;
        }
        // Bytes live in [byte_head_, byte_head_ + used_bytes_) modulo ByteCapacity; append after them.
        const std::size_t start = (byte_head_ + used_bytes_) % ByteCapacity;
        const std::size_t first = len < ByteCapacity - start ? len : ByteCapacity - start;
        std::memcpy(bytes_.data() + start, data, first);
        if (first < len) std::memcpy(bytes_.data(), data + first, len - first);
        descs_[(head_ + count_) % PacketCapacity] = Descriptor{static_cast<std::uint32_t>(len), tag};
        ++count_;
        used_bytes_ += len;
        ++stats_.pushed_packets;
        if (used_bytes_ > stats_.high_water_bytes) stats_.high_water_bytes = static_cast<std::uint32_t>(used_bytes_);
        if (count_ > stats_.high_water_packets) stats_.high_water_packets = static_cast<std::uint32_t>(count_);
        return dropped ? PushResult::queued_after_drop : PushResult::queued;
    }

    /// push() without a drop callback.
    PushResult push(const std::uint8_t* data, std::size_t len, std::uint32_t tag = 0) noexcept {
        return push(data, len, tag, [](std::uint32_t) {});
    }

    /// True when no packet is queued.
    bool empty() const noexcept { return count_ == 0; }
    /// Number of queued packets.
    std::size_t packets() const noexcept { return count_; }
    /// Number of queued bytes.
    std::size_t bytes() const noexcept { return used_bytes_; }
    /// Size of the oldest packet (0 when empty).
    std::size_t front_size() const noexcept { return count_ ? descs_[head_].length : 0; }
    /// Tag of the oldest packet (0 when empty).
    std::uint32_t front_tag() const noexcept { return count_ ? descs_[head_].tag : 0; }

    /// Moves the oldest packet into `out` (capacity `cap`) and removes it; returns its size, or 0 when the queue
    /// is empty or `cap` is too small (then nothing is removed).
    std::size_t pop(std::uint8_t* out, std::size_t cap) noexcept {
        if (count_ == 0) return 0;
        const std::size_t len = descs_[head_].length;
        if (len > cap) return 0;
        const std::size_t first = len < ByteCapacity - byte_head_ ? len : ByteCapacity - byte_head_;
        std::memcpy(out, bytes_.data() + byte_head_, first);
        if (first < len) std::memcpy(out + first, bytes_.data(), len - first);
        remove_head();
        ++stats_.popped_packets;
        return len;
    }

    /// Drops every queued packet without counting them as dropped (stream stop, host reconnect).
    void clear() noexcept { head_ = count_ = byte_head_ = used_bytes_ = 0; }
    /// Counters so far.
    const PacketQueueStats& stats() const noexcept { return stats_; }
    /// Zeroes the counters.
    void reset_stats() noexcept { stats_ = PacketQueueStats{}; }

private:
    struct Descriptor {
        std::uint32_t length;
        std::uint32_t tag;
    };

    void remove_head() noexcept {
        const std::size_t len = descs_[head_].length;
        byte_head_ = (byte_head_ + len) % ByteCapacity;
        used_bytes_ -= len;
        head_ = (head_ + 1) % PacketCapacity;
        --count_;
        if (count_ == 0) byte_head_ = 0;  // keep packets contiguous when possible
    }

    std::array<std::uint8_t, ByteCapacity> bytes_{};
    std::array<Descriptor, PacketCapacity> descs_{};
    std::size_t head_ = 0;        // index of the oldest descriptor
    std::size_t count_ = 0;       // queued packets
    std::size_t byte_head_ = 0;   // offset of the oldest packet's first byte
    std::size_t used_bytes_ = 0;  // queued bytes
    PacketQueueStats stats_{};
};

}  // namespace eyesim::firmware
