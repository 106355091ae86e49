// USB transport framing and reconnect over a fake bulk endpoint; the libusb backend with no device present.
#include "fake_usb.hpp"

#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/stream_parser.hpp"
#include "eyesim/transport/usb.hpp"

#include <catch2/catch.hpp>

#include <cstdio>
#include <cstdlib>
#include <string>

using namespace eyesim;
using transport::IoStatus;
using transport::UsbTransport;

namespace {

std::vector<std::uint8_t> frame_of(const protocol::Message& m, std::uint16_t seq) {
    std::vector<std::uint8_t> f(protocol::kMaxFrameBytes);
    f.resize(protocol::encode_frame(m, seq, f));
    REQUIRE(!f.empty());
    return f;
}

protocol::FieldMarkers field_with(int markers, std::uint32_t counter) {
    protocol::FieldMarkers fm;
    fm.camera_id = 1;
    fm.field_counter = counter;
    fm.field_end_us = 20000ull * counter + 19000;
    fm.marker_count = static_cast<std::uint8_t>(markers);
    for (int i = 0; i < markers; ++i) {
        auto& m = fm.markers[i];
        m.colour_class = static_cast<std::uint8_t>(1 + i % 4);
        m.bbox_x0 = static_cast<std::uint16_t>(10 * i);
        m.bbox_x1 = static_cast<std::uint16_t>(10 * i + 5);
        m.bbox_y0 = 3;
        m.bbox_y1 = 9;
        m.x_q16 = static_cast<std::uint32_t>((10 * i + 2) * 65536 + i);
        m.y_q16 = 6 * 65536;
        m.area_px = 30;
        m.intensity_sum = 3000;
        m.complete_us = 20000ull * counter + 500;
    }
    return fm;
}

std::unique_ptr<UsbTransport> make(std::shared_ptr<test::FakeBus> bus, bool hotplug = true) {
    transport::UsbOptions o;
    o.reconnect_initial_ms = 5;
    o.reconnect_max_ms = 40;
    auto t = std::make_unique<UsbTransport>(std::make_unique<test::FakeBackend>(bus, hotplug), o);
    std::string why;
    REQUIRE(t->open_first(why));
    return t;
}

/// Reads through the transport in `chunk`-byte reads until `want` frames decoded or a read times out.
std::vector<protocol::DecodedFrame> read_frames(UsbTransport& t, std::size_t want, std::size_t chunk = 100) {
    std::vector<protocol::DecodedFrame> out;
    protocol::StreamParser parser;
    std::vector<std::uint8_t> buf(chunk);
    for (int i = 0; i < 10000 && out.size() < want; ++i) {
        const auto r = t.read(buf, 20);
        if (r.status == IoStatus::timeout) break;
        if (r.status == IoStatus::error) continue;  // device away: the next read retries the reconnect
        REQUIRE(r.status == IoStatus::ok);
        parser.parse(std::span<const std::uint8_t>(buf.data(), r.bytes),
                     [&](const protocol::DecodedFrame& f) { out.push_back(f); });
    }
    REQUIRE(parser.stats().errors() == 0);
    return out;
}

}  // namespace

TEST_CASE("USB IN: frames split into bulk packets come out as the same byte stream", "[transport][usb]") {
    auto bus = std::make_shared<test::FakeBus>();
    auto t = make(bus);
    std::vector<protocol::Message> sent;
    // One frame per transfer (506 bytes: a short last packet), two frames per transfer, small replies, and a
    // transfer of exactly two packets (1024 bytes) that needs a zero-length packet to end.
    sent.push_back(field_with(14, 1));
    bus->device_send(frame_of(sent.back(), 0));
    protocol::Reply r;
    r.command_id = 9;
    r.host_us = 123;
    sent.push_back(r);
    sent.push_back(field_with(3, 2));
    auto two = frame_of(sent[1], 1);
    auto more = frame_of(sent[2], 2);
    two.insert(two.end(), more.begin(), more.end());
    bus->device_send(two);
    std::vector<std::uint8_t> exact;
    std::uint16_t seq = 3;
    while (exact.size() < 1024) {
        protocol::PedalState p;
        p.device_us = seq;
        p.axes[0] = static_cast<std::uint16_t>(100 * seq);
        auto f = frame_of(p, seq++);
        if (exact.size() + f.size() > 1024) {
            exact.resize(1024, 0x00);  // pad with garbage the parser skips
            break;
        }
        exact.insert(exact.end(), f.begin(), f.end());
        sent.push_back(p);
    }
    bus->device_send(exact);
    const std::size_t packets_before = bus->in_packets.size();
    REQUIRE(packets_before == 1 + 1 + 3);  // 506 B: 1 short packet; 33 + 119 B: 1 short; 1024 B: 2 full + ZLP
    for (const std::size_t chunk : {std::size_t{7}, std::size_t{100000}}) {
        DYNAMIC_SECTION("read chunk " << chunk) {
            const auto frames = read_frames(*t, sent.size(), chunk);
            REQUIRE(frames.size() == sent.size());
            for (std::size_t i = 0; i < sent.size(); ++i) REQUIRE(frames[i].message == sent[i]);
            // Every IN request was a whole number of packets (no overflow possible) and large enough for a frame.
            for (auto n : bus->in_request_sizes) {
                REQUIRE(n % bus->mps == 0);
                REQUIRE(n >= protocol::kMaxFrameBytes);
            }
            std::uint8_t rest[64];
            while (t->read(rest, 5).status == IoStatus::ok) {}  // the padding after the last frame
            REQUIRE(bus->in_packets.empty());
            REQUIRE(t->stats().in_transfers == 3);  // the ZLP ended the 1024-byte transfer, it is not one itself
        }
    }
}

