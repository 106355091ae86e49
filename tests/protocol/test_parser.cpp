#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/schema.hpp"
#include "eyesim/protocol/stream_parser.hpp"
#include "reference_scan.hpp"
#include "test_util.hpp"

#include <catch2/catch.hpp>

#include <algorithm>

using namespace eyesim::protocol;
using namespace eyesim::protocol::test;

namespace {

struct Stream {
    Bytes bytes;
    std::vector<Got> sent;  // frames in order
    std::vector<std::pair<std::size_t, std::size_t>> spans;  // [begin, end) of each frame in bytes
};

Stream make_stream(std::mt19937_64& rng, int frames, std::uint16_t first_seq = 0) {
    Stream s;
    for (int i = 0; i < frames; ++i) {
        const auto seq = static_cast<std::uint16_t>(first_seq + i);
        const Message m = random_message(rng);
        const Bytes f = frame_of(m, seq);
        s.spans.emplace_back(s.bytes.size(), s.bytes.size() + f.size());
        s.bytes.insert(s.bytes.end(), f.begin(), f.end());
        s.sent.push_back({seq, m});
    }
    return s;
}

/// Feeds `bytes` in chunks of random size (1..max_chunk; whole when max_chunk is 0) and collects the frames.
std::vector<Got> parse_all(const Bytes& bytes, StreamParser& p, std::mt19937_64& rng, std::size_t max_chunk) {
    std::vector<Got> got;
    auto on = [&](const DecodedFrame& f) { got.push_back({f.header.sequence, f.message}); };
    std::size_t i = 0;
    while (i < bytes.size()) {
        const std::size_t n =
            max_chunk == 0 ? bytes.size() - i : std::min(bytes.size() - i, uniform<std::size_t>(rng, 1, max_chunk));
        p.parse(std::span(bytes).subspan(i, n), on);
        i += n;
    }
    p.finish(on);
    return got;
}

/// The same through feed()/next() only.
std::vector<Got> feed_next_all(const Bytes& bytes, StreamParser& p) {
    std::vector<Got> got;
    DecodedFrame f;
    std::span<const std::uint8_t> rest(bytes);
    while (!rest.empty()) {
        rest = rest.subspan(p.feed(rest));
        while (p.next(f)) got.push_back({f.header.sequence, f.message});
    }
    p.end_stream();
    while (p.next(f)) got.push_back({f.header.sequence, f.message});
    return got;
}

Bytes garbage(std::mt19937_64& rng, std::size_t n) {
    Bytes g(n);
    for (auto& b : g) {
        // Plenty of sync bytes and plausible headers so the parser's candidate logic is exercised.
        const int pick = uniform<int>(rng, 0, 9);
        b = pick == 0 ? kSync0 : pick == 1 ? kSync1 : pick == 2 ? 1 : static_cast<std::uint8_t>(rng());
    }
    return g;
}

}  // namespace

TEST_CASE("a clean stream parses identically for any chunking", "[protocol][parser]") {
    std::mt19937_64 rng(1);
    const Stream s = make_stream(rng, 300, 65500);  // sequence wraps inside the stream
    for (std::size_t chunk : {0, 1, 2, 7, 64, 511, 512, 513, 4096}) {
        StreamParser p;
        CHECK(parse_all(s.bytes, p, rng, chunk) == s.sent);
        CHECK(p.stats().frames == s.sent.size());
        CHECK(p.stats().bytes_in == s.bytes.size());
        CHECK(p.stats().skipped_bytes == 0);
        CHECK(p.stats().errors() == 0);
        CHECK(p.stats().sequence_gaps == 0);
        CHECK(p.buffered() == 0);
    }
    StreamParser q;
    CHECK(feed_next_all(s.bytes, q) == s.sent);
}

