#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/crc32c.hpp"
#include "eyesim/protocol/schema.hpp"
#include "eyesim/protocol/stream_parser.hpp"
#include "test_util.hpp"

#include <catch2/catch.hpp>

#include <map>
#include <set>
#include <string>

using namespace eyesim::protocol;
using namespace eyesim::protocol::test;

namespace {

// Bit-at-a-time CRC-32C straight from the polynomial definition: the slow reference.
std::uint32_t crc32c_bitwise(const std::uint8_t* p, std::size_t n) {
    std::uint32_t reg = 0xFFFFFFFFu;
    for (std::size_t i = 0; i < n; ++i) {
        reg ^= p[i];
        for (int k = 0; k < 8; ++k) reg = (reg & 1u) ? (reg >> 1) ^ 0x82F63B78u : reg >> 1;
    }
    return ~reg;
}

// Byte size of each wire type named in schema strings.
std::size_t type_bytes(const std::string& t) {
    static const std::map<std::string, std::size_t> sizes{{"u8", 1}, {"u16", 2}, {"u32", 4}, {"u64", 8}};
    const auto br = t.find('[');
    const std::string base = t.substr(0, br);
    std::size_t count = 1;
    if (br != std::string::npos) count = std::stoul(t.substr(br + 1));
    const auto it = sizes.find(base);
    return it == sizes.end() ? 0 : it->second * count;
}

// Sum of the field sizes of the struct named `name` in a schema string (0 if a field type is unknown).
std::size_t schema_struct_bytes(std::string_view schema, const std::string& name, bool& has_repeated) {
    const std::string s(schema);
    const auto open = s.find(name + "{");
    REQUIRE(open != std::string::npos);
    const auto close = s.find('}', open);
    std::string body = s.substr(open + name.size() + 1, close - open - name.size() - 1);
    std::size_t total = 0;
    has_repeated = false;
    std::size_t pos = 0;
    while (pos <= body.size()) {
        auto comma = body.find(',', pos);
        if (comma == std::string::npos) comma = body.size();
        const std::string field = body.substr(pos, comma - pos);
        const std::string type = field.substr(field.find(':') + 1);
        if (type.rfind("Marker[", 0) == 0) {
            has_repeated = true;
        } else {
            const std::size_t b = type_bytes(type);
            REQUIRE(b > 0);
            total += b;
        }
        pos = comma + 1;
    }
    return total;
}

}  // namespace

TEST_CASE("CRC-32C matches its catalogue check value", "[protocol][crc]") {
    const std::string check = "123456789";
    CHECK(crc32c(std::string_view(check)) == 0xE3069283u);
    CHECK(kCrc32cCheck == 0xE3069283u);
    const auto* p = reinterpret_cast<const std::uint8_t*>(check.data());
    CHECK(crc32c(std::span<const std::uint8_t>(p, check.size())) == 0xE3069283u);
    CHECK(crc32c_bitwise(p, check.size()) == 0xE3069283u);
}

TEST_CASE("CRC-32C table code equals the bitwise reference and is incremental", "[protocol][crc]") {
    std::mt19937_64 rng(11);
    for (int trial = 0; trial < 200; ++trial) {
        Bytes b(uniform<std::size_t>(rng, 0, 700));
        for (auto& x : b) x = static_cast<std::uint8_t>(rng());
        const std::uint32_t ref = crc32c_bitwise(b.data(), b.size());
        REQUIRE(crc32c(b) == ref);
        const std::size_t cut = uniform<std::size_t>(rng, 0, b.size());
        const std::span<const std::uint8_t> all(b);
        REQUIRE(crc32c_finish(crc32c_update(crc32c_update(kCrc32cInit, all.first(cut)), all.subspan(cut))) == ref);
    }
}

TEST_CASE("schema strings describe exactly the payload layouts", "[protocol][schema]") {
    bool rep = false;
    CHECK(schema_struct_bytes(kFieldMarkersSchema, "FieldMarkers", rep) == kFieldMarkersHeaderBytes);
    CHECK(rep);
    CHECK(schema_struct_bytes(kFieldMarkersSchema, "Marker", rep) == kMarkerRecordBytes);
    CHECK(schema_struct_bytes(kPedalStateSchema, "PedalState", rep) == kPedalStatePayloadBytes);
    CHECK(schema_struct_bytes(kDeviceStatusSchema, "DeviceStatus", rep) == kDeviceStatusPayloadBytes);
    CHECK(schema_struct_bytes(kCommandSchema, "Command", rep) == kCommandPayloadBytes);
    CHECK(schema_struct_bytes(kReplySchema, "Reply", rep) == kReplyPayloadBytes);
    // The FieldMarkers schema names the marker capacity the frame limit gives.
    CHECK(std::string(kFieldMarkersSchema).find("<=" + std::to_string(kMaxMarkersPerMessage) + "]") !=
          std::string::npos);
}

TEST_CASE("schema hashes are distinct and change with any layout change", "[protocol][schema]") {
    std::set<std::uint32_t> seen;
    for (int t = 1; t <= static_cast<int>(kMessageTypeCount); ++t) {
        const auto type = static_cast<MessageType>(t);
        const std::uint32_t h = schema_hash(type);
        CHECK(h == crc32c(schema_string(type)));
        seen.insert(h);
        const std::string s(schema_string(type));
        // Widen the first field, swap the first two fields, rename a field: each gives another hash.
        std::string widened = s;
        const auto u = widened.find(":u");
        widened.replace(u, 3, widened.substr(u, 3) == ":u8" ? ":u16" : ":u8");
        CHECK(crc32c(widened) != h);
        const auto open = s.find('{'), c1 = s.find(',', open), c2 = s.find(',', c1 + 1);
        const std::string swapped = s.substr(0, open + 1) + s.substr(c1 + 1, c2 - c1 - 1) + "," +
                                    s.substr(open + 1, c1 - open - 1) + s.substr(c2);
        CHECK(swapped.size() == s.size());
        CHECK(crc32c(swapped) != h);
    }
    CHECK(seen.size() == kMessageTypeCount);
}

TEST_CASE("a peer built from another schema is rejected by the CRC", "[protocol][schema]") {
    std::mt19937_64 rng(5);
    const PedalState p = random_pedal(rng);
    Bytes payload(kPedalStatePayloadBytes);
    REQUIRE(encode_payload(p, payload) == kPedalStatePayloadBytes);
    // Same bytes, framed by a peer whose PedalState layout had buttons as u32 (another schema string).
    const std::uint32_t other = crc32c(std::string_view("PedalState{device_us:u64,axes:u16[3],buttons:u32}"));
    Bytes frame(kMaxFrameBytes);
    frame.resize(encode_frame_raw(2, 0, payload, frame, other));
    DecodedFrame out;
    std::size_t used = 0;
    CHECK(decode_frame(frame, out, used) == DecodeError::BadCrc);
    StreamParser parser;
    int frames = 0;
    parser.parse(frame, [&](const DecodedFrame&) { ++frames; });
    parser.finish([&](const DecodedFrame&) { ++frames; });
    CHECK(frames == 0);
    CHECK(parser.stats().crc_errors == 1);
    // With our schema hash the same payload decodes.
    Bytes good(kMaxFrameBytes);
    good.resize(encode_frame_raw(2, 0, payload, good, schema_hash(MessageType::PedalState)));
    REQUIRE(decode_frame(good, out, used) == DecodeError::None);
    CHECK(std::get<PedalState>(out.message) == p);
}
