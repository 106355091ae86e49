// The live link and replay paths against what was actually sent: loss counting on a lossy link (checked against
// the sender's own record of what it dropped), every way a link can end (FIN, RST, stall, a USB unplug and
// reconnect over the fake bulk endpoint), captures whose time goes backwards, and latency figures fed with known
// timestamps.
#include "eyesim/frame/loss.hpp"
#include "eyesim/frame/session.hpp"
#include "eyesim/protocol/capture.hpp"
#include "eyesim/protocol/codec.hpp"
#include "eyesim/protocol/stream_parser.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/rig/truth.hpp"
#include "eyesim/transport/tcp.hpp"
#include "eyesim/transport/usb.hpp"

#include "../transport/fake_usb.hpp"

#include <catch2/catch.hpp>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <thread>

using namespace eyesim;
namespace proto = eyesim::protocol;

namespace {

// ------------------------------------------------------------------------------------------------------------
// A realistic device stream: a short synthetic recording through the FPGA model, as messages.

struct Stream {
    std::vector<rig::CameraModel> cams;
    std::vector<tracking::SceneInstrument> instruments;
    std::vector<proto::Message> messages;  // in sending order
    std::vector<double> rx_us;             // modelled receive time of each
};

const Stream& recording_stream() {
    static const Stream s = [] {
        // One folder per process: CTest runs each test case as its own process, in parallel.
        const std::string dir =
            (std::filesystem::temp_directory_path() / ("eyesim_test_link_rec_" + std::to_string(::getpid()))).string();
        std::filesystem::remove_all(dir);
        rig::SynthRequest req;
        req.out_dir = dir;
        req.scenario = "surgery";
        req.seconds = 1.0;
        req.seed = 11;
        rig::write_recording(req);
        rig::Recording rec = rig::Recording::open(dir);
        Stream out;
        out.cams = rec.cameras();
        const std::vector<rig::FieldTruth> truth = rig::read_truth(rec.truth_path());
        for (const auto& it : truth[0].instruments) out.instruments.push_back({it.kind, it.trocar});
        proto::StreamParser parser;
        frame::for_each_recording_frame(rec, 0, [&](std::span<const uint8_t> bytes, double rx) {
            parser.parse(bytes, [&](const proto::DecodedFrame& f) {
                out.messages.push_back(f.message);
                out.rx_us.push_back(rx);
            });
        });
        std::filesystem::remove_all(dir);
        return out;
    }();
    return s;
}

std::vector<uint8_t> encode(const proto::Message& m, uint16_t seq) {
    std::array<uint8_t, proto::kMaxFrameBytes> buf{};
    const size_t n = proto::encode_frame(m, seq, buf);
    REQUIRE(n > 0);
    return {buf.begin(), buf.begin() + std::ptrdiff_t(n)};
}

frame::HostRun make_run() {
    const Stream& s = recording_stream();
    return frame::HostRun(frame::tracker_config(s.cams, rig::load_bodies(rig::default_bodies_path()), s.instruments));
}

/// Feeds whole frames (with receive times) straight into a run, as a replay would.
void feed(frame::HostRun& run, const std::vector<std::vector<uint8_t>>& frames, const std::vector<double>& rx) {
    run.set_run_clock(frame::RunClock::kRecorded);
    proto::StreamParser p;
    for (size_t i = 0; i < frames.size(); ++i)
        p.parse(frames[i], [&](const proto::DecodedFrame& f) { run.on_frame(f, rx[i]); });
    p.finish([&](const proto::DecodedFrame& f) { run.on_frame(f, rx.back()); });
    run.set_parser_stats(p.stats());
    run.finish();
}

std::string temp_path(const std::string& name) {
    return (std::filesystem::temp_directory_path() / (std::to_string(::getpid()) + "_" + name)).string();
}

// ------------------------------------------------------------------------------------------------------------
// A TCP device: accepts one host, sends `bytes`, then ends the link as asked.

enum class End { Fin, Reset };

/// A listening loopback socket on a free port.
int listen_loopback(int& port) {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
    REQUIRE(::listen(fd, 1) == 0);
    socklen_t n = sizeof a;
    ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &n);
    port = ntohs(a.sin_port);
    return fd;
}

