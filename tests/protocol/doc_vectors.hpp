#pragma once
// Reads the test vectors of docs/protocol.md: ```eyesim-vector name=X``` (hex bytes), ```eyesim-expect name=X```
// (JSON lines) and ```eyesim-stats name=X``` (one JSON object).

#include <catch2/catch.hpp>

#include <cstdint>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace eyesim::protocol::test {

struct DocVector {
    std::vector<std::uint8_t> bytes;
    std::vector<std::string> expect;  // JSON lines
    std::string stats;
    bool has_expect = false, has_stats = false;
};

inline std::string read_doc() {
    std::ifstream f(std::string(EYESIM_SOURCE_DIR) + "/docs/protocol.md");
    REQUIRE(f.good());
    std::stringstream ss;
    ss << f.rdbuf();
    return ss.str();
}

inline std::map<std::string, DocVector> doc_vectors(const std::string& doc) {
    std::map<std::string, DocVector> out;
    std::istringstream in(doc);
    std::string line, kind, name;
    std::vector<std::string> body;
    bool inside = false;
    while (std::getline(in, line)) {
        if (!inside && line.rfind("```eyesim-", 0) == 0) {
            const auto sp = line.find(' ');
            kind = line.substr(3, sp - 3);
            REQUIRE(line.substr(sp + 1, 5) == "name=");
            name = line.substr(sp + 6);
            body.clear();
            inside = true;
        } else if (inside && line == "```") {
            inside = false;
            DocVector& v = out[name];
            if (kind == "eyesim-vector") {
                for (const auto& l : body) {
                    std::istringstream hex(l);
                    std::string byte;
                    while (hex >> byte) {
                        REQUIRE(byte.size() == 2);
                        v.bytes.push_back(static_cast<std::uint8_t>(std::stoul(byte, nullptr, 16)));
                    }
                }
            } else if (kind == "eyesim-expect") {
                v.has_expect = true;
                for (const auto& l : body)
                    if (!l.empty()) v.expect.push_back(l);
            } else if (kind == "eyesim-stats") {
                v.has_stats = true;
                REQUIRE(body.size() == 1);
                v.stats = body[0];
            } else {
                FAIL("unknown block kind " << kind);
            }
        } else if (inside) {
            body.push_back(line);
        }
    }
    REQUIRE_FALSE(inside);
    return out;
}


}  // namespace eyesim::protocol::test
