// Host session over a Transport: commands out, frames in, capture recording, ping/pong clock offset.
#include "eyesim/transport/device_link.hpp"

#include "eyesim/protocol/codec.hpp"

#include <chrono>

namespace eyesim::transport {

std::uint64_t host_now_us() {
    using namespace std::chrono;
    return static_cast<std::uint64_t>(duration_cast<microseconds>(steady_clock::now().time_since_epoch()).count());
}

DeviceLink::DeviceLink(std::unique_ptr<Transport> transport) : transport_(std::move(transport)) {}

DeviceLink::~DeviceLink() {
    if (recording_) {
        capture_.flush();
        capture_.close();
    }
}

void DeviceLink::record_to(const std::string& capture_path) {
    if (!capture_.create(capture_path.c_str())) throw TransportError(capture_path + ": cannot create capture file");
    capture_.set_flush_each(false);
    recording_ = true;
}

std::uint32_t DeviceLink::command(protocol::Opcode op, std::uint32_t address, std::uint32_t value) {
    protocol::Command c;
    c.command_id = next_id_++;
    c.opcode = static_cast<std::uint8_t>(op);
    c.address = address;
    c.value = value;
    c.host_us = host_now_us();
    if (op == protocol::Opcode::Ping) last_ping_id_ = c.command_id;
    const std::size_t n = protocol::encode_frame(protocol::Message{c}, tx_sequence_++, tx_);
    const IoResult r = transport_->write(std::span<const std::uint8_t>(tx_.data(), n), 1000);
    if (r.status != IoStatus::ok || r.bytes != n)
        throw TransportError(transport_->describe() + ": cannot send command: " +
                             (transport_->last_error().empty() ? "link closed" : transport_->last_error()));
    return c.command_id;
}

std::uint32_t DeviceLink::ping() { return command(protocol::Opcode::Ping); }

void DeviceLink::on_frame_internal(const protocol::DecodedFrame& f, std::uint64_t rx_us) {
    const auto* r = std::get_if<protocol::Reply>(&f.message);
    if (r && r->opcode == static_cast<std::uint8_t>(protocol::Opcode::Ping) && r->status == 0) {
        // The device stamps one time (execution) for receive and send alike.
        PingSample s;
        s.host_send_us = static_cast<std::int64_t>(r->host_us);
        s.device_rx_us = static_cast<std::int64_t>(r->device_us);
        s.device_tx_us = static_cast<std::int64_t>(r->device_us);
        s.host_recv_us = static_cast<std::int64_t>(rx_us);
        clock_.add(s);
    }
}

int DeviceLink::poll_impl(int timeout_ms, RawHandler handler, void* context) {
    int frames = 0;
    int wait = timeout_ms;
    for (int reads = 0; reads < 64; ++reads) {  // bounded: a busy stream still returns to the caller
        const IoResult r = transport_->read(rx_, wait);
        if (r.status == IoStatus::closed || r.status == IoStatus::error) return frames > 0 ? frames : -1;
        if (r.bytes == 0) return frames;
        const std::uint64_t rx_us = host_now_us();
        if (recording_) capture_.write(rx_us, std::span<const std::uint8_t>(rx_.data(), r.bytes));
        parser_.parse(std::span<const std::uint8_t>(rx_.data(), r.bytes), [&](const protocol::DecodedFrame& f) {
            on_frame_internal(f, rx_us);
            ++frames;
            handler(context, f);
        });
        wait = 0;  // drain what is already there, then return
    }
    return frames;
}

std::optional<protocol::Reply> DeviceLink::wait_reply(std::uint32_t command_id, int timeout_ms,
                                                      const FrameHandler& on_frame) {
    const std::uint64_t deadline = host_now_us() + static_cast<std::uint64_t>(timeout_ms) * 1000;
    std::optional<protocol::Reply> found;
    while (!found) {
        const std::uint64_t now = host_now_us();
        if (now >= deadline) break;
        const int n = poll(static_cast<int>((deadline - now) / 1000 + 1), [&](const protocol::DecodedFrame& f) {
            if (const auto* r = std::get_if<protocol::Reply>(&f.message); r && r->command_id == command_id) found = *r;
            if (on_frame) on_frame(f);
        });
        if (n < 0) break;
    }
    return found;
}

}  // namespace eyesim::transport