class TcpDevice {
public:
    TcpDevice(std::vector<uint8_t> bytes, End end) : bytes_(std::move(bytes)), end_(end) {
        fd_ = listen_loopback(port_);
        thread_ = std::thread([this] { serve(); });
    }
    ~TcpDevice() {
        ::shutdown(fd_, SHUT_RDWR);
        ::close(fd_);
        if (thread_.joinable()) thread_.join();
    }
    std::string uri() const { return "tcp://127.0.0.1:" + std::to_string(port_); }

private:
    void serve() {
        const int c = ::accept(fd_, nullptr, nullptr);
        if (c < 0) return;
        for (size_t off = 0; off < bytes_.size();) {
            const ssize_t w = ::send(c, bytes_.data() + off, bytes_.size() - off, MSG_NOSIGNAL);
            if (w <= 0) break;
            off += size_t(w);
        }
        if (end_ == End::Reset) {
            // Like a killed process whose socket still holds unread commands: the kernel aborts with RST. Give the
            // host time to read what was sent first (the kernel drops what is unread when the RST arrives).
            std::this_thread::sleep_for(std::chrono::milliseconds(800));
            const linger lg{1, 0};
            ::setsockopt(c, SOL_SOCKET, SO_LINGER, &lg, sizeof lg);
            ::close(c);
            return;
        }
        ::shutdown(c, SHUT_WR);  // FIN, then swallow the host's commands until it hangs up
        char sink[4096];
        while (::recv(c, sink, sizeof sink, 0) > 0) {
        }
        ::close(c);
    }
    std::vector<uint8_t> bytes_;
    End end_;
    int fd_ = -1;
    int port_ = 0;
    std::thread thread_;
};

/// What a lossy sender dropped, by its own record.
struct Sent {
    std::vector<std::vector<uint8_t>> frames;  // delivered, in order
    std::vector<double> rx_us;
    uint64_t dropped = 0;
    uint64_t fields_never_sent = 0;  // camera fields of which no part was delivered (inside the delivered range)
};

/// The recording stream with DeviceStatus reports at the start and the end (queue_overflows 3 → 3 + overflows),
/// frames dropped at random with probability `p_drop` (never the first or last 5), numbered as the device would.
Sent lossy(double p_drop, uint32_t overflows, uint64_t seed) {
    const Stream& s = recording_stream();
    std::vector<proto::Message> msgs;
    proto::DeviceStatus st0;
    st0.queue_overflows = 3;
    st0.blobs_dropped = 10;
    msgs.push_back(st0);
    msgs.insert(msgs.end(), s.messages.begin(), s.messages.end());
    proto::DeviceStatus st1 = st0;
    st1.queue_overflows = 3 + overflows;
    msgs.push_back(st1);
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> u(0, 1);
    Sent out;
    std::map<int, std::set<uint32_t>> delivered_fields;
    for (size_t i = 0; i < msgs.size(); ++i) {
        const bool keep = i < 5 || i + 5 >= msgs.size() || u(rng) >= p_drop;
        if (!keep) {
            ++out.dropped;
            continue;
        }
        out.frames.push_back(encode(msgs[i], uint16_t(i)));  // sequence numbers count every frame made, sent or not
        out.rx_us.push_back(i == 0 ? 0.0 : s.rx_us[std::min(i - 1, s.rx_us.size() - 1)]);
        if (const auto* fm = std::get_if<proto::FieldMarkers>(&msgs[i])) delivered_fields[fm->camera_id].insert(fm->field_counter);
    }
    for (const auto& [cam, set] : delivered_fields)
        out.fields_never_sent += (*set.rbegin() - *set.begin() + 1) - set.size();
    return out;
}

std::vector<uint8_t> concat(const std::vector<std::vector<uint8_t>>& frames) {
    std::vector<uint8_t> b;
    for (const auto& f : frames) b.insert(b.end(), f.begin(), f.end());
    return b;
}

}  // namespace

// ------------------------------------------------------------------------------------------------------------

