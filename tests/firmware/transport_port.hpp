#pragma once
/// Device side of an in-process link for tests: the firmware core's ByteSink/ByteSource over one end of a
/// transport (never waiting).

#include "eyesim/firmware/hal.hpp"
#include "eyesim/transport/transport.hpp"

#include <cstddef>
#include <cstdint>
#include <span>

namespace eyesim::test {

struct TransportPort final : firmware::ByteSink, firmware::ByteSource {
    transport::Transport* t = nullptr;
    std::size_t write_some(const std::uint8_t* d, std::size_t n) noexcept override {
        return t->write(std::span<const std::uint8_t>(d, n), 0).bytes;
    }
    bool connected() const noexcept override { return t->connected(); }
    std::size_t read_some(std::uint8_t* out, std::size_t cap) noexcept override {
        return t->read(std::span<std::uint8_t>(out, cap), 0).bytes;
    }
};

}  // namespace eyesim::test
