#include "eyesim/protocol/crc32c.hpp"

namespace eyesim::protocol {

namespace {

// Slicing-by-8 tables: kSlice[k][b] is the CRC register contribution of byte b followed by k zero bytes.
// 8 KiB of constants (flash on the device), computed at compile time.
constexpr std::array<std::array<std::uint32_t, 256>, 8> kSlice = [] {
    std::array<std::array<std::uint32_t, 256>, 8> t{};
    t[0] = detail::kCrc32cTable;
    for (std::size_t k = 1; k < 8; ++k)
        for (std::size_t b = 0; b < 256; ++b) t[k][b] = (t[k - 1][b] >> 8) ^ t[0][t[k - 1][b] & 0xFFu];
    return t;
}();

}  // namespace

std::uint32_t crc32c_update(std::uint32_t reg, std::span<const std::uint8_t> bytes) noexcept {
    const std::uint8_t* p = bytes.data();
    std::size_t n = bytes.size();
    // Eight bytes per step (assembled byte by byte: endian- and alignment-independent).
    while (n >= 8) {
        const std::uint32_t lo = reg ^ (static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
                                        (static_cast<std::uint32_t>(p[2]) << 16) |
                                        (static_cast<std::uint32_t>(p[3]) << 24));
        reg = kSlice[7][lo & 0xFFu] ^ kSlice[6][(lo >> 8) & 0xFFu] ^ kSlice[5][(lo >> 16) & 0xFFu] ^
              kSlice[4][lo >> 24] ^ kSlice[3][p[4]] ^ kSlice[2][p[5]] ^ kSlice[1][p[6]] ^ kSlice[0][p[7]];
        p += 8;
        n -= 8;
    }
    while (n-- > 0) reg = detail::kCrc32cTable[(reg ^ *p++) & 0xFFu] ^ (reg >> 8);
    return reg;
}

}  // namespace eyesim::protocol
