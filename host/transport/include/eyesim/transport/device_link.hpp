#pragma once
/// \file
/// The host's session with one device over any Transport: sends commands, decodes the incoming byte stream into
/// frames (protocol StreamParser), records what it receives into a capture file if asked, and turns ping replies
/// into a device↔host clock offset.
///
/// \code
///   DeviceLink link(open_transport("tcp://127.0.0.1:7431"));   // or "usb", or make_inproc_pair()
///   link.record_to("run.capture");                               // optional
///   link.command(protocol::Opcode::StreamStart);
///   for (int i = 0; i < 8; ++i) link.ping();                     // clock offset (answers arrive in poll)
///   while (running) link.poll(10, [&](const protocol::DecodedFrame& f) { ... });
///   double host_us = link.clock().device_to_host_us(marker.complete_us);
/// \endcode

#include "eyesim/transport/clock_offset.hpp"
#include "eyesim/transport/transport.hpp"

#include "eyesim/protocol/capture.hpp"
#include "eyesim/protocol/frame.hpp"
#include "eyesim/protocol/messages.hpp"
#include "eyesim/protocol/stream_parser.hpp"

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <type_traits>

namespace eyesim::transport {

/// Host monotonic clock in µs (steady_clock), the time base of host_us fields and capture receive times.
std::uint64_t host_now_us();

/// One device session.
class DeviceLink {
public:
    /// Called for every decoded frame.
    using FrameHandler = std::function<void(const protocol::DecodedFrame&)>;

    /// Takes the transport.
    explicit DeviceLink(std::unique_ptr<Transport> transport);
    ~DeviceLink();
    DeviceLink(const DeviceLink&) = delete;
    DeviceLink& operator=(const DeviceLink&) = delete;

    /// Starts recording every received chunk (with its receive time) into a new capture file; throws
    /// TransportError when the file cannot be created.
    void record_to(const std::string& capture_path);

    /// Sends one command; returns its command_id. Throws TransportError when the link cannot take it.
    std::uint32_t command(protocol::Opcode op, std::uint32_t address = 0, std::uint32_t value = 0);
    /// Sends a ping stamped with host_now_us(); its reply updates clock().
    std::uint32_t ping();

    /// Reads what arrives within `timeout_ms` (0 = only what is there) and hands each frame to `on_frame`
    /// (any callable taking `const protocol::DecodedFrame&`; no allocation per call). Returns the number of
    /// frames, or -1 when the link closed or failed (see transport().last_error()).
    template <class F>
    int poll(int timeout_ms, F&& on_frame) {
        using Fn = std::remove_reference_t<F>;
        const RawHandler call = [](void* ctx, const protocol::DecodedFrame& f) { (*static_cast<Fn*>(ctx))(f); };
        return poll_impl(timeout_ms, call, const_cast<void*>(static_cast<const void*>(&on_frame)));
    }

    /// Polls until the Reply to `command_id` arrives (other frames go to `on_frame`) or `timeout_ms` passes.
    std::optional<protocol::Reply> wait_reply(std::uint32_t command_id, int timeout_ms,
                                              const FrameHandler& on_frame = {});

    /// Clock offset from the pongs received so far.
    const ClockOffsetEstimator& clock() const { return clock_; }
    /// Parser counters (errors, sequence gaps = frames lost on the device or the link).
    const protocol::ParserStats& stats() const { return parser_.stats(); }
    /// The transport.
    Transport& transport() { return *transport_; }

private:
    using RawHandler = void (*)(void* context, const protocol::DecodedFrame& frame);
    int poll_impl(int timeout_ms, RawHandler handler, void* context);
    void on_frame_internal(const protocol::DecodedFrame& f, std::uint64_t rx_us);

    std::unique_ptr<Transport> transport_;
    protocol::StreamParser parser_;
    protocol::CaptureWriter capture_;
    bool recording_ = false;
    std::array<std::uint8_t, 4096> rx_{};
    std::array<std::uint8_t, protocol::kMaxFrameBytes> tx_{};
    std::uint32_t next_id_ = 1;
    std::uint16_t tx_sequence_ = 0;
    std::uint32_t last_ping_id_ = 0;
    ClockOffsetEstimator clock_;
};

}  // namespace eyesim::transport