TEST_CASE("garbage between frames is skipped and no frame is lost", "[protocol][parser]") {
    std::mt19937_64 rng(2);
    for (int trial = 0; trial < 20; ++trial) {
        const Stream s = make_stream(rng, 100);
        Bytes noisy;
        std::size_t garbage_total = 0;
        for (std::size_t i = 0; i < s.spans.size(); ++i) {
            const Bytes g = garbage(rng, uniform<std::size_t>(rng, 0, 40));
            garbage_total += g.size();
            noisy.insert(noisy.end(), g.begin(), g.end());
            noisy.insert(noisy.end(), s.bytes.begin() + s.spans[i].first, s.bytes.begin() + s.spans[i].second);
        }
        StreamParser p;
        CHECK(parse_all(noisy, p, rng, 300) == s.sent);
        CHECK(p.stats().skipped_bytes == garbage_total);
        CHECK(p.stats().frames == s.sent.size());
        CHECK(p.stats().bad_payload == 0);
    }
}

TEST_CASE("a frame hidden behind a false header claiming the maximum length is found", "[protocol][parser]") {
    std::mt19937_64 rng(3);
    const Stream s = make_stream(rng, 3);
    // A fake header (valid version, type and maximum FieldMarkers length) whose span swallows all three frames.
    Bytes b = {kSync0, kSync1, 1, 1, 0, 0, 0xEE, 0x01};  // payload 494
    b.insert(b.end(), s.bytes.begin(), s.bytes.end());
    StreamParser p;
    CHECK(parse_all(b, p, rng, 0) == s.sent);
    CHECK(p.stats().skipped_bytes == 8);
    // The false candidate is classified once: as a truncated frame (good frames start inside its span).
    CHECK(p.stats().truncated + p.stats().crc_errors == 1);
}

TEST_CASE("bit flips in payload or CRC cost exactly the flipped frames", "[protocol][parser]") {
    std::mt19937_64 rng(4);
    for (int trial = 0; trial < 30; ++trial) {
        Stream s = make_stream(rng, 60);
        std::vector<Got> expect;
        std::size_t flipped = 0;
        for (std::size_t i = 0; i < s.spans.size(); ++i) {
            if (uniform<int>(rng, 0, 3) == 0) {
                const std::size_t at = uniform<std::size_t>(rng, s.spans[i].first + kFrameHeaderBytes,
                                                            s.spans[i].second - 1);
                s.bytes[at] ^= static_cast<std::uint8_t>(1u << uniform<int>(rng, 0, 7));
                ++flipped;
            } else {
                expect.push_back(s.sent[i]);
            }
        }
        StreamParser p;
        CHECK(parse_all(s.bytes, p, rng, 100) == expect);
        CHECK(p.stats().crc_errors == flipped);
        CHECK(p.stats().truncated == 0);
        CHECK(p.stats().sequence_gaps <= flipped);
    }
}

TEST_CASE("bit flips in headers lose only the flipped frame and are counted", "[protocol][parser]") {
    std::mt19937_64 rng(5);
    for (int trial = 0; trial < 300; ++trial) {
        Stream s = make_stream(rng, 5);
        const std::size_t victim = uniform<std::size_t>(rng, 0, 4);
        const std::size_t at = s.spans[victim].first + uniform<std::size_t>(rng, 0, kFrameHeaderBytes - 1);
        s.bytes[at] ^= static_cast<std::uint8_t>(1u << uniform<int>(rng, 0, 7));
        std::vector<Got> expect = s.sent;
        expect.erase(expect.begin() + static_cast<std::ptrdiff_t>(victim));
        StreamParser p;
        const auto got = parse_all(s.bytes, p, rng, 50);
        REQUIRE(got == expect);
        const std::size_t offset = at - s.spans[victim].first;
        if (offset < 2) {
            CHECK(p.stats().errors() == 0);  // a broken sync marker turns the frame into plain garbage
        } else {
            CHECK(p.stats().errors() >= 1);
        }
        CHECK(p.stats().skipped_bytes == s.spans[victim].second - s.spans[victim].first);
        CHECK(p.stats().resyncs == 1);
    }
}