TEST_CASE("loss counter: frames lost, repeated and late match what a random lossy channel did", "[host][link]") {
    // Reference: the channel's own record. Sequence numbers wrap at 65535 during the run.
    for (uint64_t seed = 1; seed <= 20; ++seed) {
        std::mt19937_64 rng(seed);
        std::uniform_real_distribution<double> u(0, 1);
        std::vector<uint16_t> sent;
        const uint16_t start = uint16_t(65000 + seed * 7);
        for (int i = 0; i < 5000; ++i) sent.push_back(uint16_t(start + i));
        std::vector<uint16_t> got;
        for (size_t i = 0; i < sent.size(); ++i) {
            if (i > 0 && i + 1 < sent.size() && u(rng) < 0.05) continue;          // dropped
            got.push_back(sent[i]);
            if (u(rng) < 0.02) got.push_back(sent[i]);                           // repeated
        }
        uint64_t late = 0;
        std::set<uint16_t> before;  // values already in got[0, i)
        for (size_t i = 0; i + 1 < got.size(); ++i) {  // adjacent swaps of two first copies: one late frame each
            if (i > 0 && got[i] != got[i + 1] && !before.count(got[i]) && !before.count(got[i + 1]) && u(rng) < 0.02) {
                std::swap(got[i], got[i + 1]);
                ++late;
                before.insert(got[i]);
                ++i;
            }
            before.insert(got[i]);
        }
        std::set<uint16_t> distinct(got.begin(), got.end());
        frame::LossCounter lc;
        proto::DecodedFrame f;
        f.message = proto::PedalState{};
        for (uint16_t q : got) {
            f.header.sequence = q;
            lc.observe(f);
        }
        INFO("seed " << seed);
        CHECK(lc.counts().frames_lost == sent.size() - distinct.size());
        CHECK(lc.counts().frames_repeated == got.size() - distinct.size());
        CHECK(lc.counts().frames_late == late);
        CHECK(lc.counts().frames == got.size());
    }
    // A clean stream counts nothing; a restarted device (sequence back to 0 far behind) is not a loss.
    frame::LossCounter lc;
    proto::DecodedFrame f;
    f.message = proto::PedalState{};
    for (int i = 0; i < 3000; ++i) {
        f.header.sequence = uint16_t(i < 2000 ? i : i - 2000);
        lc.observe(f);
    }
    CHECK(lc.counts().frames_lost == 0);
    CHECK(lc.counts().frames_repeated == 0);
    CHECK(lc.counts().sequence_gaps == 1);
}

TEST_CASE("a lossy link: track counts every frame, field and device overflow that was lost", "[host][link][e2e]") {
    for (uint64_t seed : {3u, 4u}) {
        const Sent sent = lossy(0.04, 7, seed);
        REQUIRE(sent.dropped > 5);
        TcpDevice dev(concat(sent.frames), End::Fin);
        frame::HostRun run = make_run();
        frame::LiveOptions lo;
        lo.stall_seconds = 3.0;
        const frame::LiveResult res = frame::run_live(dev.uri(), run, lo);
        const frame::LossCounts& c = run.stats().loss;
        INFO("seed " << seed << ": " << frame::loss_summary(c));
        CHECK(res.end == "device closed the link");
        CHECK(res.clean);
        CHECK(c.frames_lost == sent.dropped);
        CHECK(c.sequence_gaps > 0);
        CHECK(c.sequence_gaps <= sent.dropped);
        CHECK(c.fields_lost == sent.fields_never_sent);
        CHECK(c.device_queue_overflows == 7);
        CHECK(c.device_blobs_dropped == 0);
        CHECK(c.frames == sent.frames.size());
        CHECK(c.parse_errors == 0);
        CHECK(c.any());
        CHECK(frame::loss_summary(c).find(std::to_string(sent.dropped) + " frames lost") != std::string::npos);
        CHECK(run.stats().frames > 20);
    }
}

TEST_CASE("a link that ends with RST keeps every pose of what arrived, like FIN and like a replay", "[host][link][e2e]") {
    const Sent sent = lossy(0.0, 0, 1);
    frame::HostRun replay = make_run();
    feed(replay, sent.frames, sent.rx_us);
    REQUIRE(replay.stats().frames > 30);
    for (End end : {End::Fin, End::Reset}) {
        TcpDevice dev(concat(sent.frames), end);
        frame::HostRun run = make_run();
        frame::LiveOptions lo;
        lo.stall_seconds = 5.0;
        const frame::LiveResult res = frame::run_live(dev.uri(), run, lo);
        INFO((end == End::Fin ? "FIN" : "RST") << ": " << res.end);
        if (end == End::Reset) {
            // The kernel discards what the host had not read when the RST came (rare: the device waits 0.8 s).
            // Every pose of what did arrive is kept: the same as replaying exactly those frames.
            const size_t got = size_t(run.stats().loss.frames);
            REQUIRE(got > sent.frames.size() / 2);
            frame::HostRun prefix = make_run();
            feed(prefix, {sent.frames.begin(), sent.frames.begin() + std::ptrdiff_t(got)},
                 {sent.rx_us.begin(), sent.rx_us.begin() + std::ptrdiff_t(got)});
            CHECK(run.stats().frames == prefix.stats().frames);
        } else {
            CHECK(run.stats().frames == replay.stats().frames);
            CHECK(run.stats().loss.frames == sent.frames.size());
        }
        if (end == End::Reset) {
            CHECK(res.end == "connection reset by peer");
            CHECK_FALSE(res.clean);
            REQUIRE(!res.warnings.empty());
            CHECK(res.warnings.back().find(dev.uri() + ": connection reset by peer") == 0);
        } else {
            CHECK(res.end == "device closed the link");
            CHECK(res.clean);
            CHECK(res.warnings.empty());
        }
    }
}

