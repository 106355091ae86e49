// In-process pair, TCP client, URIs and the ping/pong clock offset estimator.
#include "eyesim/transport/clock_offset.hpp"
#include "eyesim/transport/inproc.hpp"
#include "eyesim/transport/tcp.hpp"

#include <catch2/catch.hpp>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <random>
#include <thread>

using namespace eyesim::transport;

TEST_CASE("in-process pair carries bytes both ways and reports close", "[transport][inproc]") {
    auto pair = make_inproc_pair(16);
    auto& a = pair.first;
    auto& b = pair.second;
    const std::vector<std::uint8_t> msg = {1, 2, 3, 4, 5};
    REQUIRE(a->write(msg, 10).bytes == 5);
    std::vector<std::uint8_t> buf(3);
    auto r = b->read(buf, 10);
    REQUIRE(r.bytes == 3);
    REQUIRE(buf == std::vector<std::uint8_t>{1, 2, 3});
    r = b->read(buf, 10);
    REQUIRE(r.bytes == 2);
    REQUIRE(b->read(buf, 5).status == IoStatus::timeout);
    // A full pipe makes the writer wait, then time out with what fitted.
    std::vector<std::uint8_t> big(40, 7);
    r = b->write(big, 20);
    REQUIRE(r.status == IoStatus::timeout);
    REQUIRE(r.bytes == 16);
    // A reader on another thread frees room: a blocking write completes.
    std::thread reader([&] {
        std::vector<std::uint8_t> sink(64);
        std::size_t total = 0;
        while (total < 16 + 40) total += a->read(sink, 200).bytes;
    });
    REQUIRE(b->write(big, 2000).bytes == 40);
    reader.join();
    a->close();
    REQUIRE(b->read(buf, 10).status == IoStatus::closed);
    REQUIRE(b->write(msg, 10).status == IoStatus::closed);
    REQUIRE_FALSE(b->connected());
}

TEST_CASE("TCP client talks to a loopback server; refused and malformed addresses say why", "[transport][tcp]") {
    const int lfd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in sa{};
    sa.sin_family = AF_INET;
    sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::bind(lfd, reinterpret_cast<sockaddr*>(&sa), sizeof sa) == 0);
    REQUIRE(::listen(lfd, 1) == 0);
    socklen_t len = sizeof sa;
    ::getsockname(lfd, reinterpret_cast<sockaddr*>(&sa), &len);
    const std::uint16_t port = ntohs(sa.sin_port);

    auto link = open_transport("tcp://127.0.0.1:" + std::to_string(port));
    const int cfd = ::accept(lfd, nullptr, nullptr);
    REQUIRE(cfd >= 0);
    REQUIRE(link->connected());
    REQUIRE(link->describe() == "tcp://127.0.0.1:" + std::to_string(port));
    const std::vector<std::uint8_t> cmd = {0xE7, 0x5A, 9, 8, 7};
    REQUIRE(link->write(cmd, 100).bytes == cmd.size());
    std::uint8_t got[16];
    REQUIRE(::recv(cfd, got, 5, MSG_WAITALL) == 5);
    REQUIRE(std::vector<std::uint8_t>(got, got + 5) == cmd);
    REQUIRE(::send(cfd, "\x01\x02\x03", 3, 0) == 3);
    std::vector<std::uint8_t> buf(8);
    auto r = link->read(buf, 1000);
    REQUIRE(r.status == IoStatus::ok);
    REQUIRE(r.bytes == 3);
    REQUIRE(link->read(buf, 10).status == IoStatus::timeout);
    ::close(cfd);
    REQUIRE(link->read(buf, 1000).status == IoStatus::closed);
    ::close(lfd);

    // The port is closed now: connection refused, one line naming the address.
    try {
        connect_tcp("127.0.0.1", port, 500);
        FAIL("connected to a closed port");
    } catch (const TransportError& e) {
        const std::string what = e.what();
        REQUIRE(what.rfind("tcp://127.0.0.1:" + std::to_string(port) + ": ", 0) == 0);
        REQUIRE(what.find("refused") != std::string::npos);
    }
    REQUIRE_THROWS_AS(open_transport("tcp://127.0.0.1"), TransportError);
    REQUIRE_THROWS_AS(open_transport("tcp://127.0.0.1:99999"), TransportError);
    REQUIRE_THROWS_AS(open_transport("tcp://127.0.0.1:12ab"), TransportError);
    REQUIRE_THROWS_AS(open_transport("serial:///dev/ttyS0"), TransportError);
    std::string host;
    std::uint16_t p = 0;
    parse_tcp_uri("tcp://[::1]:5100", host, p);
    REQUIRE(host == "::1");
    REQUIRE(p == 5100);
}

TEST_CASE("clock offset: exact for symmetric delays, min-delay sample bounds the error", "[transport][clock]") {
    const double true_offset = 12'345.0;  // device − host, µs
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> delay(20.0, 400.0);
    ClockOffsetEstimator est;
    double best_bound = 1e9;
    for (int i = 0; i < 40; ++i) {
        const double t0 = 1e6 + i * 1000.0;
        const double up = delay(rng), down = delay(rng), proc = 5.0;
        PingSample s;
        s.host_send_us = static_cast<std::int64_t>(t0);
        s.device_rx_us = static_cast<std::int64_t>(t0 + up + true_offset);
        s.device_tx_us = s.device_rx_us + static_cast<std::int64_t>(proc);
        s.host_recv_us = static_cast<std::int64_t>(t0 + up + proc + down);
        REQUIRE(est.add(s));
        // For this sample the NTP error is exactly (up - down) / 2, bounded by delay / 2.
        REQUIRE(std::abs(ping_offset_us(s) - true_offset) <= ping_delay_us(s) / 2 + 1);
        best_bound = std::min(best_bound, est.delay_us() / 2 + 1);
        REQUIRE(std::abs(est.offset_us() - true_offset) <= est.delay_us() / 2 + 1);
    }
    REQUIRE(est.samples() == 40);
    // A symmetric exchange (pong with one device time) gives the offset exactly.
    PingSample sym{1000, 1000 + 50 + 12'345, 1000 + 50 + 12'345, 1100};
    REQUIRE(ping_offset_us(sym) == Approx(true_offset));
    REQUIRE(ping_delay_us(sym) == Approx(100));
    REQUIRE(est.add(sym));
    REQUIRE(est.offset_us() == Approx(true_offset));
    REQUIRE(est.host_to_device_us(0) == Approx(true_offset));
    REQUIRE(est.device_to_host_us(true_offset) == Approx(0));
    // A sample with the host clock going backwards is refused.
    PingSample bad{2000, 5000, 5000, 1500};
    REQUIRE_FALSE(est.add(bad));
}
