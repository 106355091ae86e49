// The register map of docs/protocol.md (section 4.6) against the code: every documented row is checked against the
// FPGA model's register table and, through register_read / register_write commands, against the device core itself
// (address, access, width, reset value, accepted range); and a scan of the whole address space finds no register
// the document lacks.
#include "core_rig.hpp"

#include "eyesim/firmware/registers.hpp"
#include "eyesim/fpga/register_map.hpp"

#include <catch2/catch.hpp>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

using namespace eyesim;
using protocol::NackReason;
using protocol::Opcode;

namespace {

struct DocRegister {
    std::uint32_t address = 0;  // pipeline: offset in a window; firmware: absolute
    std::string name, access, range;
    int width = 0;
    std::uint32_t reset = 0;
};

std::string trim(const std::string& s) {
    const auto b = s.find_first_not_of(' '), e = s.find_last_not_of(' ');
    return b == std::string::npos ? std::string() : s.substr(b, e - b + 1);
}

std::string unquote(const std::string& s) {  // `0x1F` -> 0x1F
    REQUIRE(s.size() >= 2);
    REQUIRE(s.front() == '`');
    const auto end = s.find('`', 1);
    REQUIRE(end != std::string::npos);
    return s.substr(1, end - 1);
}

std::uint32_t hex(const std::string& s) {
    REQUIRE(s.rfind("0x", 0) == 0);
    std::size_t used = 0;
    const unsigned long v = std::stoul(s.substr(2), &used, 16);
    REQUIRE(used == s.size() - 2);
    return static_cast<std::uint32_t>(v);
}

/// The rows of the register tables of docs/protocol.md section 4.6.
std::vector<DocRegister> doc_registers() {
    std::ifstream f(std::string(EYESIM_SOURCE_DIR) + "/docs/protocol.md");
    REQUIRE(f.good());
    std::vector<DocRegister> out;
    std::string line;
    bool inside = false;
    while (std::getline(f, line)) {
        if (line.rfind("### 4.6 Register map", 0) == 0) inside = true;
        else if (inside && line.rfind("## ", 0) == 0) break;
        if (!inside || line.rfind("| `0x", 0) != 0) continue;
        std::vector<std::string> cells;
        std::stringstream ss(line.substr(1));
        std::string cell;
        while (std::getline(ss, cell, '|')) cells.push_back(trim(cell));
        if (cells.size() == 2) continue;  // the address-space table
        INFO(line);
        REQUIRE(cells.size() == 7);
        DocRegister r;
        r.address = hex(unquote(cells[0]));
        r.name = cells[1];
        r.access = cells[2];
        r.width = std::stoi(cells[3]);
        r.reset = hex(unquote(cells[4]));
        r.range = cells[5];
        REQUIRE((r.access == "RO" || r.access == "RW"));
        REQUIRE(r.width >= 1);
        REQUIRE(r.width <= 32);
        out.push_back(r);
    }
    REQUIRE(inside);
    return out;
}

/// Inclusive intervals of a range cell "a … b, c, d … e" (or "any"); empty for "—" and "packed: ..." cells.
std::vector<std::pair<std::uint64_t, std::uint64_t>> intervals(const DocRegister& r) {
    const std::uint64_t top = (std::uint64_t{1} << r.width) - 1;
    if (r.range == "any") return {{0, top}};
    if (r.range == "—" || r.range.rfind("packed:", 0) == 0) return {};
    std::vector<std::pair<std::uint64_t, std::uint64_t>> out;
    std::stringstream ss(r.range);
    std::string item;
    const std::string dots = "…";
    while (std::getline(ss, item, ',')) {
        item = trim(item);
        const auto at = item.find(dots);
        std::size_t used = 0;
        if (at == std::string::npos) {
            const std::uint64_t v = std::stoull(item, &used);
            REQUIRE(used == item.size());
            out.emplace_back(v, v);
        } else {
            const std::string a = trim(item.substr(0, at)), b = trim(item.substr(at + dots.size()));
            out.emplace_back(std::stoull(a, &used), std::stoull(b));
            REQUIRE(used == a.size());
        }
        REQUIRE(out.back().first <= out.back().second);
        REQUIRE(out.back().second <= top);
    }
    return out;
}

bool in(const std::vector<std::pair<std::uint64_t, std::uint64_t>>& iv, std::uint64_t v) {
    for (const auto& [a, b] : iv)
        if (v >= a && v <= b) return true;
    return false;
}

/// The device as the host sees it: register commands executed by a core (no cameras needed for registers).
struct Device {
    test::CoreRig rig{1, 0};
    std::uint32_t id = 100;