TEST_CASE("truncated frames are counted and the next frame survives", "[protocol][parser]") {
    std::mt19937_64 rng(6);
    for (int trial = 0; trial < 30; ++trial) {
        const Stream s = make_stream(rng, 40);
        Bytes cut;
        std::vector<Got> expect;
        std::size_t cuts = 0;
        for (std::size_t i = 0; i < s.spans.size(); ++i) {
            const auto [b, e] = s.spans[i];
            std::size_t keep = e - b;
            if (i + 1 < s.spans.size() && uniform<int>(rng, 0, 3) == 0) {
                keep = uniform<std::size_t>(rng, kFrameHeaderBytes, e - b - 1);  // header intact, tail lost
                ++cuts;
            } else {
                expect.push_back(s.sent[i]);
            }
            cut.insert(cut.end(), s.bytes.begin() + static_cast<std::ptrdiff_t>(b),
                       s.bytes.begin() + static_cast<std::ptrdiff_t>(b + keep));
        }
        StreamParser p;
        CHECK(parse_all(cut, p, rng, 128) == expect);
        CHECK(p.stats().truncated == cuts);
        CHECK(p.stats().crc_errors == 0);
    }
}

TEST_CASE("cuts inside the header lose only the cut frame", "[protocol][parser]") {
    std::mt19937_64 rng(7);
    for (std::size_t keep = 1; keep < kFrameHeaderBytes; ++keep) {
        const Stream s = make_stream(rng, 4);
        Bytes b(s.bytes.begin(), s.bytes.begin() + static_cast<std::ptrdiff_t>(s.spans[1].first + keep));
        b.insert(b.end(), s.bytes.begin() + static_cast<std::ptrdiff_t>(s.spans[2].first), s.bytes.end());
        StreamParser p;
        const std::vector<Got> expect = {s.sent[0], s.sent[2], s.sent[3]};
        CHECK(parse_all(b, p, rng, 0) == expect);
        CHECK(p.stats().skipped_bytes == keep);
        CHECK(p.stats().sequence_gaps == 1);
    }
}

TEST_CASE("a stream ending inside a frame counts one truncation", "[protocol][parser]") {
    std::mt19937_64 rng(8);
    const Stream s = make_stream(rng, 2);
    for (std::size_t keep = 2; keep < s.spans[1].second - s.spans[1].first; ++keep) {
        const Bytes b(s.bytes.begin(), s.bytes.begin() + static_cast<std::ptrdiff_t>(s.spans[1].first + keep));
        StreamParser p;
        CHECK(parse_all(b, p, rng, 0) == std::vector<Got>{s.sent[0]});
        CHECK(p.stats().truncated == 1);
        CHECK(p.stats().skipped_bytes == keep);
        CHECK(p.buffered() == 0);
    }
}

namespace {

/// A FieldMarkers frame with 14 markers (506 bytes) whose payload holds no sync byte, with a false header of each
/// kind (bad version, unknown type, bad length) written into its payload at offsets 20, 40 and 60.
Bytes long_frame_with_false_headers(std::uint16_t seq) {
    FieldMarkers f;
    f.camera_id = 1;
    f.marker_count = kMaxMarkersPerMessage;
    f.field_counter = 7;
    f.field_end_us = 1000;
    for (std::size_t i = 0; i < f.marker_count; ++i) {
        f.markers[i].colour_class = 1;
        f.markers[i].bbox_x1 = f.markers[i].bbox_y1 = 3;
        f.markers[i].area_px = static_cast<std::uint32_t>(10 + i);
    }
    Bytes b = frame_of(Message{f}, seq);
    REQUIRE(b.size() == kMaxFrameBytes - 6);
    REQUIRE(std::count(b.begin() + 2, b.end() - 4, kSync0) == 0);
    const Bytes bad_version = {kSync0, kSync1, 2, 2, 0, 0, 16, 0};
    const Bytes unknown_type = {kSync0, kSync1, 1, 9, 0, 0, 16, 0};
    const Bytes bad_length = {kSync0, kSync1, 1, 2, 0, 0, 17, 0};
    std::copy(bad_version.begin(), bad_version.end(), b.begin() + 20);
    std::copy(unknown_type.begin(), unknown_type.end(), b.begin() + 40);
    std::copy(bad_length.begin(), bad_length.end(), b.begin() + 60);
    return b;
}

}  // namespace

