// `eyesim compare` through the programs a user runs: the FPGA model's own capture compares identical; a capture
// with one flipped LSB, one blob removed or added, or made with one register changed does not, and the command
// names the difference; a capture of the live path (eyesim-device over TCP, recorded by `eyesim track
// --capture-out`) compares identical to the model.
#include "../../firmware/child_process.hpp"

#include "eyesim/fpga/register_map.hpp"
#include "eyesim/protocol/capture.hpp"
#include "eyesim/protocol/capture_replay.hpp"
#include "eyesim/protocol/codec.hpp"

#include "cli_run.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <array>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
namespace proto = eyesim::protocol;
using Result = eyesim::test::CliResult;
using nlohmann::json;

/// The test's scratch folder, one per process, removed at exit.
const fs::path& scratch() {
    static const eyesim::test::ScratchDir dir("eyesim_test_compare");
    return dir.path();
}

Result run_eyesim(const std::string& args) { return eyesim::test::run_cli(scratch(), EYESIM_EXE, args, 120); }

/// A 10-field `sweep` recording (instruments moving over the eye), made once per process.
const fs::path& recording() {
    static const fs::path d = [] {
        const fs::path p = scratch() / "rec";
        const Result r = run_eyesim("synth --scenario sweep --seconds 0.2 --seed 5 --out " + p.string());
        REQUIRE(r.rc == 0);
        return p;
    }();
    return d;
}

/// `eyesim fpga --out` over the recording (extra options in `extra`), and its JSON summary.
json model_capture(const fs::path& out, const std::string& extra = "") {
    const Result r = run_eyesim("fpga --recording " + recording().string() + " --out " + out.string() + " --json " + extra);
    INFO(r.err);
    REQUIRE(r.rc == 0);
    return json::parse(r.out);
}

/// The model's capture with the reset register map, made once per process.
const fs::path& model() {
    static const fs::path p = [] {
        const fs::path c = scratch() / "model.bin";
        const json j = model_capture(c);
        REQUIRE(j["fields"].get<int>() == 30);  // 3 cameras × 10 fields
        REQUIRE(j["blobs"].get<int>() > 60);
        return c;
    }();
    return p;
}

/// `eyesim compare --json` of `capture` against the recording; `rc` set to the exit status.
json compare(const fs::path& capture, int& rc, const std::string& extra = "") {
    const Result r = run_eyesim("compare --recording " + recording().string() + " --capture " + capture.string() +
                                " --json " + extra);
    INFO("compare stderr: " << r.err << "\nstdout: " << r.out);
    rc = r.rc;
    REQUIRE((r.rc == 0 || r.rc == 3));
    return json::parse(r.out);
}

/// Copies `src` to `dst` frame by frame through the protocol codec: `edit` may change a decoded message (it is
/// re-encoded with its sequence number, so its CRC is good) or return false to leave the frame out. `before`: a
/// message written first (sequence number one before the first frame's).
void rewrite(const fs::path& src, const fs::path& dst, const std::function<bool(proto::Message&)>& edit,
             const std::optional<proto::Message>& before = std::nullopt) {
    auto replay = std::make_unique<proto::CaptureReplay>();
    REQUIRE(replay->open(src.c_str()));
    proto::CaptureWriter out;
    REQUIRE(out.create(dst.c_str()));
    proto::DecodedFrame f;
    uint64_t rx_us = 0;
    std::array<uint8_t, proto::kMaxFrameBytes> bytes{};
    bool first = true;
    while (replay->next(f, rx_us)) {
        if (first && before) {
            const size_t n = proto::encode_frame(*before, uint16_t(f.header.sequence - 1), bytes);
            REQUIRE(n > 0);
            REQUIRE(out.write(rx_us, std::span<const uint8_t>(bytes.data(), n)));
        }
        first = false;
        if (!edit(f.message)) continue;
        const size_t n = proto::encode_frame(f.message, f.header.sequence, bytes);
        REQUIRE(n > 0);
        REQUIRE(out.write(rx_us, std::span<const uint8_t>(bytes.data(), n)));
    }
    REQUIRE(replay->status() == proto::CaptureStatus::End);
    out.close();
}

/// The first single-message field of camera 1 with at least three blobs (the one the tests change).
struct Target {
    int camera = -1;
    uint32_t field = 0;
    proto::FieldMarkers message;
};
Target find_target(const fs::path& capture) {
    Target t;
    rewrite(capture, scratch() / "scan.bin", [&](proto::Message& m) {
        const auto* fm = std::get_if<proto::FieldMarkers>(&m);
        if (t.camera < 0 && fm && fm->camera_id == 1 && fm->marker_count >= 3 && fm->part_index == 0 &&
            !(fm->flags & proto::kFieldFlagMoreFollows)) {
            t.camera = fm->camera_id;
            t.field = fm->field_counter;
            t.message = *fm;
        }
        return true;
    });
    REQUIRE(t.camera == 1);
    return t;
}

