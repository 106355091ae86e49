// The codec and the stream parser must not touch the heap (firmware rule): count allocations made while they
// run, with the global allocation functions of this test program replaced by counting ones.
#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/json.hpp"
#include "eyesim/protocol/stream_parser.hpp"
#include "test_util.hpp"

#include <catch2/catch.hpp>

// AddressSanitizer owns the allocator in sanitizer builds (replacing it there trips its alloc/dealloc pairing
// checks), so this check runs in the release and debug builds only.
#if defined(__SANITIZE_ADDRESS__)
#define EYESIM_COUNT_ALLOCATIONS 0
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define EYESIM_COUNT_ALLOCATIONS 0
#endif
#endif
#ifndef EYESIM_COUNT_ALLOCATIONS
#define EYESIM_COUNT_ALLOCATIONS 1
#endif

#if EYESIM_COUNT_ALLOCATIONS
#include <atomic>
#include <cstdlib>
#include <memory>
#include <new>

namespace {
std::atomic<bool> g_counting{false};
std::atomic<long> g_allocations{0};
}  // namespace

void* operator new(std::size_t n) {
    if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1, std::memory_order_relaxed);
    if (void* p = std::malloc(n ? n : 1)) return p;
    throw std::bad_alloc();
}
void* operator new[](std::size_t n) { return operator new(n); }
// GCC cannot see that these replacements pair malloc with free on purpose.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
#endif
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }

using namespace eyesim::protocol;
using namespace eyesim::protocol::test;

TEST_CASE("encoding, parsing damaged streams and JSON rendering allocate nothing", "[protocol][heap]") {
    std::mt19937_64 rng(77);
    Bytes stream;
    std::vector<Message> msgs;
    for (int i = 0; i < 500; ++i) msgs.push_back(random_message(rng));
    for (int i = 0; i < 500; ++i) {
        const Bytes f = frame_of(msgs[static_cast<std::size_t>(i)], static_cast<std::uint16_t>(i));
        stream.insert(stream.end(), f.begin(), f.end());
        if (i % 7 == 0) stream.push_back(kSync0);                              // garbage
        if (i % 11 == 0) stream[stream.size() - 5] ^= 0x20;                    // bit flip
        if (i % 13 == 0) stream.erase(stream.end() - 3, stream.end());         // truncation
    }
    auto parser = std::make_unique<StreamParser>();
    auto frame = std::make_unique<DecodedFrame>();
    Bytes out(kMaxFrameBytes);
    char json[kMaxJsonBytes];
    std::size_t frames = 0, json_bytes = 0;

    g_allocations = 0;
    g_counting = true;
    for (const Message& m : msgs) frames += encode_frame(m, 1, out) > 0;
    auto on = [&](const DecodedFrame& f) {
        ++frames;
        json_bytes += format_json(f, json);
    };
    for (std::size_t i = 0; i < stream.size(); i += 300)
        parser->parse(std::span(stream).subspan(i, std::min<std::size_t>(300, stream.size() - i)), on);
    parser->finish(on);
    std::span<const std::uint8_t> rest(stream);
    while (!rest.empty()) {
        rest = rest.subspan(parser->feed(rest));
        while (parser->next(*frame)) ++frames;
    }
    g_counting = false;

    CHECK(g_allocations == 0);
    CHECK(frames > 900);
    CHECK(json_bytes > 0);
    CHECK(parser->stats().errors() > 0);
}
#endif  // EYESIM_COUNT_ALLOCATIONS