TEST_CASE("false headers inside a damaged frame are not counted again, however it is recognised", "[protocol][parser]") {
    // Each stream holds exactly one damaged frame (truth: one error counter at 1, all others 0) and the good frames
    // around it, which must all be delivered.
    std::mt19937_64 rng(21);
    const Bytes damaged = long_frame_with_false_headers(100);
    const Stream before = make_stream(rng, 3, 97);
    const Stream next = make_stream(rng, 1, 101);
    const Stream many = make_stream(rng, 40, 101);  // far more than the damaged frame's claimed 506 bytes
    struct Case {
        const char* name;
        Bytes bytes;
        std::vector<Got> expect;
        std::uint64_t truncated, crc_errors;
    };
    auto join = [](std::initializer_list<const Bytes*> parts) {
        Bytes b;
        for (const Bytes* p : parts) b.insert(b.end(), p->begin(), p->end());
        return b;
    };
    auto cat = [](std::vector<Got> a, const std::vector<Got>& b) {
        a.insert(a.end(), b.begin(), b.end());
        return a;
    };
    const Bytes cut(damaged.begin(), damaged.begin() + 80);  // all three false headers kept, the tail lost
    Bytes flipped = damaged;                                 // whole length, one bit flipped: a CRC error
    flipped[300] ^= 0x10;
    const std::vector<Case> cases = {
        // Cut short by the next header, the stream ending before the cut frame's claimed end.
        {"cut by a header, then the end", join({&before.bytes, &cut, &next.bytes}), cat(before.sent, next.sent), 1, 0},
        // Cut short by the next header, the stream going on past the cut frame's claimed end (found by its CRC).
        {"cut by a header, stream goes on", join({&before.bytes, &cut, &many.bytes}), cat(before.sent, many.sent), 1,
         0},
        // Cut short by the end of the stream.
        {"cut by the end", join({&before.bytes, &cut}), before.sent, 1, 0},
        // Complete but corrupted in place.
        {"crc error", join({&before.bytes, &flipped, &many.bytes}), cat(before.sent, many.sent), 0, 1},
    };
    for (const Case& c : cases) {
        for (const std::size_t chunk : {std::size_t{0}, std::size_t{1}, std::size_t{37}, std::size_t{600}}) {
            INFO(c.name << ", chunks up to " << chunk);
            StreamParser p;
            CHECK(parse_all(c.bytes, p, rng, chunk) == c.expect);
            CHECK(p.stats().truncated == c.truncated);
            CHECK(p.stats().crc_errors == c.crc_errors);
            CHECK(p.stats().bad_version == 0);
            CHECK(p.stats().unknown_type == 0);
            CHECK(p.stats().bad_length == 0);
            CHECK(p.stats().errors() == 1);
            StreamParser q;
            CHECK(feed_next_all(c.bytes, q) == c.expect);
            CHECK(q.stats() == p.stats());
        }
    }
    // The same false headers outside any damaged frame are each counted.
    Bytes loose(damaged.begin() + 20, damaged.begin() + 68);
    loose.insert(loose.end(), next.bytes.begin(), next.bytes.end());
    StreamParser p;
    CHECK(parse_all(loose, p, rng, 0) == next.sent);
    CHECK(p.stats().bad_version == 1);
    CHECK(p.stats().unknown_type == 1);
    CHECK(p.stats().bad_length == 1);
    CHECK(p.stats().errors() == 3);
}

