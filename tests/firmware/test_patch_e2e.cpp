// Precision mode end to end: PATCH_ENABLE per camera and class → the core's patch capture → BlobPatch frames after
// the field's markers → stream parser → PatchAssembler on the host. Every assembled patch equals the camera's
// field at its coordinates, covers its marker's box plus the 2-px halo, and names its marker; over the budget,
// patches are dropped and counted while the markers stay exactly the FPGA model's.
#include "core_rig.hpp"
#include "eyesim/protocol/codec.hpp"
#include "eyesim/transport/device_link.hpp"
#include "eyesim/transport/inproc.hpp"
#include "eyesim/transport/patch_assembler.hpp"
#include "transport_port.hpp"

#include <catch2/catch.hpp>

#include <algorithm>
#include <map>
#include <tuple>

using namespace eyesim;

namespace {

protocol::Command cmd(std::uint32_t id, protocol::Opcode op, std::uint32_t address = 0, std::uint32_t value = 0) {
    protocol::Command c;
    c.command_id = id;
    c.opcode = static_cast<std::uint8_t>(op);
    c.address = address;
    c.value = value;
    return c;
}

struct Received {
    std::map<test::FieldKey, std::vector<protocol::Marker>> markers;
    std::map<test::FieldKey, std::size_t> last_part_frame;          // frame number of the field's last part
    std::map<std::tuple<int, std::uint32_t, int>, std::size_t> marker_frame;  // frame number of each marker's part
    // (camera, field, blob) → the patch's header; its samples pointer is the assembler's and is not kept.
    std::map<std::tuple<int, std::uint32_t, int>, transport::AssembledPatch> patches;
    std::map<std::tuple<int, std::uint32_t, int>, std::vector<std::uint8_t>> samples;
    std::map<std::tuple<int, std::uint32_t, int>, std::size_t> patch_frame;  // frame number of its first fragment
    std::map<test::FieldKey, std::size_t> patch_wire_bytes;
    transport::PatchAssemblerStats assembler;
};

Received receive(const std::vector<std::uint8_t>& bytes) {
    protocol::ParserStats stats;
    const auto frames = test::decode_all(bytes, &stats);
    REQUIRE(stats.errors() == 0);
    REQUIRE(stats.sequence_gaps == 0);
    Received r;
    auto assembler = std::make_unique<transport::PatchAssembler>();
    for (std::size_t i = 0; i < frames.size(); ++i) {
        if (const auto* fm = std::get_if<protocol::FieldMarkers>(&frames[i].message)) {
            auto& v = r.markers[{fm->camera_id, fm->field_counter}];
            for (int k = 0; k < fm->marker_count; ++k) {
                r.marker_frame[{fm->camera_id, fm->field_counter, static_cast<int>(v.size())}] = i;
                v.push_back(fm->markers[k]);
            }
            if (!(fm->flags & protocol::kFieldFlagMoreFollows)) r.last_part_frame[{fm->camera_id, fm->field_counter}] = i;
        } else if (const auto* bp = std::get_if<protocol::BlobPatch>(&frames[i].message)) {
            const std::tuple<int, std::uint32_t, int> key{bp->camera_id, bp->field_counter, bp->blob_index};
            r.patch_wire_bytes[{bp->camera_id, bp->field_counter}] += frames[i].header.payload_bytes + 12u;
            if (bp->fragment_index == 0) r.patch_frame[key] = i;
            if (const transport::AssembledPatch* p = assembler->add(*bp)) {
                REQUIRE(r.patches.count(key) == 0);  // one patch per marker
                r.patches[key] = *p;
                r.samples[key].assign(p->samples, p->samples + p->bytes);
            }
        }
    }
    r.assembler = assembler->stats();
    return r;
}

/// Checks every received patch against the camera streams and its marker; returns the patches checked.
std::size_t check_against_fields(const Received& r, const test::CoreRig& rig, bool low_latency) {
    std::size_t checked = 0;
    for (const auto& [key, p] : r.patches) {
        const auto [cam, field, blob] = key;
        INFO("camera " << cam << " field " << field << " blob " << blob);
        const auto& markers = r.markers.at({cam, field});
        REQUIRE(blob < static_cast<int>(markers.size()));
        const protocol::Marker& m = markers[static_cast<std::size_t>(blob)];
        CHECK(p.colour_class == m.colour_class);
        // The box plus 2 px on every side (inside the field), widened to whole UYVY pairs.
        const int x0 = std::max(0, m.bbox_x0 - 2), x1 = std::min(719, m.bbox_x1 + 2);
        const int y0 = std::max(0, m.bbox_y0 - 2), y1 = std::min(287, m.bbox_y1 + 2);
        CHECK(int(p.origin_x) == x0 - x0 % 2);
        CHECK(int(p.origin_x + p.width_px - 1) == x1 + (1 - x1 % 2));
        CHECK(int(p.origin_y) == y0);
        CHECK(int(p.origin_y + p.height_px - 1) == y1);
        CHECK(p.field_parity == field % 2);
        // Every byte equals the field's sample at its coordinates.
        const std::uint8_t* f = rig.streams[static_cast<std::size_t>(cam)].data() + test::kFieldBytes * field;
        const auto& s = r.samples.at(key);
        REQUIRE(s.size() == 2u * p.width_px * p.height_px);
        int wrong = 0;
        for (int row = 0; row < p.height_px; ++row)
            for (int k = 0; k < 2 * p.width_px; ++k)
                wrong += s[static_cast<std::size_t>(2 * row * p.width_px + k)] !=
                         f[static_cast<std::size_t>((p.origin_y + row) * 1440 + 2 * p.origin_x + k)];
        CHECK(wrong == 0);
        // The accessors read the samples as UYVY: pixel (c, r) of the patch is field pixel (origin_x + c, origin_y + r).
        transport::AssembledPatch q = p;
        q.samples = s.data();  // the assembler's own buffer is reused by its next patch
        for (int row = 0; row < q.height_px; ++row)
            for (int c = 0; c < q.width_px; ++c) {
                const std::size_t at = static_cast<std::size_t>((q.origin_y + row) * 1440 + 2 * (q.origin_x + c));
                const std::size_t pair = at - 2 * static_cast<std::size_t>(c % 2);
                wrong += q.y(c, row) != f[at + 1] || q.cb(c, row) != f[pair] || q.cr(c, row) != f[pair + 2];
            }
        CHECK(wrong == 0);
        // After its marker; per-field mode: after all the field's markers.
        CHECK(r.patch_frame.at(key) > r.marker_frame.at(key));
        if (!low_latency) CHECK(r.patch_frame.at(key) > r.last_part_frame.at({cam, field}));
        ++checked;
    }
    return checked;
}

}  // namespace