    protocol::Reply run(Opcode op, std::uint32_t address, std::uint32_t value) {
        protocol::Command c;
        c.command_id = ++id;
        c.opcode = static_cast<std::uint8_t>(op);
        c.address = address;
        c.value = value;
        const protocol::Reply r = rig.core->execute(c);
        REQUIRE(r.command_id == c.command_id);
        return r;
    }
    bool read(std::uint32_t address, std::uint32_t& value) {
        const protocol::Reply r = run(Opcode::RegisterRead, address, 0);
        value = r.value;
        return r.status == 0;
    }
    std::uint32_t read(std::uint32_t address) {
        std::uint32_t v = 0;
        REQUIRE(read(address, v));
        return v;
    }
    /// 0 (ack) or the Nack reason; on ack, the reply carries the value now in the register.
    int write(std::uint32_t address, std::uint32_t value) {
        const protocol::Reply r = run(Opcode::RegisterWrite, address, value);
        if (r.status == 0) {
            REQUIRE(r.reason == 0);
            REQUIRE(r.value == value);
            return 0;
        }
        return r.reason;
    }
};

constexpr int kRange = static_cast<int>(NackReason::BadRange);
constexpr int kReadOnly = static_cast<int>(NackReason::ReadOnly);

/// Writes that a packed register's documented rule accepts (true) or refuses (false), from its range cell.
std::vector<std::pair<std::uint32_t, bool>> packed_cases(const DocRegister& r) {
    auto pack = [](std::uint32_t lo, std::uint32_t hi, int shift) { return lo | (hi << shift); };
    if (r.range == "packed: min ≤ max")  // bits [7:0] min, [15:8] max
        return {{pack(4, 5, 8), true}, {pack(5, 5, 8), true}, {pack(0, 255, 8), true}, {pack(6, 5, 8), false},
                {pack(255, 0, 8), false}};
    if (r.range == "packed: half-width 1 … 127")  // bits [7:0] centre, [15:8] half-width
        return {{pack(0, 1, 8), true}, {pack(255, 127, 8), true}, {pack(77, 0, 8), false}, {pack(77, 128, 8), false},
                {pack(77, 255, 8), false}};
    if (r.range == "packed: x0 ≤ x1 ≤ 719; bits 10–15 zero")  // bits [9:0] x0, [25:16] x1
        return {{pack(0, 719, 16), true}, {pack(300, 300, 16), true}, {pack(301, 300, 16), false},
                {pack(0, 720, 16), false}, {pack(0, 1023, 16), false}, {pack(0, 719, 16) | (1u << 10), false},
                {pack(0, 719, 16) | (1u << 15), false}};
    if (r.range == "packed: y0 ≤ y1; bits 9–15 zero")  // bits [8:0] y0, [24:16] y1
        return {{pack(0, 287, 16), true}, {pack(0, 511, 16), true}, {pack(100, 100, 16), true},
                {pack(101, 100, 16), false}, {pack(0, 287, 16) | (1u << 9), false},
                {pack(0, 287, 16) | (1u << 15), false}};
    FAIL("no check for the range rule '" << r.range << "' of " << r.name << ": add one here");
    return {};
}

}  // namespace

TEST_CASE("docs/protocol.md register map: every row matches the FPGA model's register table", "[firmware][doc]") {
    const auto doc = doc_registers();
    std::map<std::uint32_t, DocRegister> pipeline;
    for (const auto& r : doc)
        if (r.address < firmware::kRegCameraBase) REQUIRE(pipeline.emplace(r.address, r).second);
    const auto& table = fpga::register_table();
    REQUIRE(pipeline.size() == table.size());
    for (const fpga::RegisterInfo& info : table) {
        INFO("register " << info.name);
        REQUIRE(pipeline.count(info.address) == 1);
        const DocRegister& r = pipeline.at(info.address);
        CHECK(r.name == info.name);
        CHECK(r.width == info.width_bits);
        CHECK(r.reset == info.reset_value);
        CHECK((r.access == "RW") == info.writable);
        if (!info.writable) CHECK(r.range == "—");
    }
}