TEST_CASE("USB OUT: one transfer per write, a zero-length packet after an exact multiple", "[transport][usb]") {
    for (const std::uint16_t mps : {transport::kUsbMaxPacketHighSpeed, transport::kUsbMaxPacketFullSpeed}) {
        DYNAMIC_SECTION("wMaxPacketSize " << mps) {
            auto bus = std::make_shared<test::FakeBus>();
            bus->mps = mps;
            auto t = make(bus);
            protocol::Command c;
            c.command_id = 5;
            c.opcode = 5;
            const auto cmd = frame_of(c, 0);  // 33 bytes
            std::vector<std::uint8_t> exact(2 * mps, 0xAB);
            std::vector<std::uint8_t> odd(mps + 1, 0xCD);
            REQUIRE(t->write(cmd, 100).bytes == cmd.size());
            REQUIRE(t->write(exact, 100).bytes == exact.size());
            REQUIRE(t->write(odd, 100).bytes == odd.size());
            REQUIRE(t->write(cmd, 100).status == IoStatus::ok);
            // The device saw four separate transfers: the ZLP kept `exact` from merging with `odd`.
            REQUIRE(bus->out_transfers.size() == 4);
            REQUIRE(bus->out_transfers[0] == cmd);
            REQUIRE(bus->out_transfers[1] == exact);
            REQUIRE(bus->out_transfers[2] == odd);
            REQUIRE(bus->out_transfers[3] == cmd);
            REQUIRE(t->stats().zero_length_out == 1);
        }
    }
}

TEST_CASE("USB unplug and replug: clear errors while away, reconnect with backoff, data flows again",
          "[transport][usb]") {
    for (const bool hotplug : {true, false}) {
        DYNAMIC_SECTION("hotplug " << hotplug) {
            auto bus = std::make_shared<test::FakeBus>();
            auto t = make(bus, hotplug);
            protocol::PedalState p;
            p.device_us = 1;
            bus->device_send(frame_of(p, 0));
            REQUIRE(read_frames(*t, 1).size() == 1);

            bus->unplug();
            std::uint8_t buf[64];
            auto r = t->read(buf, 10);
            REQUIRE(r.status == IoStatus::error);
            REQUIRE_FALSE(t->connected());
            REQUIRE(t->last_error().find("device lost") != std::string::npos);
            // While it is away, reads keep failing within their timeout; attempts are spaced by the backoff.
            const int opens_before = bus->opens;
            for (int i = 0; i < 5; ++i) REQUIRE(t->read(buf, 30).status == IoStatus::error);
            const int attempts = bus->opens - opens_before;
            REQUIRE(attempts >= 2);
            REQUIRE(attempts <= 30);  // 150 ms of retries at 5..40 ms spacing, not a busy loop
            REQUIRE(t->write(std::span<const std::uint8_t>(buf, 4), 10).status == IoStatus::error);
            REQUIRE(t->last_error().find("reconnecting") != std::string::npos);

            bus->replug();
            p.device_us = 2;
            bus->device_send(frame_of(p, 1));
            const auto frames = read_frames(*t, 1);
            REQUIRE(frames.size() == 1);
            REQUIRE(std::get<protocol::PedalState>(frames[0].message).device_us == 2);
            REQUIRE(t->connected());
            REQUIRE(t->stats().disconnects == 1);
            REQUIRE(t->stats().reconnects == 1);
        }
    }
}

TEST_CASE("USB URIs", "[transport][usb]") {
    const auto def = transport::parse_usb_uri("usb");
    REQUIRE(def.vendor_id == 0x1209);
    REQUIRE(def.product_id == 0x0001);
    const auto ids = transport::parse_usb_uri("usb://cafe:00ff");
    REQUIRE(ids.vendor_id == 0xCAFE);
    REQUIRE(ids.product_id == 0x00FF);
    REQUIRE_THROWS_AS(transport::parse_usb_uri("usb://12:34"), transport::TransportError);
    REQUIRE_THROWS_AS(transport::parse_usb_uri("usb://1209:0001x"), transport::TransportError);
    REQUIRE_THROWS_AS(transport::parse_usb_uri("usbx"), transport::TransportError);
}

TEST_CASE("libusb with no device attached: a clear error, and eyesim-usb-probe exits non-zero", "[transport][usb]") {
    transport::UsbIds ids;
    std::vector<transport::UsbDeviceInfo> present;
    try {
        present = transport::list_usb_devices(ids);
    } catch (const transport::TransportError& e) {
        // No USB subsystem at all (containers): connecting must still fail with a clear message.
        INFO(e.what());
    }
    if (!present.empty()) {
        WARN("an eyesim USB device is attached: the no-device checks are skipped");
        return;
    }
    try {
        transport::connect_usb();
        FAIL("connect_usb succeeded without a device");
    } catch (const transport::TransportError& e) {
        const std::string what = e.what();
        INFO(what);
        REQUIRE(what.find("usb://1209:0001") == 0);
        REQUIRE((what.find("no device found") != std::string::npos || what.find("libusb") != std::string::npos));
        REQUIRE(what.find('\n') == std::string::npos);
    }
    const std::string out = std::string(EYESIM_TEST_TMP) + "/usb_probe.err";
    const std::string cmd = std::string(EYESIM_USB_PROBE) + " 2> " + out;
    const int rc = std::system(cmd.c_str());
    REQUIRE(rc != 0);
    std::FILE* f = std::fopen(out.c_str(), "r");
    REQUIRE(f != nullptr);
    char line[512] = {};
    REQUIRE(std::fgets(line, sizeof line, f) != nullptr);
    std::fclose(f);
    REQUIRE(std::string(line).rfind("eyesim-usb-probe: error: usb://1209:0001", 0) == 0);
}
