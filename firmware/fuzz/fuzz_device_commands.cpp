// libFuzzer target: arbitrary host bytes into the firmware core while it streams. The core must never crash,
// hang or put an undecodable frame on the wire, and must answer every command frame it decoded exactly once.
#include "eyesim/firmware/device_core.hpp"
#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/stream_parser.hpp"

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <vector>

namespace {

using namespace eyesim;

/// A camera showing two coloured squares on grey, forever (one static field).
struct SquaresCamera final : firmware::CameraSource {
    std::vector<std::uint8_t> field = std::vector<std::uint8_t>(720 * 288 * 2);
    std::uint32_t counter = 0;
    int y = 0;
    SquaresCamera() {
        for (std::size_t i = 0; i < field.size(); i += 4) {
            field[i] = 128, field[i + 1] = 100, field[i + 2] = 128, field[i + 3] = 100;  // grey UYVY
        }
        for (int yy = 50; yy < 58; ++yy)
            for (int x = 100; x < 108; x += 2) {
                std::uint8_t* p = field.data() + (static_cast<std::size_t>(yy) * 720 + x) * 2;
                p[0] = 90, p[1] = 81, p[2] = 220, p[3] = 81;  // red (BT.601 studio swing)
            }
    }
    firmware::LineStatus next_line(firmware::CameraLine& out) noexcept override {
        if (y == 288) {
            y = 0;
            ++counter;
            return firmware::LineStatus::field_end;
        }
        out.uyvy = field.data() + static_cast<std::size_t>(y) * 1440;
        out.width_px = 720;
        out.line = static_cast<std::uint16_t>(y++);
        out.field = counter;
        out.parity = static_cast<std::uint8_t>(counter & 1);
        out.field_start_us = 20000ull * counter;
        return firmware::LineStatus::line;
    }
};

struct Clock final : firmware::Clock {
    std::uint64_t t = 0;
    std::uint64_t now_us() const noexcept override { return t; }
};

struct Sink final : firmware::ByteSink {
    protocol::StreamParser parser;
    std::uint64_t replies = 0;
    std::size_t write_some(const std::uint8_t* d, std::size_t n) noexcept override {
        parser.parse(std::span<const std::uint8_t>(d, n), [&](const protocol::DecodedFrame& f) {
            if (std::get_if<protocol::Reply>(&f.message)) ++replies;
        });
        return n;
    }
    bool connected() const noexcept override { return true; }
};

struct Source final : firmware::ByteSource {
    const std::uint8_t* data = nullptr;
    std::size_t left = 0;
    std::size_t read_some(std::uint8_t* out, std::size_t cap) noexcept override {
        // Deliver in uneven chunks so frames straddle reads.
        const std::size_t n = std::min({cap, left, std::size_t{37}});
        std::memcpy(out, data, n);
        data += n;
        left -= n;
        return n;
    }
};

}  // namespace

/// Structured mode: each 10 input bytes become one Command frame (opcode, address, value from the bytes), now
/// and then with one byte flipped, so the fuzzer reaches command execution without having to forge CRCs.
std::vector<std::uint8_t> commands_from(const std::uint8_t* d, std::size_t n) {
    std::vector<std::uint8_t> out;
    std::uint8_t frame[protocol::kMaxFrameBytes];
    std::uint16_t seq = 0;
    for (std::size_t i = 0; i + 10 <= n; i += 10) {
        protocol::Command c;
        c.command_id = static_cast<std::uint32_t>(i);
        c.opcode = static_cast<std::uint8_t>(d[i] % 8);
        c.address = static_cast<std::uint32_t>(d[i + 1] | (d[i + 2] << 8) | ((d[i + 3] & 0x1) << 16));
        std::memcpy(&c.value, d + i + 4, 4);
        const std::size_t len = protocol::encode_frame(protocol::Message{c}, seq++, frame);
        if ((d[i + 8] & 0x7) == 0 && len > 0) frame[d[i + 9] % len] ^= static_cast<std::uint8_t>(1u << (d[i + 8] >> 5));
        out.insert(out.end(), frame, frame + len);
    }
    return out;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* raw, std::size_t raw_size) {
    static SquaresCamera cams[3];
    if (raw_size == 0) return 0;
    std::vector<std::uint8_t> structured;
    const std::uint8_t* data = raw + 1;
    std::size_t size = raw_size - 1;
    if (raw[0] & 1) {
        structured = commands_from(data, size);
        data = structured.data();
        size = structured.size();
    }
    Clock clock;
    Sink sink;
    Source source;
    source.data = data;
    source.left = size;
    firmware::DeviceHal hal;
    for (int c = 0; c < 3; ++c) hal.cameras[c] = &cams[c];
    hal.sink = &sink;
    hal.source = &source;
    hal.clock = &clock;
    auto core = std::make_unique<firmware::DeviceCore>(hal);
    // Commands the device should see, decoded independently.
    protocol::StreamParser reference;
    std::uint64_t commands = 0;
    reference.parse(std::span<const std::uint8_t>(data, size), [&](const protocol::DecodedFrame& f) {
        if (std::get_if<protocol::Command>(&f.message)) ++commands;
    });
    for (int step = 0; step < 4000 && (source.left > 0 || !core->tx_idle()); ++step) {
        core->step_cameras();
        clock.t += 64;
        core->service();
    }
    for (int i = 0; i < 1000 && !core->tx_idle(); ++i) core->service();
    if (sink.parser.stats().errors() != 0) std::abort();  // the device put a bad frame on the wire
    if (core->queue_stats().dropped_packets == 0 && sink.replies != commands) std::abort();
    return 0;
}
