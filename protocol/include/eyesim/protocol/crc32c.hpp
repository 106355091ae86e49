#pragma once
/// \file
/// CRC-32C (Castagnoli), the frame and capture-record checksum: width 32, poly 0x1EDC6F41 (reflected 0x82F63B78),
/// init 0xFFFFFFFF, refin/refout true, xorout 0xFFFFFFFF; catalogue check value for "123456789" is 0xE3069283.

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>

namespace eyesim::protocol {

/// CRC-32C catalogue check value: crc32c("123456789").
inline constexpr std::uint32_t kCrc32cCheck = 0xE3069283u;
/// Initial CRC register value.
inline constexpr std::uint32_t kCrc32cInit = 0xFFFFFFFFu;

namespace detail {
/// Byte-wise lookup table of the reflected polynomial 0x82F63B78.
inline constexpr std::array<std::uint32_t, 256> kCrc32cTable = [] {
    std::array<std::uint32_t, 256> t{};
    for (std::uint32_t i = 0; i < 256; ++i) {
        std::uint32_t c = i;
        for (int k = 0; k < 8; ++k) c = (c & 1u) ? (c >> 1) ^ 0x82F63B78u : c >> 1;
        t[i] = c;
    }
    return t;
}();
}  // namespace detail

/// Feeds bytes into a running CRC-32C register (start from kCrc32cInit, finish with crc32c_finish).
std::uint32_t crc32c_update(std::uint32_t reg, std::span<const std::uint8_t> bytes) noexcept;

/// Final XOR of the CRC-32C register.
constexpr std::uint32_t crc32c_finish(std::uint32_t reg) noexcept { return reg ^ 0xFFFFFFFFu; }

/// CRC-32C of a byte range.
inline std::uint32_t crc32c(std::span<const std::uint8_t> bytes) noexcept {
    return crc32c_finish(crc32c_update(kCrc32cInit, bytes));
}

/// CRC-32C of a string, usable at compile time (schema hashes).
constexpr std::uint32_t crc32c(std::string_view s) noexcept {
    std::uint32_t reg = kCrc32cInit;
    for (char ch : s) reg = detail::kCrc32cTable[(reg ^ static_cast<std::uint8_t>(ch)) & 0xFFu] ^ (reg >> 8);
    return crc32c_finish(reg);
}

}  // namespace eyesim::protocol
