#pragma once
// Fake transport for the firmware core: a byte sink that records what it is given (with an optional per-call
// budget to model a slow host) and a byte source fed by the test.
#include "eyesim/firmware/hal.hpp"
#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/stream_parser.hpp"

#include <algorithm>
#include <cstdint>
#include <deque>
#include <vector>

namespace eyesim::test {

struct MemorySink final : firmware::ByteSink {
    std::vector<std::uint8_t> bytes;
    std::size_t budget_per_call = SIZE_MAX;  // bytes accepted per write_some call
    bool link_up = true;
    std::size_t write_some(const std::uint8_t* data, std::size_t len) noexcept override {
        const std::size_t n = std::min(len, budget_per_call);
        bytes.insert(bytes.end(), data, data + n);
        return n;
    }
    bool connected() const noexcept override { return link_up; }
};

struct QueueSource final : firmware::ByteSource {
    std::deque<std::uint8_t> pending;
    void push(const std::vector<std::uint8_t>& b) { pending.insert(pending.end(), b.begin(), b.end()); }
    std::size_t read_some(std::uint8_t* out, std::size_t cap) noexcept override {
        const std::size_t n = std::min(cap, pending.size());
        for (std::size_t i = 0; i < n; ++i) out[i] = pending[i];
        pending.erase(pending.begin(), pending.begin() + static_cast<std::ptrdiff_t>(n));
        return n;
    }
};

inline std::vector<std::uint8_t> command_frame(const protocol::Command& c, std::uint16_t seq = 0) {
    std::vector<std::uint8_t> f(protocol::kMaxFrameBytes);
    f.resize(protocol::encode_frame(protocol::Message{c}, seq, f));
    return f;
}

inline std::vector<protocol::DecodedFrame> decode_all(const std::vector<std::uint8_t>& bytes,
                                                       protocol::ParserStats* stats = nullptr) {
    std::vector<protocol::DecodedFrame> out;
    protocol::StreamParser parser;
    parser.parse(bytes, [&](const protocol::DecodedFrame& f) { out.push_back(f); });
    parser.finish([&](const protocol::DecodedFrame& f) { out.push_back(f); });
    if (stats) *stats = parser.stats();
    return out;
}

}  // namespace eyesim::test