TEST_CASE("a plausible header inside a damaged frame ends its span and counts on its own", "[protocol][parser]") {
    std::mt19937_64 rng(22);
    const Bytes damaged = long_frame_with_false_headers(5);
    const Bytes pedal = frame_of(Message{PedalState{0x0102030405060708ull, {1, 2, 3}, 4}}, 6);
    // The damaged frame cut after 80 bytes, then the first 20 bytes of a pedal frame (a plausible header), a
    // false header after it (inside the pedal frame's claimed 28 bytes) and the end of the stream: two frames cut
    // short, nothing else counted.
    Bytes b(damaged.begin(), damaged.begin() + 80);
    b.insert(b.end(), pedal.begin(), pedal.begin() + 20);
    b[80 + 12] = kSync0, b[80 + 13] = kSync1, b[80 + 14] = 3;
    StreamParser p;
    CHECK(parse_all(b, p, rng, 0).empty());
    CHECK(p.stats().truncated == 2);
    CHECK(p.stats().errors() == 2);
    CHECK(p.stats().skipped_bytes == b.size());
    CHECK(p.stats().resyncs == 1);
    // A stream ending inside a header with another sync pair in those last bytes: one truncation.
    const Bytes tail = {kSync0, kSync1, 1, kSync0, kSync1, 1};
    StreamParser q;
    CHECK(parse_all(tail, q, rng, 0).empty());
    CHECK(q.stats().truncated == 1);
    CHECK(q.stats().errors() == 1);
    CHECK(q.stats().skipped_bytes == tail.size());
}

TEST_CASE("oversize and invalid lengths, bad versions and unknown types are counted", "[protocol][parser]") {
    std::mt19937_64 rng(9);
    const Stream s = make_stream(rng, 2);
    auto with_header = [&](std::uint8_t version, std::uint8_t type, std::uint16_t len) {
        Bytes b = {kSync0, kSync1, version, type, 0, 0, static_cast<std::uint8_t>(len), static_cast<std::uint8_t>(len >> 8)};
        b.insert(b.end(), s.bytes.begin(), s.bytes.end());
        StreamParser p;
        REQUIRE(parse_all(b, p, rng, 0) == s.sent);
        CHECK(p.stats().skipped_bytes == 8);
        return p.stats();
    };
    CHECK(with_header(1, 1, 0xFFFF).bad_length == 1);
    CHECK(with_header(1, 1, 501).bad_length == 1);
    CHECK(with_header(1, 1, 19).bad_length == 1);
    CHECK(with_header(1, 2, 17).bad_length == 1);
    CHECK(with_header(0, 2, 16).bad_version == 1);
    CHECK(with_header(2, 2, 16).bad_version == 1);
    CHECK(with_header(1, 0, 16).unknown_type == 1);
    CHECK(with_header(1, 7, 16).unknown_type == 1);
}

TEST_CASE("a frame with a good CRC but out-of-range fields is counted and dropped whole", "[protocol][parser]") {
    std::mt19937_64 rng(10);
    const Stream s = make_stream(rng, 2);
    Bytes payload(kReplyPayloadBytes);
    REQUIRE(encode_payload(Reply{1, 2, 1, 1, 0, 0, 0}, payload) == kReplyPayloadBytes);
    payload[6] = 9;  // nack reason 9 is undefined
    Bytes frame(kMaxFrameBytes);
    frame.resize(encode_frame_raw(5, 0, payload, frame, schema_hash(MessageType::Reply)));
    Bytes b = frame;
    b.insert(b.end(), s.bytes.begin(), s.bytes.end());
    StreamParser p;
    CHECK(parse_all(b, p, rng, 0) == s.sent);
    CHECK(p.stats().bad_payload == 1);
    CHECK(p.stats().skipped_bytes == frame.size());
}