TEST_CASE("docs/protocol.md register map: the device has exactly the documented registers, as documented",
          "[firmware][doc]") {
    const auto doc = doc_registers();
    std::vector<DocRegister> pipeline, fw;
    for (const auto& r : doc) (r.address < firmware::kRegCameraBase ? pipeline : fw).push_back(r);
    REQUIRE(pipeline.size() >= 30);
    REQUIRE(fw.size() >= 6);
    for (const auto& r : fw) REQUIRE(r.address >= firmware::kFwRegBase);

    // Where the document says a register is: each pipeline row in the broadcast window and the three camera
    // windows, and each firmware row.
    std::map<std::uint32_t, const DocRegister*> expected;
    for (const auto& r : pipeline)
        for (std::uint32_t w = 0; w <= 3; ++w) expected[w * firmware::kRegCameraBase + r.address] = &r;
    for (const auto& r : fw) expected[r.address] = &r;

    Device dev;
    // Power-up values, read before anything is written (STREAMING is 0 until stream_start).
    for (const auto& [address, r] : expected) {
        INFO(r->name << " at 0x" << std::hex << address);
        CHECK(dev.read(address) == r->reset);
    }
    // Every aligned address of the 16-bit space: a register answers exactly where the document has one.
    std::set<std::uint32_t> found;
    for (std::uint32_t a = 0; a <= 0xFFFC; a += 4) {
        std::uint32_t v = 0;
        if (dev.read(a, v)) found.insert(a);
    }
    std::set<std::uint32_t> want;
    for (const auto& e : expected) want.insert(e.first);
    CHECK(found == want);
    // Misaligned and out-of-space addresses are no register.
    for (std::uint32_t a : {0x0001u, 0x0002u, 0x0003u, 0x1005u, 0x8002u, 0x10000u, 0x8000'0000u}) {
        std::uint32_t v = 0;
        CHECK_FALSE(dev.read(a, v));
        CHECK(dev.run(Opcode::RegisterRead, a, 0).reason == static_cast<int>(NackReason::BadAddress));
    }

    // No register is locked while streaming: everything below runs with the stream on.
    REQUIRE(dev.run(Opcode::StreamStart, 0, 0).status == 0);
    REQUIRE(dev.rig.core->streaming());

    auto check_row = [&](std::uint32_t address, const DocRegister& r) {
        INFO(r.name << " at 0x" << std::hex << address << std::dec << ", range '" << r.range << "'");
        const std::uint32_t before = dev.read(address);
        if (r.access == "RO") {
            CHECK(dev.write(address, before) == kReadOnly);
            CHECK(dev.write(address, before ^ 1u) == kReadOnly);
            CHECK(dev.read(address) == before);
            return;
        }
        CHECK(dev.write(address, r.reset) == 0);
        // Bits above the width are refused and change nothing.
        if (r.width < 32) {
            CHECK(dev.write(address, r.reset | (1u << r.width)) == kRange);
            CHECK(dev.write(address, 0x8000'0000u) == kRange);
            CHECK(dev.read(address) == r.reset);
        }
        const auto iv = intervals(r);
        if (!iv.empty()) {
            const std::uint64_t top = (std::uint64_t{1} << r.width) - 1;
            for (const auto& [a, b] : iv) {
                for (const std::uint64_t v : {a, b}) {
                    CHECK(dev.write(address, static_cast<std::uint32_t>(v)) == 0);
                    CHECK(dev.read(address) == v);
                }
                if (a > 0 && !in(iv, a - 1)) CHECK(dev.write(address, static_cast<std::uint32_t>(a - 1)) == kRange);
                if (b < top && !in(iv, b + 1)) CHECK(dev.write(address, static_cast<std::uint32_t>(b + 1)) == kRange);
            }
        } else {
            for (const auto& [v, ok] : packed_cases(r)) {
                INFO("value 0x" << std::hex << v);
                const std::uint32_t keep = dev.read(address);
                CHECK(dev.write(address, v) == (ok ? 0 : kRange));
                CHECK(dev.read(address) == (ok ? v : keep));
            }
        }
        CHECK(dev.write(address, r.reset) == 0);
        CHECK(dev.read(address) == r.reset);
    };
    for (const auto& r : pipeline) check_row(r.address, r);  // broadcast window
    for (const auto& r : pipeline) check_row(firmware::kRegCameraBase * 3 + r.address, r);  // camera 2's window
    for (const auto& r : fw) {
        if (r.name == "STREAMING") continue;  // reads 1 now; checked below
        check_row(r.address, r);
    }
    REQUIRE(dev.rig.core->streaming());
    const auto streaming = std::find_if(fw.begin(), fw.end(), [](const DocRegister& r) { return r.name == "STREAMING"; });
    REQUIRE(streaming != fw.end());
    CHECK(dev.read(streaming->address) == 1);
    CHECK(dev.write(streaming->address, 0) == kReadOnly);

    // A camera window writes that camera only; the broadcast window writes all three.
    const DocRegister& area = *std::find_if(pipeline.begin(), pipeline.end(), [](const DocRegister& r) {
        return r.name == "MIN_AREA";
    });
    REQUIRE(dev.write(firmware::kRegCameraBase * 2 + area.address, 7) == 0);  // camera 1
    CHECK(dev.read(firmware::kRegCameraBase * 1 + area.address) == area.reset);
    CHECK(dev.read(firmware::kRegCameraBase * 2 + area.address) == 7);
    CHECK(dev.read(firmware::kRegCameraBase * 3 + area.address) == area.reset);
    CHECK(dev.read(area.address) == area.reset);  // the broadcast window reads camera 0
    REQUIRE(dev.write(area.address, 9) == 0);
    for (std::uint32_t w = 1; w <= 3; ++w) CHECK(dev.read(firmware::kRegCameraBase * w + area.address) == 9);
}

TEST_CASE("docs/protocol.md: FW_VERSION is the USB bcdDevice", "[firmware][doc]") {
    std::ifstream f(std::string(EYESIM_SOURCE_DIR) + "/docs/protocol.md");
    std::stringstream ss;
    ss << f.rdbuf();
    const std::string doc = ss.str();
    char want[64];
    std::snprintf(want, sizeof want, "| bcdDevice | `0x%04X` |", firmware::kFirmwareVersion);
    CHECK(doc.find(want) != std::string::npos);
}
