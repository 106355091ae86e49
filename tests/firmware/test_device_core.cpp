// Firmware core under a modelled clock and a fake transport: packets against the FPGA model, queue overflow,
// command validation, register timing, ping/pong, latency, no heap after start-up.
#include "core_rig.hpp"

#include "eyesim/firmware/registers.hpp"
#include "eyesim/fpga/timing.hpp"
#include "eyesim/protocol/codec.hpp"

#include <catch2/catch.hpp>

#include <algorithm>
#include <atomic>
#include <set>
#include <cstdlib>
#include <new>

#include "alloc_counter.hpp"

using namespace eyesim;
using test::CoreRig;
using test::FieldMap;

namespace {

protocol::Command cmd(std::uint32_t id, protocol::Opcode op, std::uint32_t address = 0, std::uint32_t value = 0,
                      std::uint64_t host_us = 0) {
    protocol::Command c;
    c.command_id = id;
    c.opcode = static_cast<std::uint8_t>(op);
    c.address = address;
    c.value = value;
    c.host_us = host_us;
    return c;
}

/// Assembles FieldMarkers parts into fields, checking the part rules of docs/protocol.md on the way.
FieldMap assemble(const std::vector<protocol::DecodedFrame>& frames, bool low_latency) {
    FieldMap out;
    std::map<test::FieldKey, int> next_part;
    std::map<test::FieldKey, bool> closed;
    for (const auto& f : frames) {
        const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message);
        if (!fm) continue;
        const test::FieldKey key{fm->camera_id, fm->field_counter};
        INFO("camera " << int(fm->camera_id) << " field " << fm->field_counter << " part " << fm->part_index);
        REQUIRE_FALSE(closed[key]);
        REQUIRE(fm->part_index == next_part[key]++);
        REQUIRE(((fm->flags & protocol::kFieldFlagLowLatency) != 0) == low_latency);
        const bool last = (fm->flags & protocol::kFieldFlagMoreFollows) == 0;
        if (last) {
            closed[key] = true;
            REQUIRE(fm->field_end_us > 0);
        } else if (low_latency) {
            REQUIRE(fm->field_end_us == 0);
        }
        auto& v = out[key];
        for (int i = 0; i < fm->marker_count; ++i) v.push_back(fm->markers[i]);
    }
    for (const auto& [key, c] : closed) REQUIRE(c);
    return out;
}

}  // namespace

TEST_CASE("core packets equal the FPGA model's markers, per field and per blob", "[firmware][core]") {
    const int fields = 6;
    for (const bool low_latency : {false, true}) {
        DYNAMIC_SECTION("low_latency=" << low_latency) {
            firmware::CoreConfig cfg;
            cfg.low_latency = low_latency;
            CoreRig rig(fields, 20, cfg);  // 20 markers: more than one part per field
            rig.command(cmd(1, protocol::Opcode::StreamStart));
            rig.run();
            protocol::ParserStats stats;
            const auto frames = test::decode_all(rig.sink.bytes, &stats);
            REQUIRE(stats.errors() == 0);
            REQUIRE(stats.sequence_gaps == 0);
            const FieldMap got = assemble(frames, low_latency);
            const test::Reference ref = test::reference_output(rig.streams);
            const FieldMap& want = ref.markers;
            if (!low_latency) {
                // Per-field mode sends exactly the messages `eyesim fpga --out` writes (order: by camera).
                std::vector<protocol::FieldMarkers> sent;
                for (const auto& f : frames)
                    if (const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message)) sent.push_back(*fm);
                std::stable_sort(sent.begin(), sent.end(), [](const auto& a, const auto& b) {
                    return a.camera_id < b.camera_id;
                });
                REQUIRE(sent.size() == ref.messages.size());
                for (std::size_t i = 0; i < sent.size(); ++i) REQUIRE(sent[i] == ref.messages[i]);
            }
            REQUIRE(want.size() == 3 * fields);
            std::size_t total = 0;
            for (const auto& [key, markers] : want) {
                INFO("camera " << key.first << " field " << key.second);
                REQUIRE(got.count(key) == 1);
                REQUIRE(got.at(key) == markers);
                total += markers.size();
            }
            REQUIRE(got.size() == want.size());
            REQUIRE(total == 3 * fields * 20);
            REQUIRE(rig.core->queue_stats().dropped_packets == 0);
        }
    }
}