TEST_CASE("sequence gaps count lost frames", "[protocol][parser]") {
    std::mt19937_64 rng(11);
    const Stream s = make_stream(rng, 10);
    Bytes b;
    for (std::size_t i : {0, 1, 2, 5, 6, 9})
        b.insert(b.end(), s.bytes.begin() + static_cast<std::ptrdiff_t>(s.spans[i].first),
                 s.bytes.begin() + static_cast<std::ptrdiff_t>(s.spans[i].second));
    StreamParser p;
    CHECK(parse_all(b, p, rng, 0).size() == 6);
    CHECK(p.stats().sequence_gaps == 2);
    CHECK(p.stats().errors() == 0);
}

namespace {

void compare_with_brute_force(std::uint64_t seed, int trials) {
    std::mt19937_64 rng(seed);
    for (int trial = 0; trial < trials; ++trial) {
        Stream s = make_stream(rng, uniform<int>(rng, 1, 30));
        Bytes b = s.bytes;
        // Random damage: garbage insertions, deletions, bit flips, duplicated slices.
        const int edits = uniform<int>(rng, 0, 12);
        for (int e = 0; e < edits && !b.empty(); ++e) {
            const std::size_t at = uniform<std::size_t>(rng, 0, b.size() - 1);
            switch (uniform<int>(rng, 0, 3)) {
                case 0: {
                    const Bytes g = garbage(rng, uniform<std::size_t>(rng, 1, 600));
                    b.insert(b.begin() + static_cast<std::ptrdiff_t>(at), g.begin(), g.end());
                    break;
                }
                case 1: {
                    const std::size_t n = std::min(b.size() - at, uniform<std::size_t>(rng, 1, 80));
                    b.erase(b.begin() + static_cast<std::ptrdiff_t>(at), b.begin() + static_cast<std::ptrdiff_t>(at + n));
                    break;
                }
                case 2: b[at] ^= static_cast<std::uint8_t>(1u << uniform<int>(rng, 0, 7)); break;
                default: {
                    const std::size_t n = std::min(b.size() - at, uniform<std::size_t>(rng, 1, 300));
                    const Bytes dup(b.begin() + static_cast<std::ptrdiff_t>(at), b.begin() + static_cast<std::ptrdiff_t>(at + n));
                    b.insert(b.begin() + static_cast<std::ptrdiff_t>(at), dup.begin(), dup.end());
                }
            }
        }
        const std::vector<Got> ref = brute_force(b);
        StreamParser p1, p2, p3;
        const auto whole = parse_all(b, p1, rng, 0);
        const auto bytewise = parse_all(b, p2, rng, 1);
        const auto pulled = feed_next_all(b, p3);
        REQUIRE(whole == ref);
        REQUIRE(bytewise == ref);
        REQUIRE(pulled == ref);
        CHECK(p1.stats() == p2.stats());
        CHECK(p1.stats() == p3.stats());
        std::size_t delivered = 0;
        for (const auto& g : ref) delivered += frame_size(payload_size(g.msg));
        CHECK(p1.stats().skipped_bytes + delivered == b.size());
        CHECK(p1.stats().bytes_in == b.size());
    }
}

}  // namespace

TEST_CASE("the parser delivers exactly what a brute-force scan finds, on any damage", "[protocol][parser]") {
    compare_with_brute_force(12, 200);
}

TEST_CASE("brute-force comparison on many damaged streams", "[protocol][parser][stress]") {
    compare_with_brute_force(1200, 20000);
}

TEST_CASE("reset clears the buffer and the counters", "[protocol][parser]") {
    std::mt19937_64 rng(13);
    const Stream s = make_stream(rng, 1);
    StreamParser p;
    p.feed(std::span(s.bytes).first(s.bytes.size() - 1));
    DecodedFrame f;
    CHECK_FALSE(p.next(f));
    CHECK(p.buffered() == s.bytes.size() - 1);
    p.reset();
    CHECK(p.buffered() == 0);
    CHECK(p.stats() == ParserStats{});
}
