#pragma once
// The slow reference the stream parser is checked against, shared by the parser tests and the fuzz target: at
// every offset try to decode a whole frame; take it, skip a frame whose CRC held but whose payload did not
// decode, or move on by one byte.

#include "eyesim/protocol/codec.hpp"

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace eyesim::protocol::test {

/// One frame as a parser delivers it.
struct Got {
    std::uint16_t seq;
    Message msg;
    bool operator==(const Got& o) const { return seq == o.seq && msg == o.msg; }
};

/// Every frame a byte-by-byte scan of `bytes` finds, in order.
inline std::vector<Got> brute_force(std::span<const std::uint8_t> bytes) {
    std::vector<Got> got;
    std::size_t i = 0;
    DecodedFrame f;
    while (i < bytes.size()) {
        std::size_t used = 0;
        const DecodeError e = decode_frame(bytes.subspan(i), f, used);
        if (e == DecodeError::None) {
            got.push_back({f.header.sequence, f.message});
            i += used;
        } else if (e == DecodeError::BadPayload) {
            i += frame_size(f.header.payload_bytes);
        } else {
            ++i;
        }
    }
    return got;
}

}  // namespace eyesim::protocol::test