TEST_CASE("field_end_us is the time of the field's last active pixel", "[firmware][core]") {
    CoreRig rig(3, 4);
    rig.command(cmd(1, protocol::Opcode::StreamStart));
    rig.run();
    for (const auto& f : test::decode_all(rig.sink.bytes)) {
        const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message);
        if (!fm) continue;
        const std::uint64_t start_us = 20000ull * fm->field_counter;
        const std::uint64_t expect =
            (start_us * 1000 + fpga::cycles_to_ns(fpga::active_line_end_cycle(287))) / 1000;
        REQUIRE(fm->field_end_us == expect);
        for (int i = 0; i < fm->marker_count; ++i) {
            // complete_us is the time of the blob's last pixel: on its last bbox row, before the field end.
            const auto& m = fm->markers[i];
            REQUIRE(m.complete_us >= start_us + fpga::cycles_to_ns(fpga::pixel_cycle(0, m.bbox_y1)) / 1000);
            REQUIRE(m.complete_us <= start_us + fpga::cycles_to_ns(fpga::pixel_cycle(m.bbox_x1, m.bbox_y1)) / 1000);
        }
    }
}

TEST_CASE("nothing is streamed before StreamStart, and StreamStop stops it", "[firmware][core]") {
    CoreRig rig(4, 4);
    // Two fields without streaming.
    while (rig.cams[0]->fields_delivered() < 2) {
        rig.core->step_cameras();
        rig.core->service();
    }
    REQUIRE(rig.sink.bytes.empty());
    rig.command(cmd(1, protocol::Opcode::StreamStart));
    rig.run();
    std::set<std::uint32_t> seen;
    bool status = false;
    for (const auto& f : test::decode_all(rig.sink.bytes)) {
        if (const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message)) seen.insert(fm->field_counter);
        if (const auto* st = std::get_if<protocol::DeviceStatus>(&f.message)) {
            status = true;
            REQUIRE(st->fields_processed[0] >= 2);
        }
    }
    REQUIRE(seen == std::set<std::uint32_t>{2, 3});
    REQUIRE(status);
}

TEST_CASE("a slow host makes the queue drop the oldest whole packets and count them", "[firmware][core]") {
    CoreRig rig(20, 20, {});
    rig.sink.budget_per_call = 0;  // the host reads nothing for now
    rig.command(cmd(1, protocol::Opcode::StreamStart));
    while (rig.core->step_cameras() != firmware::StepStatus::finished) rig.core->service();
    const auto& qs = rig.core->queue_stats();
    REQUIRE(qs.dropped_packets > 0);
    REQUIRE(qs.high_water_bytes <= firmware::kTxQueueBytes);
    REQUIRE(qs.high_water_packets <= firmware::kTxQueuePackets);
    const auto queued = rig.core->counters().frames_queued;
    REQUIRE(queued == qs.pushed_packets);
    // Now the host reads, a few bytes at a time (frames must still arrive whole and in order).
    rig.sink.budget_per_call = 7;
    for (int i = 0; i < 100000 && !rig.core->tx_idle(); ++i) rig.core->service();
    REQUIRE(rig.core->tx_idle());
    protocol::ParserStats stats;
    const auto frames = test::decode_all(rig.sink.bytes, &stats);
    REQUIRE(stats.errors() == 0);  // only whole frames were dropped: nothing truncated
    // What arrived is the newest frames: a reply first (it was sent before anything was dropped) then a gap.
    REQUIRE(frames.size() + qs.dropped_packets == queued);
    REQUIRE(std::get_if<protocol::Reply>(&frames.front().message) != nullptr);
    REQUIRE(frames.back().header.sequence == static_cast<std::uint16_t>(queued - 1));
    for (std::size_t i = 2; i < frames.size(); ++i)
        REQUIRE(frames[i].header.sequence == static_cast<std::uint16_t>(frames[i - 1].header.sequence + 1));
    REQUIRE(stats.sequence_gaps == 1);
    REQUIRE(rig.core->status().queue_overflows == qs.dropped_packets);
    REQUIRE(rig.core->status().blobs_dropped > 0);
}