TEST_CASE("track over USB reconnects after an unplug and goes on tracking (fake bulk endpoint)", "[host][link][usb]") {
    const Sent sent = lossy(0.0, 0, 1);
    auto bus = std::make_shared<test::FakeBus>();
    std::atomic<bool> stop{false};
    std::atomic<int> starts{0};
    const size_t half = sent.frames.size() / 2;
    std::thread device([&] {
        // The device: streams after each stream_start; halfway it is unplugged for 300 ms and comes back as a
        // fresh device (not streaming) that streams the second half after the next stream_start.
        size_t next = 0, seen_out = 0;
        bool unplugged = false;
        while (!stop) {
            bool start = false;
            {
                std::scoped_lock lock(bus->m);
                for (; seen_out < bus->out_transfers.size(); ++seen_out) {
                    proto::DecodedFrame f;
                    size_t used = 0;
                    if (proto::decode_frame(bus->out_transfers[seen_out], f, used) == proto::DecodeError::None)
                        if (const auto* c = std::get_if<proto::Command>(&f.message); c && c->opcode == uint8_t(proto::Opcode::StreamStart))
                            start = true;
                }
            }
            if (start) {
                ++starts;
                const size_t until = starts == 1 ? half : sent.frames.size();
                for (; next < until; ++next) bus->device_send(sent.frames[next]);
                if (starts == 1 && !unplugged) {
                    std::this_thread::sleep_for(std::chrono::milliseconds(300));  // the host reads the first half
                    bus->unplug();
                    unplugged = true;
                    std::this_thread::sleep_for(std::chrono::milliseconds(300));
                    bus->replug();
                }
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(2));
        }
    });
    transport::UsbOptions uo;
    uo.reconnect_initial_ms = 10;
    uo.reconnect_max_ms = 50;
    transport::UsbTransport link(std::make_unique<test::FakeBackend>(bus), uo);
    std::string why;
    REQUIRE(link.open_first(why));
    frame::HostRun run = make_run();
    frame::LiveOptions lo;
    lo.stall_seconds = 1.5;
    const frame::LiveResult res = frame::run_live(link, run, lo);
    stop = true;
    device.join();
    frame::HostRun replay = make_run();
    feed(replay, sent.frames, sent.rx_us);
    CHECK(starts == 2);
    CHECK(link.stats().reconnects == 1);
    CHECK(run.stats().loss.link_drops == 1);
    CHECK(run.stats().loss.frames == sent.frames.size());  // nothing was in flight during the unplug
    CHECK(run.stats().loss.frames_lost == 0);
    // A few frames at the break are built from one side of it only.
    CHECK(run.stats().frames + 3 >= replay.stats().frames);
    CHECK(res.end.find("device stalled") != std::string::npos);  // it never closes: the run ends by the stall time
    bool lost = false, back = false;
    for (const auto& w : res.warnings) {
        lost = lost || w.find("usb://1209:0001: device lost (no_device); reconnecting") == 0;
        back = back || w.find("device back after") != std::string::npos;
    }
    CHECK(lost);
    CHECK(back);
}

namespace {
/// Writes `frames` as capture records.
void write_capture(const std::string& path, const std::vector<std::vector<uint8_t>>& frames, const std::vector<double>& rx_us) {
    proto::CaptureWriter w;
    REQUIRE(w.create(path.c_str()));
    for (size_t i = 0; i < frames.size(); ++i) REQUIRE(w.write(uint64_t(std::llround(rx_us[i])), frames[i]));
    w.close();
}
}  // namespace

