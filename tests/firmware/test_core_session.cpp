// The firmware core driven by the host API over the in-process transport pair, and the core's periodic
// messages (pedal on change and keep-alive, status period), stream stop and per-field mode switching.
#include "core_rig.hpp"

#include "eyesim/firmware/registers.hpp"
#include "eyesim/transport/device_link.hpp"
#include "eyesim/transport/inproc.hpp"
#include "transport_port.hpp"

#include <catch2/catch.hpp>

#include <set>

using namespace eyesim;

namespace {

struct FakePedal final : firmware::PedalInput {
    std::uint16_t pos = 0;
    bool sw = false;
    firmware::PedalReading read() const noexcept override {
        firmware::PedalReading r;
        r.axes[0] = pos;
        r.buttons = sw ? 1 : 0;
        return r;
    }
};

}  // namespace

TEST_CASE("host session over the in-process pair: commands, ping offset, low-latency markers", "[firmware][session]") {
    test::CoreRig rig(4, 10);
    auto [host_end, device_end] = transport::make_inproc_pair(1u << 20);
    test::TransportPort port;
    port.t = device_end.get();
    firmware::DeviceHal hal;
    for (int c = 0; c < 3; ++c) hal.cameras[c] = rig.cams[c].get();
    hal.sink = &port;
    hal.source = &port;
    hal.clock = &rig.clock;
    firmware::DeviceCore core(hal);
    transport::DeviceLink link(std::move(host_end));

    // Read back the firmware id, switch to low latency, ping, start.
    const auto id = link.command(protocol::Opcode::RegisterRead, firmware::fwreg::kId);
    core.service();
    const auto r = link.wait_reply(id, 1000);
    REQUIRE(r.has_value());
    REQUIRE(r->value == firmware::kFirmwareId);
    const auto ll = link.command(protocol::Opcode::SetLowLatency, 0, 1);
    link.ping();
    link.command(protocol::Opcode::StreamStart);
    std::vector<protocol::FieldMarkers> got;
    auto collect = [&](const protocol::DecodedFrame& f) {
        if (const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message)) got.push_back(*fm);
    };
    core.service();
    REQUIRE(link.wait_reply(ll, 1000, collect)->status == 0);
    REQUIRE(link.clock().valid());
    // Device time is modelled (0 before the first line), host time is the steady clock: offset = −host time.
    REQUIRE(link.clock().offset_us() < 0);
    while (core.step_cameras() != firmware::StepStatus::finished) {
        core.service();
        link.poll(0, collect);
    }
    for (int i = 0; i < 100 && !core.tx_idle(); ++i) core.service();
    link.poll(10, collect);
    REQUIRE(link.stats().errors() == 0);
    REQUIRE(link.stats().sequence_gaps == 0);
    test::FieldMap markers;
    for (const auto& fm : got) {
        REQUIRE((fm.flags & protocol::kFieldFlagLowLatency) != 0);
        auto& v = markers[{fm.camera_id, fm.field_counter}];
        for (int i = 0; i < fm.marker_count; ++i) v.push_back(fm.markers[i]);
    }
    REQUIRE(markers == test::reference_output(rig.streams).markers);
}

TEST_CASE("unsynchronised cameras: each field leaves at its own end, not when the latest camera's lines run",
          "[firmware][session]") {
    // Fields of the three cameras start 0, 6.7 and 13.3 ms apart. A board takes each camera's lines as they are
    // read out, so a field's message is queued at that field's end; running the cameras' lines in lockstep (line
    // y of every camera together) would hold camera 0's field until camera 2 reached the same line, 13.3 ms later.
    for (bool low_latency : {false, true}) {
        firmware::CoreConfig cfg;
        cfg.low_latency = low_latency;
        test::CoreRig rig(6, 2, cfg, {0, 6667, 13333});
        rig.command({1, static_cast<std::uint8_t>(protocol::Opcode::StreamStart), 0, 0, 0});
        std::size_t seen = 0;
        std::int64_t worst_lag_us = 0;
        int fields = 0;
        std::set<int> cameras;
        while (rig.core->step_cameras() != firmware::StepStatus::finished) {
            rig.core->service();
            const auto frames = test::decode_all(rig.sink.bytes);
            for (std::size_t i = seen; i < frames.size(); ++i)
                if (const auto* fm = std::get_if<protocol::FieldMarkers>(&frames[i].message); fm && fm->field_end_us) {
                    worst_lag_us = std::max(worst_lag_us, std::int64_t(rig.clock.now_us()) - std::int64_t(fm->field_end_us));
                    cameras.insert(fm->camera_id);
                    ++fields;
                }
            seen = frames.size();
        }
        INFO((low_latency ? "low-latency" : "per-field") << ": " << fields << " fields, worst lag " << worst_lag_us << " us");
        CHECK(fields >= 15);
        CHECK(cameras.size() == 3);
        CHECK(worst_lag_us < 200);  // a few lines at most
    }
}

