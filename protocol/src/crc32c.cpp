#include "eyesim/protocol/crc32c.hpp"

namespace eyesim::protocol {

std::uint32_t crc32c_update(std::uint32_t reg, std::span<const std::uint8_t> bytes) noexcept {
    for (const std::uint8_t b : bytes) reg = detail::kCrc32cTable[(reg ^ b) & 0xFFu] ^ (reg >> 8);
    return reg;
}

}  // namespace eyesim::protocol
