// libFuzzer target for the stream parser. The first input byte picks a mode:
//   even: raw mode, the rest is a byte stream fed in chunks;
//   odd:  framed mode, the rest is a list of (control, length, payload) records that are framed with a correct
//         CRC (and the type's schema hash) so the fuzzer reaches the payload decoder past the CRC check.
// Either way the stream is checked against a brute-force reference and for internal consistency; any
// disagreement aborts.
#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/json.hpp"
#include "eyesim/protocol/schema.hpp"
#include "eyesim/protocol/stream_parser.hpp"
#include "fuzz_require.hpp"
#include "reference_scan.hpp"

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <vector>

namespace {

using namespace eyesim::protocol;

using test::brute_force;
using test::Got;

void check_frame(const DecodedFrame& f) {
    require(valid_message(f.message));
    require(message_type(f.message) == f.header.type);
    require(payload_size(f.message) == f.header.payload_bytes);
    std::uint8_t again[kMaxFrameBytes];
    const std::size_t n = encode_frame(f.message, f.header.sequence, again);
    require(n == frame_size(f.header.payload_bytes));
    DecodedFrame back;
    std::size_t used = 0;
    require(decode_frame({again, n}, back, used) == DecodeError::None && back.message == f.message);
    char json[kMaxJsonBytes];
    require(format_json(f, json) > 0);
}

void check_stream(const std::vector<std::uint8_t>& bytes, std::uint32_t chunk_seed) {
    const std::vector<Got> ref = brute_force(bytes);

    // Whole buffer at once.
    auto whole = std::make_unique<StreamParser>();
    std::vector<Got> a;
    auto on_a = [&](const DecodedFrame& f) {
        check_frame(f);
        a.push_back({f.header.sequence, f.message});
    };
    whole->parse(bytes, on_a);
    whole->finish(on_a);
    require(a == ref);

    // Pseudo-random chunks (1..600 bytes).
    auto chunked = std::make_unique<StreamParser>();
    std::vector<Got> b;
    auto on_b = [&](const DecodedFrame& f) { b.push_back({f.header.sequence, f.message}); };
    std::uint32_t x = chunk_seed | 1u;
    for (std::size_t i = 0; i < bytes.size();) {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        const std::size_t n = std::min<std::size_t>(bytes.size() - i, 1 + x % 600);
        chunked->parse(std::span(bytes).subspan(i, n), on_b);
        i += n;
    }
    chunked->finish(on_b);
    require(b == ref);
    require(chunked->stats() == whole->stats());

    // feed()/next() only.
    auto pulled = std::make_unique<StreamParser>();
    std::size_t k = 0;
    DecodedFrame f;
    std::span<const std::uint8_t> rest(bytes);
    while (!rest.empty()) {
        rest = rest.subspan(pulled->feed(rest));
        while (pulled->next(f)) require(k < ref.size() && Got{f.header.sequence, f.message} == ref[k++]);
    }
    pulled->end_stream();
    while (pulled->next(f)) require(k < ref.size() && Got{f.header.sequence, f.message} == ref[k++]);
    require(k == ref.size());
    require(pulled->stats() == whole->stats());

    // Every byte is either in a delivered frame or skipped.
    const ParserStats& s = whole->stats();
    std::size_t delivered = 0;
    for (const auto& g : ref) delivered += frame_size(payload_size(g.msg));
    require(s.bytes_in == bytes.size());
    require(s.frames == ref.size());
    require(s.skipped_bytes + delivered == bytes.size());
    require(whole->buffered() == 0);
}

// Framed mode: [ctl][len][payload...] records; ctl bits 0-2 type (0..7), bit 3 wrong schema hash, bit 4 wrong
// version, bit 5 adds 256 to the length, bit 6 cuts the frame in half, bit 7 puts the next byte in front as
// garbage.
std::vector<std::uint8_t> framed_stream(const std::uint8_t* data, std::size_t size) {
    std::vector<std::uint8_t> out;
    std::uint8_t frame[2 * kMaxFrameBytes];
    std::size_t i = 0;
    std::uint16_t seq = 0;
    while (i + 2 <= size) {
        const std::uint8_t ctl = data[i];
        std::size_t len = data[i + 1] + ((ctl & 0x20) ? 256u : 0u);
        i += 2;
        if (ctl & 0x80 && i < size) out.push_back(data[i++]);
        len = std::min(len, size - i);
        const std::uint8_t type = ctl & 0x07;
        const std::uint32_t schema = (ctl & 0x08) ? 0u : schema_hash(static_cast<MessageType>(type));
        const std::uint8_t version = (ctl & 0x10) ? 2 : kProtocolVersion;
        std::size_t n = encode_frame_raw(type, seq++, {data + i, len}, frame, schema, version);
        i += len;
        if (ctl & 0x40) n /= 2;
        out.insert(out.end(), frame, frame + n);
    }
    return out;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    if (size < 1) return 0;
    const std::uint8_t mode = data[0];
    const std::uint32_t chunk_seed = 0x9E3779B9u * (size + mode);
    if (mode % 2 == 0) {
        check_stream(std::vector<std::uint8_t>(data + 1, data + size), chunk_seed);
    } else {
        check_stream(framed_stream(data + 1, size - 1), chunk_seed);
        // The payload decoder on its own, every type.
        Message m;
        for (int t = 0; t <= static_cast<int>(kMessageTypeCount) + 1; ++t) {
            const DecodeError e = decode_payload(static_cast<MessageType>(t), {data + 1, size - 1}, m);
            if (e == DecodeError::None) require(valid_message(m));
        }
    }
    return 0;
}