TEST_CASE("pedal: sent on change and as keep-alive; status at its period; stream stop is obeyed", "[firmware][session]") {
    test::CoreRig rig(8, 2);
    FakePedal pedal;
    firmware::DeviceHal hal;
    for (int c = 0; c < 3; ++c) hal.cameras[c] = rig.cams[c].get();
    hal.sink = &rig.sink;
    hal.source = &rig.source;
    hal.clock = &rig.clock;
    hal.pedal = &pedal;
    firmware::CoreConfig cfg;
    cfg.status_period_ms = 50;
    cfg.pedal_period_ms = 20;
    firmware::DeviceCore core(hal, cfg);
    rig.source.push(test::command_frame({1, static_cast<std::uint8_t>(protocol::Opcode::StreamStart), 0, 0, 0}));
    int lines = 0;
    while (core.step_cameras() != firmware::StepStatus::finished) {
        ++lines;
        // Pedal pressed in field 2 (one change), switch in field 3; stream stopped after field 6.
        if (rig.clock.now_us() > 45000) pedal.pos = 30000;
        if (rig.clock.now_us() > 65000) pedal.sw = true;
        if (lines == 6 * 289 + 10)
            rig.source.push(test::command_frame({2, static_cast<std::uint8_t>(protocol::Opcode::StreamStop), 0, 0, 0}));
        core.service();
    }
    std::vector<protocol::PedalState> pedals;
    std::vector<protocol::DeviceStatus> statuses;
    std::uint32_t last_field = 0;
    for (const auto& f : test::decode_all(rig.sink.bytes)) {
        if (const auto* p = std::get_if<protocol::PedalState>(&f.message)) pedals.push_back(*p);
        if (const auto* s = std::get_if<protocol::DeviceStatus>(&f.message)) statuses.push_back(*s);
        if (const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message)) last_field = std::max(last_field, fm->field_counter);
    }
    REQUIRE(last_field == 5);  // fields 6 and 7 were not sent
    REQUIRE(core.status().fields_processed[0] == 8);  // but still processed: pixels never stop
    // Keep-alive: consecutive pedal messages at most 20 ms apart (plus one line), one at each change.
    REQUIRE(pedals.size() >= 6);
    int changes = 0;
    for (std::size_t i = 1; i < pedals.size(); ++i) {
        REQUIRE(pedals[i].device_us - pedals[i - 1].device_us <= 20000 + 64);
        changes += pedals[i].axes != pedals[i - 1].axes || pedals[i].buttons != pedals[i - 1].buttons;
    }
    REQUIRE(changes == 2);
    REQUIRE(pedals.back().axes[0] == 30000);
    REQUIRE(pedals.back().buttons == 1);
    // Status every 50 ms of device time while streaming (~120 ms): at start, +50, +100.
    REQUIRE(statuses.size() == 3);
    for (std::size_t i = 1; i < statuses.size(); ++i)
        REQUIRE(statuses[i].device_us - statuses[i - 1].device_us == Approx(50000).margin(64));
}

TEST_CASE("a mode switch applies from the next field", "[firmware][session]") {
    test::CoreRig rig(3, 4);
    rig.command({1, static_cast<std::uint8_t>(protocol::Opcode::StreamStart), 0, 0, 0});
    while (rig.clock.now_us() < 30000) {  // middle of field 1
        rig.core->step_cameras();
        rig.core->service();
    }
    rig.command({2, static_cast<std::uint8_t>(protocol::Opcode::SetLowLatency), 0, 1, 0});
    rig.run();
    std::map<std::uint32_t, bool> ll;
    for (const auto& f : test::decode_all(rig.sink.bytes))
        if (const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message))
            ll[fm->field_counter] = (fm->flags & protocol::kFieldFlagLowLatency) != 0;
    REQUIRE(ll == std::map<std::uint32_t, bool>{{0, false}, {1, false}, {2, true}});
}
