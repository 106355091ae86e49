// Bounded drop-oldest packet queue against a std::deque reference model.
#include "eyesim/firmware/fixed_vector.hpp"
#include "eyesim/firmware/packet_queue.hpp"

#include <catch2/catch.hpp>

#include <deque>
#include <random>
#include <vector>

using namespace eyesim::firmware;

TEST_CASE("packet queue drops the oldest whole packets, like the reference model", "[firmware][queue]") {
    constexpr std::size_t kBytes = 1000, kPackets = 16;
    PacketQueue<kBytes, kPackets> q;
    std::deque<std::vector<std::uint8_t>> model;
    std::size_t model_bytes = 0;
    std::uint64_t dropped = 0, dropped_bytes = 0;
    std::vector<std::uint32_t> dropped_tags;
    std::mt19937 rng(7);
    std::uint32_t next_tag = 0;
    for (int step = 0; step < 20000; ++step) {
        if (rng() % 3 != 0) {
            const std::size_t len = 1 + rng() % 300;
            std::vector<std::uint8_t> p(len);
            for (auto& b : p) b = static_cast<std::uint8_t>(rng());
            const std::uint32_t tag = next_tag++;
            // Reference: drop from the front until both limits hold.
            std::vector<std::uint32_t> expect_drops;
            while (model.size() == kPackets || kBytes - model_bytes < len) {
                model_bytes -= model.front().size();
                dropped_bytes += model.front().size();
                expect_drops.push_back(model.front()[0] | 0u);
                model.pop_front();
                ++dropped;
            }
            std::size_t drops_seen = 0;
            const auto r = q.push(p.data(), len, tag, [&](std::uint32_t) { ++drops_seen; });
            REQUIRE(drops_seen == expect_drops.size());
            REQUIRE(r == (expect_drops.empty() ? PushResult::queued : PushResult::queued_after_drop));
            model.push_back(p);
            model_bytes += len;
        } else {
            std::vector<std::uint8_t> out(kBytes);
            const std::size_t n = q.pop(out.data(), out.size());
            if (model.empty()) {
                REQUIRE(n == 0);
            } else {
                REQUIRE(n == model.front().size());
                out.resize(n);
                REQUIRE(out == model.front());
                model_bytes -= n;
                model.pop_front();
            }
        }
        REQUIRE(q.packets() == model.size());
        REQUIRE(q.bytes() == model_bytes);
        REQUIRE(q.stats().dropped_packets == dropped);
        REQUIRE(q.stats().dropped_bytes == dropped_bytes);
        REQUIRE(q.bytes() <= kBytes);
    }
    REQUIRE(dropped > 100);  // the random load really overflowed the queue
}

TEST_CASE("packet queue reports tags of dropped packets and rejects oversize ones", "[firmware][queue]") {
    PacketQueue<100, 4> q;
    std::vector<std::uint32_t> tags;
    auto on_drop = [&](std::uint32_t t) { tags.push_back(t); };
    std::uint8_t buf[200] = {};
    for (std::uint32_t t = 1; t <= 4; ++t) REQUIRE(q.push(buf, 10, t, on_drop) == PushResult::queued);
    REQUIRE(q.push(buf, 10, 5, on_drop) == PushResult::queued_after_drop);  // packet limit
    REQUIRE(tags == std::vector<std::uint32_t>{1});
    REQUIRE(q.push(buf, 75, 6, on_drop) == PushResult::queued_after_drop);  // byte limit: 40 + 75 > 100
    REQUIRE(tags == std::vector<std::uint32_t>{1, 2, 3});
    REQUIRE(q.front_tag() == 4);
    REQUIRE(q.push(buf, 101, 7, on_drop) == PushResult::rejected_too_large);
    REQUIRE(tags.back() == 7);
    REQUIRE(q.packets() == 3);
    std::uint8_t small[5];
    REQUIRE(q.pop(small, sizeof small) == 0);  // does not fit: nothing removed
    REQUIRE(q.packets() == 3);
    q.clear();
    REQUIRE(q.empty());
    REQUIRE(q.stats().dropped_packets == 4);
}

TEST_CASE("fixed vector refuses to grow past its capacity", "[firmware][queue]") {
    FixedVector<int, 3> v;
    REQUIRE(v.push_back(1));
    REQUIRE(v.push_back(2));
    REQUIRE(v.push_back(3));
    REQUIRE_FALSE(v.push_back(4));
    REQUIRE(v.size() == 3);
    int sum = 0;
    for (int x : v) sum += x;
    REQUIRE(sum == 6);
}