/// Calls `edit` on the target field's message only.
std::function<bool(proto::Message&)> on_target(const Target& t, const std::function<void(proto::FieldMarkers&)>& edit) {
    return [&t, edit](proto::Message& m) {
        auto* fm = std::get_if<proto::FieldMarkers>(&m);
        if (fm && fm->camera_id == t.camera && fm->field_counter == t.field) edit(*fm);
        return true;
    };
}

int64_t value_mismatches(const json& j) {
    int64_t n = 0;
    for (const auto& [name, count] : j["counts"]["value_mismatch"].items()) n += count.get<int64_t>();
    return n;
}

}  // namespace

TEST_CASE("compare: the model's own capture is identical, and every field is compared", "[host][compare]") {
    const json fpga = model_capture(scratch() / "again.bin");
    int rc = -1;
    const json j = compare(model(), rc);
    CHECK(rc == 0);
    CHECK(j["identical"] == true);
    CHECK(j["mismatches"] == 0);
    CHECK(j["first_mismatch"].is_null());
    CHECK(value_mismatches(j) == 0);
    for (const char* k : {"blob_missing", "blob_extra", "field_missing", "field_extra"}) CHECK(j["counts"][k] == 0);
    for (const auto& [name, count] : j["counts"]["header_mismatch"].items()) CHECK(count == 0);
    // Every field of every camera compared, one message each (no field of this recording has over 14 blobs), and
    // every blob the model found.
    CHECK(j["compared"]["fields"] == fpga["fields"]);
    CHECK(j["compared"]["messages"] == fpga["fields"]);
    CHECK(j["compared"]["markers"] == fpga["blobs"]);
    CHECK(j["compared"]["values"].get<int64_t>() == 11 * fpga["blobs"].get<int64_t>());
    CHECK(j["device"]["field_markers"] == fpga["fields"]);
    CHECK(j["device"]["pedal_states"].get<int>() == 10);  // one per field period, not compared
    CHECK(j["device_epoch_us"] == 0);                     // the model writes the recording clock

    // The text says so too, on stdout only.
    const Result text = run_eyesim("compare --recording " + recording().string() + " --capture " + model().string());
    CHECK(text.rc == 0);
    CHECK(text.out.find("identical") != std::string::npos);
    CHECK(text.err.empty());
}

TEST_CASE("compare: one flipped LSB in one blob's coordinate is found and named", "[host][compare]") {
    const Target t = find_target(model());
    const fs::path cap = scratch() / "flipped.bin";
    rewrite(model(), cap, on_target(t, [](proto::FieldMarkers& m) { m.markers[1].x_q16 ^= 1u; }));
    int rc = -1;
    const json j = compare(cap, rc);
    CHECK(rc == 3);
    CHECK(j["identical"] == false);
    CHECK(j["mismatches"] == 1);
    CHECK(j["counts"]["value_mismatch"]["x_q16"] == 1);
    CHECK(value_mismatches(j) == 1);
    const json& f = j["first_mismatch"];
    CHECK(f["kind"] == "value_mismatch");
    CHECK(f["camera"] == t.camera);
    CHECK(f["field"] == t.field);
    CHECK(f["blob"] == 1);
    CHECK(f["device_blob"] == 1);
    CHECK(f["value"] == "x_q16");
    CHECK(f["model"] == t.message.markers[1].x_q16);
    CHECK(f["device"] == (t.message.markers[1].x_q16 ^ 1u));
    // The neighbouring blobs of both sides: blobs 0, 1, 2, the device's with the flipped value.
    REQUIRE(f["neighbours"]["model"].size() == 3);
    REQUIRE(f["neighbours"]["device"].size() == 3);
    CHECK(f["neighbours"]["model"][0]["blob"] == 0);
    CHECK(f["neighbours"]["model"][1]["x_q16"] == t.message.markers[1].x_q16);
    CHECK(f["neighbours"]["device"][1]["x_q16"] == (t.message.markers[1].x_q16 ^ 1u));
    CHECK(f["neighbours"]["device"][2]["y_q16"] == t.message.markers[2].y_q16);

    // The text names it on one line.
    const Result text = run_eyesim("compare --recording " + recording().string() + " --capture " + cap.string());
    CHECK(text.rc == 3);
    const std::string line = "first mismatch: value_mismatch at camera 1, field " + std::to_string(t.field) +
                             ", blob 1 (device blob 1): x_q16 model " + std::to_string(t.message.markers[1].x_q16) +
                             " device " + std::to_string(t.message.markers[1].x_q16 ^ 1u) + "\n";
    CHECK(text.out.find(line) != std::string::npos);
}

