#pragma once
/// \file
/// Modelled device latency of each blob: last pixel on the wire → blob leaves the FPGA pipeline → its frame is in
/// the transmit queue → the frame's last byte has left on the link. All times are device time in nanoseconds
/// (the PAL pixel clock model gives pixel-exact times; 1 µs would hide the interesting part).
///
/// The firmware costs are those of a 100 MHz soft core next to the FPGA; the link is USB 2.0 high-speed bulk.
/// Both are models with their constants here and in docs/firmware.md, not measurements of hardware.

#include <cstdint>

namespace eyesim::firmware {

/// Soft-core clock the firmware costs are counted in.
inline constexpr std::uint64_t kCoreClockHz = 100'000'000;
/// Cycles to take one blob from the FPGA FIFO, convert it and append it to a frame.
inline constexpr std::uint64_t kBlobHandleCycles = 150;
/// Cycles to close a frame: header, CRC-32C (table driven, ~4 cycles/byte over ≤ 512 bytes), queue copy.
inline constexpr std::uint64_t kFrameBaseCycles = 250;
/// Extra cycles per frame byte (CRC and copy into the queue).
inline constexpr std::uint64_t kFrameCyclesPerByte = 6;
/// Modelled link throughput: USB 2.0 high-speed bulk, 40 MB/s sustained (theory: 53 MB/s).
inline constexpr std::uint64_t kLinkBytesPerSecond = 40'000'000;
/// Modelled fixed cost of one bulk transfer on the link (token, handshake, host scheduling), ns.
inline constexpr std::uint64_t kLinkTransferOverheadNs = 2'000;

/// Soft-core cycles → ns.
constexpr std::uint64_t core_cycles_to_ns(std::uint64_t cycles) { return cycles * 1'000'000'000ull / kCoreClockHz; }

/// Modelled cost of encoding and queueing one frame of `frame_bytes` carrying `blobs` blobs, ns.
constexpr std::uint64_t frame_cost_ns(std::uint64_t frame_bytes, std::uint64_t blobs) {
    return core_cycles_to_ns(kFrameBaseCycles + kFrameCyclesPerByte * frame_bytes + kBlobHandleCycles * blobs);
}

/// Modelled time on the link for one frame of `frame_bytes`, ns.
constexpr std::uint64_t link_time_ns(std::uint64_t frame_bytes) {
    return kLinkTransferOverheadNs + frame_bytes * 1'000'000'000ull / kLinkBytesPerSecond;
}

/// The link as a single server: frames leave in queue order, one after the other.
class LinkModel {
public:
    /// A frame queued at `queued_ns` leaves completely at the returned time.
    std::uint64_t transmit(std::uint64_t queued_ns, std::uint64_t frame_bytes) noexcept {
        const std::uint64_t start = queued_ns > free_at_ns_ ? queued_ns : free_at_ns_;
        free_at_ns_ = start + link_time_ns(frame_bytes);
        return free_at_ns_;
    }
    /// Time the link becomes idle.
    std::uint64_t free_at_ns() const noexcept { return free_at_ns_; }
    /// Forgets the backlog (stream restart).
    void reset() noexcept { free_at_ns_ = 0; }

private:
    std::uint64_t free_at_ns_ = 0;
};

/// One blob's modelled path through the device.
struct BlobLatency {
    std::uint8_t camera = 0;            ///< camera id
    std::uint8_t low_latency = 0;       ///< 1 when sent in low-latency (per-blob) mode
    std::uint16_t blob_index = 0;       ///< emission order in the field
    std::uint32_t field_counter = 0;    ///< field of the blob
    std::uint64_t last_pixel_ns = 0;    ///< device time of the blob's last pixel on the wire
    std::uint64_t complete_ns = 0;      ///< the pipeline emitted the blob
    std::uint64_t queued_ns = 0;        ///< its frame was encoded and in the transmit queue
    std::uint64_t written_ns = 0;       ///< the frame's last byte left on the link

    /// Last pixel → bytes written, ns.
    std::uint64_t total_ns() const noexcept { return written_ns - last_pixel_ns; }
};

/// Receives one BlobLatency per sent blob (optional; the PC build collects them for reports and benchmarks).
class LatencyObserver {
public:
    virtual ~LatencyObserver() = default;
    /// Called once per blob when its frame is queued (all times are known then: the link is modelled).
    virtual void on_blob(const BlobLatency& record) noexcept = 0;
};

}  // namespace eyesim::firmware