TEST_CASE("precision mode end to end: patches per camera and class arrive whole and equal to the field",
          "[firmware][patch]") {
    for (const bool low_latency : {false, true}) {
        DYNAMIC_SECTION("low_latency=" << low_latency) {
            firmware::CoreConfig cfg;
            cfg.low_latency = low_latency;
            test::CoreRig rig(4, 20, cfg);  // 20 markers: two FieldMarkers parts per field, blob_index ≥ 14 too
            // Camera 0: red and green; camera 1: every class; camera 2: none (its window's register left at 0).
            const std::array<std::uint32_t, 3> enable{0x3, 0xF, 0x0};
            std::uint32_t id = 1;
            for (std::uint32_t c = 0; c < 2; ++c) {
                const protocol::Reply rep =
                    rig.core->execute(cmd(id++, protocol::Opcode::RegisterWrite, 0x1000 * (c + 1) + 0x03C, enable[c]));
                REQUIRE(rep.status == 0);
            }
            REQUIRE(rig.core->execute(cmd(id++, protocol::Opcode::RegisterWrite, 0x303C, 0x10)).status == 1);  // 4 bits
            rig.command(cmd(id++, protocol::Opcode::StreamStart));
            rig.run();
            const Received r = receive(rig.sink.bytes);

            // Markers unchanged by precision mode: exactly the FPGA model's.
            const test::Reference ref = test::reference_output(rig.streams);
            REQUIRE(r.markers == ref.markers);
            // Which markers get a patch: those of enabled classes (the scene's markers all fit).
            std::size_t wanted = 0;
            for (const auto& [key, markers] : ref.markers)
                for (std::size_t i = 0; i < markers.size(); ++i) {
                    const bool on = (enable[static_cast<std::size_t>(key.first)] >> (markers[i].colour_class - 1)) & 1;
                    wanted += on;
                    CHECK(r.patches.count({key.first, key.second, static_cast<int>(i)}) == (on ? 1u : 0u));
                }
            REQUIRE(wanted > 60);
            CHECK(check_against_fields(r, rig, low_latency) == wanted);
            // Low-latency mode sends a patch as soon as its lines and its marker are out, long before the field
            // ends for the markers in the upper part of the field.
            std::size_t early = 0;
            for (const auto& [key, frame] : r.patch_frame)
                early += frame < r.last_part_frame.at({std::get<0>(key), std::get<1>(key)});
            if (low_latency) CHECK(early > wanted / 2);
            else CHECK(early == 0);
            CHECK(r.assembler.completed == wanted);
            CHECK(r.assembler.incomplete == 0);
            CHECK(rig.core->counters().patches_sent == wanted);
            CHECK(rig.core->counters().patches_dropped == 0);
            CHECK(rig.core->queue_stats().dropped_packets == 0);
        }
    }
}