TEST_CASE("a capture whose time goes backwards is replayed segment by segment, with a warning naming the byte", "[host][link]") {
    const Sent sent = lossy(0.0, 0, 1);
    const std::string path = temp_path("eyesim_test_link_order.capture");
    write_capture(path, sent.frames, sent.rx_us);
    frame::HostRun clean = make_run();
    std::vector<std::string> warnings;
    frame::run_capture(path, clean, warnings);
    CHECK(warnings.empty());
    const uint64_t n = clean.stats().frames;
    REQUIRE(n > 30);

    // The byte offset of record k: header 16, then 12 + L + 4 per record.
    auto offset_of = [&](const std::vector<std::vector<uint8_t>>& frames, size_t k) {
        uint64_t off = 16;
        for (size_t i = 0; i < k; ++i) off += 16 + frames[i].size();
        return off;
    };
    SECTION("halves swapped") {
        const size_t h = sent.frames.size() / 2;
        std::vector<std::vector<uint8_t>> f(sent.frames.begin() + std::ptrdiff_t(h), sent.frames.end());
        std::vector<double> rx(sent.rx_us.begin() + std::ptrdiff_t(h), sent.rx_us.end());
        f.insert(f.end(), sent.frames.begin(), sent.frames.begin() + std::ptrdiff_t(h));
        rx.insert(rx.end(), sent.rx_us.begin(), sent.rx_us.begin() + std::ptrdiff_t(h));
        write_capture(path, f, rx);
        frame::HostRun run = make_run();
        frame::run_capture(path, run, warnings);
        const std::string at = "at byte " + std::to_string(offset_of(f, sent.frames.size() - h));
        bool named_rx = false, named_segment = false;
        for (const auto& w : warnings) {
            named_rx = named_rx || (w.find("receive time goes back") != std::string::npos && w.find(at) != std::string::npos);
            // Device time is seen at the first FieldMarkers after the boundary (a DeviceStatus and a PedalState
            // come first): its record, a few after the boundary.
            const auto p = w.find("device time goes back at byte ");
            if (p != std::string::npos) {
                const uint64_t byte = std::stoull(w.substr(p + 30));
                const uint64_t boundary = offset_of(f, sent.frames.size() - h);
                named_segment = byte >= boundary && byte < boundary + 4 * 512;
            }
        }
        INFO(warnings.size() << " warnings; " << (warnings.empty() ? "" : warnings[0]));
        CHECK(named_rx);
        CHECK(named_segment);
        CHECK(run.stats().loss.time_jumps == 1);
        CHECK(run.stats().frames + 4 >= n);  // each segment starts cold: a frame or two at each edge
    }
    SECTION("two captures joined") {
        std::vector<std::vector<uint8_t>> f = sent.frames;
        std::vector<double> rx = sent.rx_us;
        f.insert(f.end(), sent.frames.begin(), sent.frames.end());
        rx.insert(rx.end(), sent.rx_us.begin(), sent.rx_us.end());
        write_capture(path, f, rx);
        frame::HostRun run = make_run();
        frame::run_capture(path, run, warnings);
        CHECK(run.stats().loss.time_jumps == 1);
        CHECK(run.stats().frames == 2 * n);
        CHECK(run.stats().loss.frames_lost == 0);  // the sequence restarts far behind: a new sender, not a loss
        REQUIRE(!warnings.empty());
        CHECK(warnings[0].find("at byte " + std::to_string(offset_of(f, sent.frames.size()))) != std::string::npos);
    }
    std::filesystem::remove(path);
}