TEST_CASE("compare: one blob removed is one blob missing in the device, one added one extra", "[host][compare]") {
    const Target t = find_target(model());
    const fs::path removed = scratch() / "removed.bin";
    rewrite(model(), removed, on_target(t, [](proto::FieldMarkers& m) {
                for (int i = 1; i + 1 < m.marker_count; ++i) m.markers[i] = m.markers[i + 1];
                --m.marker_count;
            }));
    int rc = -1;
    json j = compare(removed, rc);
    CHECK(rc == 3);
    CHECK(j["mismatches"] == 1);  // aligned: the blobs after it are not shifted into mismatches
    CHECK(j["counts"]["blob_missing"] == 1);
    CHECK(j["counts"]["blob_extra"] == 0);
    CHECK(value_mismatches(j) == 0);
    CHECK(j["first_mismatch"]["kind"] == "blob_missing");
    CHECK(j["first_mismatch"]["camera"] == t.camera);
    CHECK(j["first_mismatch"]["field"] == t.field);
    CHECK(j["first_mismatch"]["blob"] == 1);

    const fs::path added = scratch() / "added.bin";
    rewrite(model(), added, on_target(t, [](proto::FieldMarkers& m) {
                m.markers[m.marker_count] = m.markers[0];
                m.markers[m.marker_count].bbox_x0 = m.markers[m.marker_count].bbox_x1 = 700;  // somewhere else
                ++m.marker_count;
            }));
    j = compare(added, rc);
    CHECK(rc == 3);
    CHECK(j["mismatches"] == 1);
    CHECK(j["counts"]["blob_extra"] == 1);
    CHECK(j["first_mismatch"]["kind"] == "blob_extra");
    CHECK(j["first_mismatch"]["device_blob"] == t.message.marker_count);

    // A field the device never sent, and one it sent twice.
    const fs::path lost = scratch() / "lost.bin";
    rewrite(model(), lost, [&](proto::Message& m) {
        const auto* fm = std::get_if<proto::FieldMarkers>(&m);
        return !(fm && fm->camera_id == t.camera && fm->field_counter == t.field);
    });
    j = compare(lost, rc);
    CHECK(rc == 3);
    CHECK(j["mismatches"] == 1);
    CHECK(j["counts"]["field_missing"] == 1);
    CHECK(j["counts"]["blob_missing"] == 0);  // its blobs are in the missing field, not counted again
    CHECK(j["first_mismatch"]["kind"] == "field_missing");
}

TEST_CASE("compare: a capture made with one register changed differs unless compare is told", "[host][compare]") {
    // MIN_AREA 30 (reset 2): the smaller marker images are filtered out.
    const fs::path cap = scratch() / "min_area.bin";
    const json fpga = model_capture(cap, "--reg 0x01C=30");
    REQUIRE(fpga["blobs"].get<int>() > 0);
    int rc = -1;
    json j = compare(cap, rc);
    CHECK(rc == 3);
    CHECK(j["counts"]["blob_extra"] == 0);
    CHECK(j["counts"]["blob_missing"].get<int64_t>() > 0);
    CHECK(j["compared"]["fields"] == 30);

    j = compare(cap, rc, "--reg 0x01C=30");
    CHECK(rc == 0);
    CHECK(j["identical"] == true);
    CHECK(j["compared"]["markers"] == fpga["blobs"]);
    CHECK(j["registers"] == json::array({"0x01C=30"}));

    // The same register in camera 1's window only: a broadcast write differs in cameras 0 and 2.
    const fs::path cam1 = scratch() / "min_area_cam1.bin";
    model_capture(cam1, "--reg 0x201C=30");
    j = compare(cam1, rc, "--reg 0x201C=30");
    CHECK(rc == 0);
    j = compare(cam1, rc, "--reg 0x01C=30");
    CHECK(rc == 3);
    CHECK(j["first_mismatch"]["camera"] != 1);
    j = compare(cam1, rc, "--reg 0x01C=30 --cameras 1");
    CHECK(rc == 0);

    // A capture in which the device acknowledged a register write whose command the capture does not hold (as
    // one written by another tool): the Reply has the value but not the address, so compare cannot know the map.
    proto::Reply ack;
    ack.command_id = 7;
    ack.opcode = uint8_t(proto::Opcode::RegisterWrite);
    ack.value = 30;
    const fs::path acked = scratch() / "acked.bin";
    rewrite(cap, acked, [](proto::Message&) { return true; }, proto::Message{ack});
    const Result r = run_eyesim("compare --recording " + recording().string() + " --capture " + acked.string() +
                                " --reg 0x01C=30 --json");
    CHECK(r.rc == 0);
    CHECK(r.err == "eyesim: warning: " + acked.string() + ": 1 register write(s) acknowledged by the device; the "
                   "capture does not hold their addresses: give the device's writes with --reg\n");
    j = json::parse(r.out);
    CHECK(j["device"]["register_writes"] == 1);
    CHECK(j["warnings"].size() == 1);
}