TEST_CASE("every malformed command gets a nack with its reason and changes nothing", "[firmware][core][commands]") {
    using protocol::NackReason;
    using protocol::Opcode;
    namespace reg = fpga::reg;
    struct Case {
        const char* what;
        protocol::Command c;
        NackReason reason;
    };
    const std::vector<Case> cases = {
        {"unknown opcode 0", cmd(1, Opcode{0}), NackReason::BadOpcode},
        {"unknown opcode 99", cmd(2, Opcode{99}), NackReason::BadOpcode},
        {"write unknown address", cmd(3, Opcode::RegisterWrite, 0x0FFC, 1), NackReason::BadAddress},
        {"write misaligned", cmd(4, Opcode::RegisterWrite, reg::kMinArea + 2, 1), NackReason::BadAddress},
        {"write beyond 16 bits", cmd(5, Opcode::RegisterWrite, 0x10000 + reg::kMinArea, 1), NackReason::BadAddress},
        {"write camera window 4", cmd(6, Opcode::RegisterWrite, 0x4000 + reg::kMinArea, 1), NackReason::BadAddress},
        {"write unknown firmware register", cmd(7, Opcode::RegisterWrite, 0x8040, 1), NackReason::BadAddress},
        {"write too wide for 1-bit enable", cmd(8, Opcode::RegisterWrite, reg::kEnable, 2), NackReason::BadRange},
        {"write too wide for 18-bit area", cmd(9, Opcode::RegisterWrite, reg::kMaxArea, 1u << 18), NackReason::BadRange},
        {"write weight bits 0 (range 1..8)", cmd(10, Opcode::RegisterWrite, reg::kWeightBits, 0), NackReason::BadRange},
        {"write read-only id", cmd(11, Opcode::RegisterWrite, reg::kId, 0), NackReason::ReadOnly},
        {"write read-only firmware id", cmd(12, Opcode::RegisterWrite, firmware::fwreg::kId, 0), NackReason::ReadOnly},
        {"status period out of range", cmd(13, Opcode::RegisterWrite, firmware::fwreg::kStatusPeriodMs, 5), NackReason::BadRange},
        {"read unknown address", cmd(14, Opcode::RegisterRead, 0x0FFC), NackReason::BadAddress},
        {"read misaligned", cmd(15, Opcode::RegisterRead, 0x0001), NackReason::BadAddress},
        {"read with a value", cmd(16, Opcode::RegisterRead, reg::kId, 5), NackReason::Malformed},
        {"stream start with an address", cmd(17, Opcode::StreamStart, 4), NackReason::Malformed},
        {"stream stop with a value", cmd(18, Opcode::StreamStop, 0, 1), NackReason::Malformed},
        {"ping with an address", cmd(19, Opcode::Ping, 8), NackReason::Malformed},
        {"low latency 2", cmd(20, Opcode::SetLowLatency, 0, 2), NackReason::BadRange},
        {"low latency with an address", cmd(21, Opcode::SetLowLatency, 4, 1), NackReason::Malformed},
    };
    CoreRig rig(1, 2);
    std::array<std::array<std::uint32_t, fpga::kNumRegisters>, 3> before{};
    for (int c = 0; c < 3; ++c)
        for (int i = 0; i < fpga::kNumRegisters; ++i)
            before[c][i] = rig.core->registers(c).get(fpga::register_table()[i].address);
    for (const auto& k : cases) rig.command(k.c);
    rig.command(cmd(100, Opcode::RegisterRead, reg::kId));  // a good command after the bad ones
    rig.core->service();
    const auto frames = test::decode_all(rig.sink.bytes);
    REQUIRE(frames.size() == cases.size() + 1);
    for (std::size_t i = 0; i < cases.size(); ++i) {
        INFO(cases[i].what);
        const auto* r = std::get_if<protocol::Reply>(&frames[i].message);
        REQUIRE(r != nullptr);
        REQUIRE(r->command_id == cases[i].c.command_id);
        REQUIRE(r->opcode == cases[i].c.opcode);
        REQUIRE(r->status == static_cast<std::uint8_t>(protocol::ReplyStatus::Nack));
        REQUIRE(r->reason == static_cast<std::uint8_t>(cases[i].reason));
    }
    const auto* ok = std::get_if<protocol::Reply>(&frames.back().message);
    REQUIRE(ok->status == static_cast<std::uint8_t>(protocol::ReplyStatus::Ack));
    REQUIRE(ok->value == 0x45594650u);
    for (int c = 0; c < 3; ++c)
        for (int i = 0; i < fpga::kNumRegisters; ++i)
            REQUIRE(rig.core->registers(c).get(fpga::register_table()[i].address) == before[c][i]);
    REQUIRE_FALSE(rig.core->streaming());
    REQUIRE_FALSE(rig.core->low_latency());
    REQUIRE(rig.core->counters().nacks == cases.size());
}