TEST_CASE("precision mode over the budget: patches dropped and counted, markers intact", "[firmware][patch]") {
    test::CoreRig rig(3, 32);  // 32 markers per field: their patches exceed 8 KiB per camera field
    REQUIRE(rig.core->execute(cmd(1, protocol::Opcode::RegisterWrite, 0x03C, 0xF)).status == 0);  // all cameras
    rig.command(cmd(2, protocol::Opcode::StreamStart));
    rig.run();
    const Received r = receive(rig.sink.bytes);
    const test::Reference ref = test::reference_output(rig.streams);
    REQUIRE(r.markers == ref.markers);
    std::size_t markers = 0;
    for (const auto& [key, m] : ref.markers) markers += m.size();
    const auto& k = rig.core->counters();
    CHECK(k.patches_dropped > 0);
    CHECK(k.patches_sent + k.patches_dropped == markers);
    CHECK(r.patches.size() == k.patches_sent);
    for (const auto& [key, bytes] : r.patch_wire_bytes) CHECK(bytes <= firmware::kPatchBudgetBytesPerField);
    CHECK(check_against_fields(r, rig, false) == k.patches_sent);
    CHECK(rig.core->queue_stats().dropped_packets == 0);
}

TEST_CASE("PatchAssembler: fragments of three cameras interleaved, a lost fragment drops its patch", "[patch]") {
    // A 20 × 30 px patch: 1200 sample bytes in fragments of 472, 472 and 256 bytes.
    std::vector<std::uint8_t> samples(1200);
    for (std::size_t i = 0; i < samples.size(); ++i) samples[i] = static_cast<std::uint8_t>(i * 7 + 3);
    auto fragment = [&](std::uint8_t cam, std::uint16_t blob, std::uint8_t index) {
        protocol::BlobPatch b;
        b.camera_id = cam;
        b.colour_class = 2;
        b.field_counter = 9;
        b.blob_index = blob;
        b.origin_x = 100;
        b.origin_y = 40;
        b.width_px = 20;
        b.height_px = 30;
        b.fragment_count = 3;
        b.fragment_index = index;
        const std::size_t first = 472u * index;
        for (std::size_t i = 0; i < b.sample_bytes(); ++i) b.samples[i] = samples[first + i];
        REQUIRE(protocol::valid_message(b));
        return b;
    };
    auto a = std::make_unique<transport::PatchAssembler>();
    // Cameras 0 and 1 interleaved: both whole.
    CHECK(a->add(fragment(0, 5, 0)) == nullptr);
    CHECK(a->add(fragment(1, 6, 0)) == nullptr);
    CHECK(a->add(fragment(0, 5, 1)) == nullptr);
    CHECK(a->add(fragment(1, 6, 1)) == nullptr);
    const transport::AssembledPatch* p = a->add(fragment(0, 5, 2));
    REQUIRE(p != nullptr);
    CHECK((p->camera_id == 0 && p->blob_index == 5 && p->bytes == 1200));
    CHECK(std::equal(samples.begin(), samples.end(), p->samples));
    p = a->add(fragment(1, 6, 2));
    REQUIRE(p != nullptr);
    CHECK(std::equal(samples.begin(), samples.end(), p->samples));
    // Camera 2 loses fragment 1: nothing delivered, counted once; the next patch is whole again.
    CHECK(a->add(fragment(2, 7, 0)) == nullptr);
    CHECK(a->add(fragment(2, 7, 2)) == nullptr);
    CHECK(a->stats().incomplete == 1);
    CHECK(a->add(fragment(2, 8, 0)) == nullptr);
    CHECK(a->add(fragment(2, 8, 1)) == nullptr);
    p = a->add(fragment(2, 8, 2));
    REQUIRE(p != nullptr);
    CHECK(p->blob_index == 8);
    // A patch cut off by the next patch's first fragment is dropped and counted.
    CHECK(a->add(fragment(2, 9, 0)) == nullptr);
    CHECK(a->add(fragment(2, 10, 0)) == nullptr);
    CHECK(a->stats().incomplete == 2);
    CHECK(a->stats().completed == 3);
    CHECK(a->stats().fragments == 13);
}