TEST_CASE("compare: nothing compared is never a pass, and bad input or usage is an error", "[host][compare]") {
    int rc = -1;
    // A capture of camera 0 only against all three cameras: the other cameras' fields are missing.
    const fs::path cam0 = scratch() / "cam0.bin";
    model_capture(cam0, "--cameras 0");
    json j = compare(cam0, rc);
    CHECK(rc == 3);
    CHECK(j["counts"]["field_missing"] == 20);
    j = compare(cam0, rc, "--cameras 0");
    CHECK(rc == 0);
    CHECK(j["compared"]["fields"] == 10);

    // No FieldMarkers at all (only the pedal): nothing to compare, an error.
    const fs::path pedal = scratch() / "pedal.bin";
    rewrite(model(), pedal, [](proto::Message& m) { return !std::holds_alternative<proto::FieldMarkers>(m); });
    Result r = run_eyesim("compare --recording " + recording().string() + " --capture " + pedal.string());
    CHECK(r.rc == 1);
    CHECK(r.err.rfind("eyesim: error: " + pedal.string() + ": no FieldMarkers", 0) == 0);

    r = run_eyesim("compare --recording " + recording().string() + " --capture " + (scratch() / "absent.bin").string());
    CHECK(r.rc == 1);
    CHECK(r.err.rfind("eyesim: error: ", 0) == 0);
    r = run_eyesim("compare --recording " + (scratch() / "no_recording").string() + " --capture " + model().string());
    CHECK(r.rc == 1);
    for (const char* bad : {"--reg 0x4000=1", "--reg 0x01C", "--reg 0x01C=0", "--reg 0x000=1", "--cameras 3"}) {
        r = run_eyesim("compare --recording " + recording().string() + " --capture " + model().string() + " " + std::string(bad));
        INFO(bad << ": " << r.err);
        CHECK(r.rc == 2);
        CHECK(r.err.rfind("eyesim: error: ", 0) == 0);
        CHECK(r.out.empty());
    }
    r = run_eyesim("compare --recording " + recording().string());
    CHECK(r.rc == 2);
}

/// Plays the recording on eyesim-device (with `device_flags`) over TCP loopback and records what `eyesim track`
/// receives with --capture-out into `capture`.
void live_capture(const fs::path& capture, const std::vector<std::string>& device_flags = {}) {
    std::vector<std::string> argv{EYESIM_DEVICE_EXE, "--recording", recording().string(), "--port", "0",
                                  "--linger-ms", "300"};
    argv.insert(argv.end(), device_flags.begin(), device_flags.end());
    eyesim::test::ChildProcess device(argv);
    REQUIRE(device.started());
    const std::string listening = device.read_line(10000);
    REQUIRE(listening.rfind("listening tcp://", 0) == 0);
    const std::string uri = listening.substr(std::string("listening ").size());
    const Result host = run_eyesim("track --connect " + uri + " --rig " + (recording() / "rig.yaml").string() +
                                   " --capture-out " + capture.string() + " --json");
    INFO(host.err);
    REQUIRE(host.rc == 0);
    CHECK(json::parse(host.out)["capture_out"] == capture.string());
    REQUIRE(device.wait(10000) == 0);
}