TEST_CASE("latency figures are differences of the clocks they name, fed with known timestamps", "[host][link]") {
    // Three cameras' fields with known device field ends; every packet received 1500 µs after its field end on
    // the host clock, which runs 5 s behind the device clock (pongs say so exactly: zero round trip).
    const Stream& s = recording_stream();
    const double offset_us = 5e6;  // device − host
    std::vector<std::vector<uint8_t>> frames;
    std::vector<double> rx;
    uint16_t seq = 0;
    auto pong = [&](double host_us) {
        proto::Reply r;
        r.opcode = uint8_t(proto::Opcode::Ping);
        r.host_us = uint64_t(host_us);
        r.device_us = uint64_t(host_us + offset_us);
        frames.push_back(encode(r, seq++));
        rx.push_back(host_us);
    };
    double last_end_host = 0;
    for (const proto::Message& m : s.messages) {
        proto::Message c = m;
        if (auto* fm = std::get_if<proto::FieldMarkers>(&c)) {
            fm->field_end_us += uint64_t(offset_us);
            for (uint8_t k = 0; k < fm->marker_count; ++k) fm->markers[k].complete_us += uint64_t(offset_us);
            last_end_host = double(fm->field_end_us) - offset_us;
            if (frames.size() % 40 == 0) pong(last_end_host + 1000.0);  // before the field's packet arrives
            frames.push_back(encode(c, seq++));
            rx.push_back(last_end_host + 1500.0);
        }
    }
    pong(last_end_host + 600000.0);  // a last pong after the stream: the pongs span more than the 1 s a rate needs
    frame::HostRun run = make_run();
    const std::string path = temp_path("eyesim_test_link_latency.capture");
    write_capture(path, frames, rx);
    std::vector<std::string> warnings;
    frame::run_capture(path, run, warnings);
    const frame::RunStats& st = run.stats();
    REQUIRE(st.frames > 30);
    REQUIRE(st.latency_us.count == st.frames - 0);
    CHECK(run.clock().offset_us() == Approx(offset_us).margin(1.0));
    CHECK(st.device_clock_rate == Approx(1.0).margin(1e-6));
    for (size_t i = 0; i < st.latency_us.v.size(); ++i) {
        // field end → received: exactly the 1500 µs put in (the frame's newest field arrived last)
        CHECK(st.transfer_us.v[i] == Approx(1500.0).margin(1.5));
        // field end → poses ready = received → poses ready (the compute time here) + transfer
        CHECK(st.latency_us.v[i] == Approx(st.transfer_us.v[i] + st.ready_us.v[i]).margin(1.5));
        CHECK(st.ready_us.v[i] >= 0.0);
        CHECK(st.ready_us.v[i] < 20000.0);
    }
    CHECK(st.latency_note.empty());

    // The same stream from a device whose clock runs twice as fast: its field ends cannot be placed on the host
    // clock, and the run says so instead of printing a negative or drifting figure.
    for (auto& f : frames) {
        proto::DecodedFrame d;
        size_t used = 0;
        REQUIRE(proto::decode_frame(f, d, used) == proto::DecodeError::None);
        if (auto* r = std::get_if<proto::Reply>(&d.message)) {
            r->device_us = uint64_t(2.0 * double(r->host_us) + offset_us);
            f = encode(*r, d.header.sequence);
        }
    }
    write_capture(path, frames, rx);
    frame::HostRun fast = make_run();
    frame::run_capture(path, fast, warnings);
    CHECK(fast.stats().latency_us.empty());
    CHECK(fast.stats().device_clock_rate == Approx(2.0).epsilon(0.01));
    CHECK(fast.stats().latency_note.find("not at real-time pace") != std::string::npos);
    CHECK(fast.stats().ready_us.count == fast.stats().frames);
    std::filesystem::remove(path);
}

TEST_CASE("a recording through the modelled link: latencies on the modelled clock, never the host's uptime", "[host][link]") {
    const Stream& s = recording_stream();
    std::vector<std::vector<uint8_t>> frames;
    for (size_t i = 0; i < s.messages.size(); ++i) frames.push_back(encode(s.messages[i], uint16_t(i)));
    frame::HostRun run = make_run();
    run.set_clock_offset_us(0.0);
    feed(run, frames, s.rx_us);
    const frame::RunStats& st = run.stats();
    REQUIRE(st.latency_us.count == st.frames);
    for (size_t i = 0; i < st.latency_us.v.size(); ++i) {
        CHECK(st.transfer_us.v[i] > 0.0);
        CHECK(st.transfer_us.v[i] < 2000.0);  // queue + USB link of one field's parts
        CHECK(st.latency_us.v[i] >= st.transfer_us.v[i]);
        CHECK(st.latency_us.v[i] < 50000.0);
    }
}