TEST_CASE("corrupt and foreign frames from the host are counted, never answered or fatal", "[firmware][core][commands]") {
    CoreRig rig(1, 2);
    auto good = test::command_frame(cmd(1, protocol::Opcode::Ping, 0, 0, 42));
    auto flipped = good;
    flipped[12] ^= 0x10;  // payload bit flip: CRC error
    std::vector<std::uint8_t> garbage = {0x00, 0xE7, 0x5A, 0x07, 0xFF, 0x13};
    protocol::PedalState p;
    std::vector<std::uint8_t> foreign(protocol::kMaxFrameBytes);
    foreign.resize(protocol::encode_frame(protocol::Message{p}, 0, foreign));
    rig.source.push(flipped);
    rig.source.push(garbage);
    rig.source.push(foreign);
    rig.source.push(good);
    rig.core->service();
    const auto frames = test::decode_all(rig.sink.bytes);
    REQUIRE(frames.size() == 1);
    const auto* r = std::get_if<protocol::Reply>(&frames[0].message);
    REQUIRE(r->command_id == 1);
    REQUIRE(r->host_us == 42);
    const auto st = rig.core->status();
    REQUIRE(st.crc_errors == 1);
    REQUIRE(st.parse_errors >= 2);  // the foreign PedalState and the bad header
}

TEST_CASE("register writes take effect at the next field, never inside one", "[firmware][core][commands]") {
    CoreRig rig(4, 8);
    rig.command(cmd(1, protocol::Opcode::StreamStart));
    // Run into the middle of field 1, then disable all colour classes on every camera.
    while (!(rig.cams[0]->fields_delivered() == 1 && rig.clock.now_us() > 20000 + 10000)) {
        rig.core->step_cameras();
        rig.core->service();
    }
    rig.command(cmd(2, protocol::Opcode::RegisterWrite, fpga::reg::kClassEnable, 0));
    // And on camera 2 only, re-enable class... nothing: camera window write of MinArea huge on camera 1.
    rig.command(cmd(3, protocol::Opcode::RegisterWrite, 0x2000 + fpga::reg::kMinArea, 1000));
    rig.core->service();
    REQUIRE(rig.core->registers(0).get(fpga::reg::kClassEnable) == 0);
    REQUIRE(rig.core->registers(1).get(fpga::reg::kMinArea) == 1000);
    REQUIRE(rig.core->registers(0).get(fpga::reg::kMinArea) != 1000);
    rig.run();
    const FieldMap got = assemble(test::decode_all(rig.sink.bytes), false);
    const FieldMap want = test::reference_output(rig.streams).markers;
    for (int c = 0; c < 3; ++c) {
        INFO("camera " << c);
        REQUIRE(got.at({c, 0}) == want.at({c, 0}));
        REQUIRE(got.at({c, 1}) == want.at({c, 1}));  // the write arrived mid-field: field 1 is unaffected
        REQUIRE_FALSE(want.at({c, 2}).empty());
        REQUIRE(got.at({c, 2}).empty());              // from field 2 on, no class is enabled
        REQUIRE(got.at({c, 3}).empty());
    }
    // The acks carry the value now in the register.
    int acks = 0;
    for (const auto& f : test::decode_all(rig.sink.bytes))
        if (const auto* r = std::get_if<protocol::Reply>(&f.message); r && r->command_id >= 2) {
            REQUIRE(r->status == 0);
            REQUIRE(r->value == (r->command_id == 2 ? 0u : 1000u));
            ++acks;
        }
    REQUIRE(acks == 2);
}