TEST_CASE("compare: the live path (eyesim-device over TCP, recorded by the host) is identical to the model",
          "[host][compare][e2e]") {
    const fs::path live = scratch() / "live.bin";
    live_capture(live);
    int rc = -1;
    json j = compare(live, rc);
    CHECK(rc == 0);
    CHECK(j["identical"] == true);
    CHECK(j["compared"]["fields"] == 30);
    CHECK(j["compared"]["messages"] == 30);
    // The device clock runs from its start-up: the recording's t = 0 was played on a later whole millisecond.
    CHECK(j["device_epoch_us"].get<int64_t>() > 0);
    CHECK(j["device_epoch_us"].get<int64_t>() % 1000 == 0);
    CHECK(j["device"]["replies"].get<int>() > 0);  // the pongs to the host's pings, not compared
    // The same capture against a map the device did not have.
    j = compare(live, rc, "--reg 0x01C=30");
    CHECK(rc == 3);
    CHECK(j["counts"]["blob_extra"].get<int64_t>() > 0);

    // Low-latency mode: each blob in its own message as it completes; the field's markers are the same.
    const fs::path low = scratch() / "live_low_latency.bin";
    live_capture(low, {"--low-latency"});
    j = compare(low, rc);
    CHECK(rc == 0);
    CHECK(j["device"]["low_latency_fields"] == 30);
    CHECK(j["compared"]["fields"] == 30);
    CHECK(j["compared"]["messages"].get<int64_t>() > 30);
    CHECK(j["compared"]["markers"] == model_capture(scratch() / "again.bin")["blobs"]);

    // --capture-out goes with a live source only.
    const Result bad = run_eyesim("track --capture " + live.string() + " --rig " + (recording() / "rig.yaml").string() +
                                  " --capture-out " + (scratch() / "x.bin").string());
    CHECK(bad.rc == 2);
}

TEST_CASE("compare: a host capture holds the device's register map, so compare needs no --reg",
          "[host][compare][e2e]") {
    // The device powered up with registers a configuration tool changed; the host's capture records its reads of
    // every pipeline register and the device's replies.
    const fs::path cap = scratch() / "live_configured.bin";
    live_capture(cap, {"--reg", "0x01C=30", "--reg", "0x2038=2"});
    int rc = -1;
    json j = compare(cap, rc);
    CHECK(rc == 0);
    CHECK(j["identical"] == true);
    CHECK(j["compared"]["fields"] == 30);
    int writable = 0;
    for (const eyesim::fpga::RegisterInfo& r : eyesim::fpga::register_table()) writable += r.writable;
    CHECK(j["device"]["registers_from_capture"] == 3 * writable);  // every camera's whole map
    CHECK(j["device"]["host_commands"].get<int>() > 3 * writable);  // the reads, stream_start, pings
    CHECK(j["device"]["register_changes_after_first_field"] == 0);
    CHECK(j["warnings"].empty());
    // Replaying the capture sees the device's stream alone: the host's commands are no loss and no gap.
    const Result replayed = run_eyesim("track --capture " + cap.string() + " --rig " +
                                       (recording() / "rig.yaml").string() + " --json");
    REQUIRE(replayed.rc == 0);
    const json tj = json::parse(replayed.out);
    CHECK(tj["loss"]["frames_lost"] == 0);
    CHECK(tj["loss"]["sequence_gaps"] == 0);
    CHECK(tj["loss"]["frames_repeated"] == 0);
    // The same device's fields are not the reset map's: --reg on top of the capture's map puts the reset back.
    j = compare(cap, rc, "--reg 0x01C=2");
    CHECK(rc == 3);
    CHECK(j["counts"]["blob_missing"].get<int64_t>() > 0);
    // A version-1 capture of the same run (no Sent records: the received records alone, header version 1) holds
    // no map: compare uses the reset values and finds the difference.
    const fs::path v1 = scratch() / "live_configured_v1.bin";
    {
        proto::CaptureReader reader;
        REQUIRE(reader.open(cap.c_str()));
        std::ofstream out(v1, std::ios::binary | std::ios::trunc);
        std::ifstream in(cap, std::ios::binary);
        std::vector<char> header(proto::kCaptureHeaderBytes);
        in.read(header.data(), std::streamsize(header.size()));
        header[8] = 1;
        out.write(header.data(), std::streamsize(header.size()));
        proto::CaptureRecord rec;
        while (reader.next(rec) == proto::CaptureStatus::Ok) {
            if (rec.direction == proto::CaptureDirection::Sent) continue;
            in.seekg(std::streamoff(rec.file_offset));
            std::vector<char> whole(proto::kCaptureRecordHeaderBytes + rec.bytes.size() + proto::kCaptureRecordCrcBytes);
            in.read(whole.data(), std::streamsize(whole.size()));
            out.write(whole.data(), std::streamsize(whole.size()));
        }
    }
    j = compare(v1, rc);
    CHECK(rc == 3);
    CHECK(j["device"]["registers_from_capture"] == 0);
    j = compare(v1, rc, "--reg 0x01C=30 --reg 0x2038=2");
    CHECK(rc == 0);
}