TEST_CASE("soak: 30 minutes of live streaming through a lossy loopback link, memory flat, every loss counted",
          "[host][link][stress]") {
    // EYESIM_SOAK_SECONDS shortens it for a quick look; the stress label runs the full 30 minutes.
    const char* env = std::getenv("EYESIM_SOAK_SECONDS");
    const double seconds = env ? std::atof(env) : 1800.0;
    const Stream& s = recording_stream();
    const double period_us = 1e6;  // the recording is 1 s long; it is played in a loop with time running on
    int port = 0;
    const int lfd = listen_loopback(port);
    const std::string uri = "tcp://127.0.0.1:" + std::to_string(port);
    std::atomic<uint64_t> dropped{0};
    std::thread device([&] {
        const int c = ::accept(lfd, nullptr, nullptr);
        if (c < 0) return;
        std::mt19937_64 rng(99);
        std::uniform_real_distribution<double> u(0, 1);
        uint16_t seq = 0;
        const auto t0 = std::chrono::steady_clock::now();
        bool ok = true;
        for (uint64_t loop = 0; ok; ++loop) {
            const double elapsed_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            const bool last = elapsed_s + 1.0 >= seconds;
            for (size_t i = 0; i < s.messages.size() && ok; ++i) {
                proto::Message m = s.messages[i];
                const uint64_t shift = uint64_t(double(loop) * period_us);
                if (auto* fm = std::get_if<proto::FieldMarkers>(&m)) {
                    fm->field_end_us += shift;
                    fm->field_counter += uint32_t(loop * 50);
                    for (uint8_t k = 0; k < fm->marker_count; ++k) fm->markers[k].complete_us += shift;
                } else if (auto* p = std::get_if<proto::PedalState>(&m)) {
                    p->device_us += shift;
                }
                // Real-time pace: send each frame at its modelled receive time.
                const double due_s = (double(loop) * period_us + s.rx_us[i]) * 1e-6;
                const double now_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
                if (due_s > now_s) std::this_thread::sleep_for(std::chrono::duration<double>(due_s - now_s));
                const std::vector<uint8_t> b = encode(m, seq++);
                if (!last && u(rng) < 0.01) {  // the lossy link: 1 % of frames never arrive
                    ++dropped;
                    continue;
                }
                ok = ::send(c, b.data(), b.size(), MSG_NOSIGNAL) == ssize_t(b.size());
            }
            if (last) break;
        }
        ::shutdown(c, SHUT_WR);
        char sink[4096];
        while (::recv(c, sink, sizeof sink, 0) > 0) {
        }
        ::close(c);
    });
    auto rss_kib = [] {
        std::ifstream f("/proc/self/statm");
        long pages = 0, resident = 0;
        f >> pages >> resident;
        return double(resident) * double(::sysconf(_SC_PAGESIZE)) / 1024.0;
    };
    frame::HostRun run = make_run();
    double rss_warm = 0, rss_peak = 0;
    const double warm_s = std::min(60.0, 0.2 * seconds);
    const auto t0 = std::chrono::steady_clock::now();
    run.set_hook([&](const tracking::TrackingFrame&, const frame::FramePoses&) {
        const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        if (rss_warm == 0 && t >= warm_s) rss_warm = rss_kib();
        if (rss_warm > 0 && run.stats().frames % 500 == 0) rss_peak = std::max(rss_peak, rss_kib());
    });
    frame::LiveOptions lo;
    lo.stall_seconds = 5.0;
    const frame::LiveResult res = frame::run_live(uri, run, lo);
    device.join();
    ::close(lfd);
    rss_peak = std::max(rss_peak, rss_kib());
    const frame::LossCounts& c = run.stats().loss;
    INFO(res.end << "; " << frame::loss_summary(c) << "; RSS " << rss_warm << " → " << rss_peak << " KiB");
    std::printf("soak: %.0f s, %llu tracking frames, %llu frames dropped by the link, %llu counted lost; RSS %.0f KiB "
                "after %.0f s, peak %.0f KiB\n",
                seconds, static_cast<unsigned long long>(run.stats().frames), static_cast<unsigned long long>(dropped.load()),
                static_cast<unsigned long long>(c.frames_lost), rss_warm, warm_s, rss_peak);
    CHECK(res.end == "device closed the link");
    CHECK(c.frames_lost == dropped.load());
    CHECK(dropped.load() > 0);
    CHECK(c.parse_errors == 0);
    CHECK(run.stats().frames >= uint64_t(seconds * 50 * 0.9));
    REQUIRE(rss_warm > 0);
    CHECK(rss_peak <= rss_warm * 1.05);
}