TEST_CASE("ping echoes host time with the device time of execution", "[firmware][core][commands]") {
    CoreRig rig(2, 2);
    for (int i = 0; i < 300; ++i) rig.core->step_cameras();  // into field 0, device time > 0
    const std::uint64_t t_dev = rig.clock.now_us();
    REQUIRE(t_dev > 0);
    rig.command(cmd(77, protocol::Opcode::Ping, 0, 0, 1'700'000'000'000'123ull));
    rig.core->service();
    const auto frames = test::decode_all(rig.sink.bytes);
    REQUIRE(frames.size() == 1);
    const auto& r = std::get<protocol::Reply>(frames[0].message);
    REQUIRE(r.command_id == 77);
    REQUIRE(r.status == 0);
    REQUIRE(r.host_us == 1'700'000'000'000'123ull);
    REQUIRE(r.device_us == t_dev);
}

TEST_CASE("low-latency mode: every blob leaves within 100 us of its last pixel (modelled)", "[firmware][core][latency]") {
    firmware::CoreConfig cfg;
    cfg.low_latency = true;
    CoreRig rig(4, 20, cfg);
    rig.command(cmd(1, protocol::Opcode::StreamStart));
    rig.run();
    REQUIRE(rig.latency.records().size() == 4 * 3 * 20);
    for (const auto& r : rig.latency.records()) {
        REQUIRE(r.low_latency == 1);
        REQUIRE(r.last_pixel_ns < r.complete_ns);
        REQUIRE(r.complete_ns < r.queued_ns);
        REQUIRE(r.queued_ns < r.written_ns);
        REQUIRE(r.total_ns() <= 100'000);
    }
    // Per-field mode on the same data waits for the field end: far later.
    CoreRig slow(4, 20, {});
    slow.command(cmd(1, protocol::Opcode::StreamStart));
    slow.run();
    const auto fast = rig.latency.summarise(firmware::pc::LatencyLog::Span::last_pixel_to_written);
    const auto field = slow.latency.summarise(firmware::pc::LatencyLog::Span::last_pixel_to_written);
    REQUIRE(field.count == fast.count);
    REQUIRE(field.p50_us > 10 * fast.p50_us);
}

TEST_CASE("the core allocates nothing after start-up", "[firmware][core]") {
    CoreRig rig(3, 20);
    rig.command(cmd(1, protocol::Opcode::StreamStart));
    rig.command(cmd(2, protocol::Opcode::SetLowLatency, 0, 1));
    rig.sink.bytes.reserve(1u << 22);
    const long before = test::allocation_count();
    if (before < 0) WARN("allocation counting is unavailable in this build (sanitizer): only the run is checked");
    while (rig.core->step_cameras() != firmware::StepStatus::finished) rig.core->service();
    // The field loader copies from memory; the sink's vector was reserved: any allocation is the core's.
    REQUIRE(test::allocation_count() == before);
    REQUIRE(rig.core->counters().blobs_sent == 3 * 3 * 20);
}

TEST_CASE("stream_stop inside a field: a low-latency field gets its last part, nothing more of the field is sent",
          "[firmware][core][commands]") {
    using protocol::kFieldFlagBlobsDropped;
    using protocol::kFieldFlagLowLatency;
    using protocol::kFieldFlagMoreFollows;
    for (const bool low_latency : {true, false}) {
        DYNAMIC_SECTION("low_latency=" << low_latency) {
            firmware::CoreConfig cfg;
            cfg.low_latency = low_latency;
            CoreRig rig(4, 20, cfg);  // 20 markers per field, on rows near y = 30, 90 and 150
            rig.command(cmd(1, protocol::Opcode::StreamStart));
            while (rig.cams[0]->fields_delivered() < 1) {
                rig.core->step_cameras();
                rig.core->service();
            }
            // 130 lines into field 1: the blobs of the first two rows are complete, those of the third are not.
            for (int i = 0; i < 130; ++i) {
                rig.core->step_cameras();
                rig.core->service();
            }
            rig.command(cmd(2, protocol::Opcode::StreamStop));
            rig.core->service();
            REQUIRE_FALSE(rig.core->streaming());
            rig.command(cmd(3, protocol::Opcode::StreamStart));  // again, still inside field 1
            rig.core->service();
            rig.run();

            protocol::ParserStats stats;
            const auto frames = test::decode_all(rig.sink.bytes, &stats);
            REQUIRE(stats.errors() == 0);
            REQUIRE(stats.sequence_gaps == 0);
            std::size_t stop_at = frames.size(), restart_at = frames.size();
            std::uint64_t stop_us = 0;
            for (std::size_t i = 0; i < frames.size(); ++i)
                if (const auto* r = std::get_if<protocol::Reply>(&frames[i].message)) {
                    REQUIRE(r->status == 0);
                    if (r->command_id == 2) stop_at = i, stop_us = r->device_us;
                    if (r->command_id == 3) restart_at = i;
                }
            REQUIRE(stop_at < restart_at);
            REQUIRE(restart_at < frames.size());
            REQUIRE(stop_us > 20000);  // inside field 1 (it starts at 20 000 µs)
            REQUIRE(stop_us < 40000);

            const test::Reference ref = test::reference_output(rig.streams);
            std::map<test::FieldKey, std::vector<protocol::FieldMarkers>> parts;
            for (std::size_t i = 0; i < frames.size(); ++i) {
                const auto* fm = std::get_if<protocol::FieldMarkers>(&frames[i].message);
                if (!fm) continue;
                INFO("frame " << i << ": camera " << int(fm->camera_id) << " field " << fm->field_counter);
                REQUIRE((i < stop_at || i > restart_at));  // nothing while stopped
                if (fm->field_counter == 1) REQUIRE(i < stop_at);  // nothing of field 1 after the stop
                parts[{fm->camera_id, fm->field_counter}].push_back(*fm);
            }
            for (int c = 0; c < 3; ++c) {
                INFO("camera " << c);
                for (std::uint32_t k : {0u, 2u, 3u}) {  // whole fields, as the FPGA model has them
                    std::vector<protocol::Marker> got;
                    for (const auto& p : parts[{c, k}])
                        for (int m = 0; m < p.marker_count; ++m) got.push_back(p.markers[m]);
                    REQUIRE(got == ref.markers.at({c, k}));
                    REQUIRE((parts[{c, k}].back().flags & kFieldFlagMoreFollows) == 0);
                }
                const auto& f1 = parts[{c, 1}];
                if (!low_latency) {
                    REQUIRE(f1.empty());  // per-field mode had sent nothing of it: nothing at all
                    continue;
                }
                // Low-latency: the parts sent before the stop, then one last part at the stop.
                REQUIRE(f1.size() >= 2);
                std::vector<protocol::Marker> got;
                for (std::size_t p = 0; p < f1.size(); ++p) {
                    REQUIRE(f1[p].part_index == p);
                    REQUIRE((f1[p].flags & kFieldFlagLowLatency) != 0);
                    const bool last = p + 1 == f1.size();
                    REQUIRE(((f1[p].flags & kFieldFlagMoreFollows) == 0) == last);
                    for (int m = 0; m < f1[p].marker_count; ++m) got.push_back(f1[p].markers[m]);
                }
                const protocol::FieldMarkers& close = f1.back();
                REQUIRE(close.marker_count == 0);
                REQUIRE(close.flags == (kFieldFlagLowLatency | kFieldFlagBlobsDropped));
                REQUIRE(close.field_end_us == stop_us);
                // What was sent is the start of the field's markers, not all of them.
                const auto& want = ref.markers.at({c, 1});
                REQUIRE(!got.empty());
                REQUIRE(got.size() < want.size());
                REQUIRE(std::equal(got.begin(), got.end(), want.begin()));
            }
        }
    }
}
