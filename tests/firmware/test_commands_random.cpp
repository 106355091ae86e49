// Random commands against an oracle: the fpga register map's own validation, applied to a mirror of the device's
// register file. Every decoded command gets exactly one reply, in order; acks and nacks match the oracle.
#include "core_rig.hpp"

#include "eyesim/firmware/pc/tcp_server.hpp"
#include "eyesim/firmware/registers.hpp"

#include <catch2/catch.hpp>

#include <random>

using namespace eyesim;

TEST_CASE("random register commands: one reply each, ack exactly when the register map accepts", "[firmware][commands]") {
    test::CoreRig rig(1, 2);
    std::array<fpga::RegisterMap, 3> mirror{};
    std::mt19937 rng(2024);
    const auto& table = fpga::register_table();
    std::vector<protocol::Command> sent;
    for (std::uint32_t id = 1; id <= 3000; ++id) {
        protocol::Command c;
        c.command_id = id;
        c.opcode = static_cast<std::uint8_t>(rng() % 3 == 0 ? protocol::Opcode::RegisterRead : protocol::Opcode::RegisterWrite);
        const auto& reg = table[rng() % table.size()];
        const std::uint32_t target = (rng() % 5) * 0x1000;  // broadcast, cameras 0..2, and the invalid window 4
        c.address = target + reg.address + (rng() % 8 == 0 ? 2u : 0u);  // sometimes misaligned
        switch (rng() % 4) {
            case 0: c.value = rng() & (reg.width_bits >= 32 ? ~0u : (1u << reg.width_bits) - 1u); break;  // fits
            case 1: c.value = rng(); break;                                     // usually too wide
            case 2: c.value = reg.reset_value; break;
            default: c.value = rng() % 300; break;                              // small values: ranges
        }
        if (c.opcode == static_cast<std::uint8_t>(protocol::Opcode::RegisterRead)) c.value = 0;
        sent.push_back(c);
        rig.command(c);
        if (id % 8 == 0) rig.core->service();  // several commands per service call, some split reads
    }
    for (int i = 0; i < 100; ++i) rig.core->service();
    const auto frames = test::decode_all(rig.sink.bytes);
    REQUIRE(frames.size() == sent.size());
    std::size_t acks = 0, nacks = 0;
    for (std::size_t i = 0; i < sent.size(); ++i) {
        const auto& c = sent[i];
        const auto& r = std::get<protocol::Reply>(frames[i].message);
        INFO("command " << c.command_id << " opcode " << int(c.opcode) << " address " << c.address << " value " << c.value);
        REQUIRE(r.command_id == c.command_id);
        const std::uint32_t target = c.address & 0xF000;
        const auto offset = static_cast<std::uint16_t>(c.address & 0x0FFF);
        const bool window_ok = target <= 0x3000;
        const std::size_t first = target == 0 ? 0 : target / 0x1000 - 1;
        const std::size_t last = target == 0 ? 3 : first + 1;
        bool expect_ok = window_ok;
        std::uint32_t expect_value = 0;
        if (c.opcode == static_cast<std::uint8_t>(protocol::Opcode::RegisterWrite)) {
            for (std::size_t k = first; expect_ok && k < last; ++k)
                expect_ok = mirror[k].check_write(offset, c.value) == fpga::RegWriteResult::kOk;
            if (expect_ok) {
                for (std::size_t k = first; k < last; ++k) mirror[k].write(offset, c.value);
                expect_value = mirror[first].get(offset);
            }
        } else {
            expect_ok = window_ok && mirror[first].read(offset, expect_value);
        }
        REQUIRE((r.status == 0) == expect_ok);
        if (expect_ok) {
            REQUIRE(r.value == expect_value);
            ++acks;
        } else {
            REQUIRE(r.reason != 0);
            ++nacks;
        }
    }
    REQUIRE(acks > 300);
    REQUIRE(nacks > 300);
    for (std::size_t k = 0; k < 3; ++k)
        for (const auto& reg : table) REQUIRE(rig.core->registers(k).get(reg.address) == mirror[k].get(reg.address));
}

TEST_CASE("loopback addresses are told from others", "[firmware][device]") {
    using firmware::pc::is_loopback_address;
    for (const char* a : {"127.0.0.1", "127.1.2.3", "::1", "localhost"}) REQUIRE(is_loopback_address(a));
    for (const char* a : {"0.0.0.0", "192.168.1.10", "::", "10.0.0.1", "example.org", "", "128.0.0.1"})
        REQUIRE_FALSE(is_loopback_address(a));
    REQUIRE_THROWS_AS(firmware::pc::TcpServer("0.0.0.0", 0, false), firmware::pc::ServerError);
    firmware::pc::TcpServer server("127.0.0.1", 0, false);
    REQUIRE(server.port() != 0);
    REQUIRE_FALSE(server.connected());
}
