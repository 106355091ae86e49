// docs/protocol.md is the specification: these tests decode its test vectors and compare the outcome with the
// values written there, and check its schema-hash table and CRC check value, so the document and the code
// cannot drift apart.
#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/crc32c.hpp"
#include "eyesim/protocol/json.hpp"
#include "eyesim/protocol/schema.hpp"
#include "eyesim/protocol/stream_parser.hpp"
#include "doc_vectors.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

using namespace eyesim::protocol;

using namespace eyesim::protocol::test;

TEST_CASE("docs/protocol.md test vectors decode to the documented values", "[protocol][doc]") {
    const auto vectors = doc_vectors(read_doc());
    REQUIRE(vectors.size() >= 7);
    std::map<std::string, int> types_seen;
    bool corrupted = false, truncated = false;
    for (const auto& [name, v] : vectors) {
        INFO("vector " << name);
        REQUIRE(!v.bytes.empty());
        REQUIRE(v.has_expect);
        REQUIRE(v.has_stats);
        StreamParser parser;
        std::vector<nlohmann::json> got;
        std::vector<DecodedFrame> frames;
        auto on = [&](const DecodedFrame& f) {
            char buf[kMaxJsonBytes];
            REQUIRE(format_json(f, buf) > 0);
            got.push_back(nlohmann::json::parse(buf));
            frames.push_back(f);
        };
        parser.parse(v.bytes, on);
        parser.finish(on);
        REQUIRE(got.size() == v.expect.size());
        for (std::size_t i = 0; i < got.size(); ++i) {
            const auto want = nlohmann::json::parse(v.expect[i]);
            CHECK(got[i] == want);
            types_seen[want.at("type").get<std::string>()]++;
        }
        char stats[kMaxJsonBytes];
        REQUIRE(format_stats_json(parser.stats(), stats) > 0);
        CHECK(nlohmann::json::parse(stats) == nlohmann::json::parse(v.stats));
        // A clean single-frame vector re-encodes to exactly its bytes.
        if (parser.stats().errors() == 0 && parser.stats().skipped_bytes == 0 && frames.size() == 1) {
            std::vector<std::uint8_t> again(kMaxFrameBytes);
            again.resize(encode_frame(frames[0].message, frames[0].header.sequence, again));
            CHECK(again == v.bytes);
        }
        corrupted = corrupted || parser.stats().crc_errors > 0;
        truncated = truncated || parser.stats().truncated > 0;
    }
    for (int t = 1; t <= static_cast<int>(kMessageTypeCount); ++t)
        CHECK(types_seen[message_type_name(static_cast<MessageType>(t))] >= 1);
    CHECK(corrupted);
    CHECK(truncated);
}

TEST_CASE("docs/protocol.md lists the schema hashes and the CRC check value the code uses", "[protocol][doc]") {
    const std::string doc = read_doc();
    std::istringstream in(doc);
    std::string line;
    int rows = 0;
    while (std::getline(in, line)) {
        // | 2 | PedalState | `0xD8D04C2A` | `PedalState{...}` |
        for (int t = 1; t <= static_cast<int>(kMessageTypeCount); ++t) {
            const auto type = static_cast<MessageType>(t);
            const std::string prefix = "| " + std::to_string(t) + " | " + message_type_name(type) + " | `0x";
            if (line.rfind(prefix, 0) != 0) continue;
            char hex[16];
            std::snprintf(hex, sizeof hex, "%08X", schema_hash(type));
            CHECK(line.substr(prefix.size(), 8) == hex);
            std::string quoted = "`";
            quoted.append(schema_string(type));
            quoted.push_back('`');
            CHECK(line.find(quoted) != std::string::npos);
            ++rows;
        }
    }
    CHECK(rows == static_cast<int>(kMessageTypeCount));
    char check[16];
    std::snprintf(check, sizeof check, "0x%08X", crc32c(std::string_view("123456789")));
    std::string sentence = "CRC-32C(\"123456789\") = `";
    sentence.append(check);
    sentence.push_back('`');
    CHECK(doc.find(sentence) != std::string::npos);
    CHECK(doc.find("## USB transport") != std::string::npos);
}