TEST_CASE("precision mode through the host API: DeviceLink enables patches, the host assembles them equal to the field",
          "[firmware][patch][session]") {
    test::CoreRig rig(3, 12);
    auto [host_end, device_end] = transport::make_inproc_pair(1u << 20);
    test::TransportPort port;
    port.t = device_end.get();
    firmware::DeviceHal hal;
    for (int c = 0; c < 3; ++c) hal.cameras[c] = rig.cams[c].get();
    hal.sink = &port;
    hal.source = &port;
    hal.clock = &rig.clock;
    auto core = std::make_unique<firmware::DeviceCore>(hal);
    transport::DeviceLink link(std::move(host_end));

    // Camera 1 only, blue and yellow (classes 3 and 4), in low-latency mode.
    const auto w = link.command(protocol::Opcode::RegisterWrite, 0x2000 + 0x03C, 0xC);
    link.command(protocol::Opcode::SetLowLatency, 0, 1);
    link.command(protocol::Opcode::StreamStart);
    auto assembler = std::make_unique<transport::PatchAssembler>();
    std::map<test::FieldKey, std::vector<protocol::Marker>> markers;
    std::size_t checked = 0, wrong = 0, orphans = 0;
    auto on_frame = [&](const protocol::DecodedFrame& f) {
        if (const auto* fm = std::get_if<protocol::FieldMarkers>(&f.message)) {
            auto& v = markers[{fm->camera_id, fm->field_counter}];
            for (int i = 0; i < fm->marker_count; ++i) v.push_back(fm->markers[i]);
        } else if (const auto* bp = std::get_if<protocol::BlobPatch>(&f.message)) {
            const transport::AssembledPatch* p = assembler->add(*bp);
            if (p == nullptr) return;
            // Its marker has arrived before it; the patch is the field's bytes around the marker's box.
            const auto& v = markers[{p->camera_id, p->field_counter}];
            if (p->blob_index >= v.size()) {
                ++orphans;
                return;
            }
            const protocol::Marker& m = v[p->blob_index];
            wrong += p->camera_id != 1 || m.colour_class < 3 || p->origin_x > m.bbox_x0 || p->origin_y > m.bbox_y0 ||
                     p->origin_x + p->width_px - 1 < m.bbox_x1 || p->origin_y + p->height_px - 1 < m.bbox_y1;
            const std::uint8_t* field = rig.streams[1].data() + test::kFieldBytes * p->field_counter;
            for (int r = 0; r < p->height_px; ++r)
                wrong += !std::equal(p->samples + 2 * r * p->width_px, p->samples + 2 * (r + 1) * p->width_px,
                                     field + (p->origin_y + r) * 1440 + 2 * p->origin_x);
            ++checked;
        }
    };
    core->service();
    const auto reply = link.wait_reply(w, 1000, on_frame);
    REQUIRE(reply.has_value());
    REQUIRE(reply->status == 0);
    while (core->step_cameras() != firmware::StepStatus::finished) {
        core->service();
        link.poll(0, on_frame);
    }
    for (int i = 0; i < 100 && !core->tx_idle(); ++i) core->service();
    link.poll(10, on_frame);
    REQUIRE(link.stats().errors() == 0);
    REQUIRE(link.stats().sequence_gaps == 0);
    REQUIRE(markers == test::reference_output(rig.streams).markers);
    std::size_t wanted = 0;  // camera 1's blue and yellow markers, all fields
    for (const auto& [key, v] : markers)
        for (const auto& m : v) wanted += key.first == 1 && m.colour_class >= 3;
    CHECK(wanted >= 6);
    CHECK(checked == wanted);
    CHECK(core->counters().patches_sent == wanted);
    CHECK(wrong == 0);
    CHECK(orphans == 0);
    CHECK(assembler->stats().incomplete == 0);
}
