// `eyesim compare`: the bit-true FPGA model (the golden reference) against a device's capture of the same
// recording, field by field and message by message: every header value, every marker value, the device times.
#include "eyesim/app/command.hpp"
#include "eyesim/app/fpga_run.hpp"
#include "eyesim/firmware/capacity.hpp"
#include "eyesim/firmware/registers.hpp"
#include "eyesim/fpga/register_map.hpp"
#include "eyesim/protocol/capture_replay.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/recording.hpp"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cstdio>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <variant>
#include <vector>

namespace {

namespace proto = eyesim::protocol;
namespace rig = eyesim::rig;
namespace firmware = eyesim::firmware;
using eyesim::app::Error;

struct CompareOptions {
    std::string recording;
    std::string capture;
    std::string cameras;
    std::vector<std::string> regs;
    int64_t max_fields = -1;
    bool json = false;
};

// The marker values compared, in wire order (docs/protocol.md section 4.1). complete_us is a device time.
constexpr size_t kValues = 11;
constexpr std::array<const char*, kValues> kValueNames = {"colour_class", "flags", "bbox_x0", "bbox_y0",
                                                          "bbox_x1", "bbox_y1", "x_q16", "y_q16",
                                                          "area_px", "intensity_sum", "complete_us"};
constexpr size_t kCompleteUs = 10;

// The field header values compared: parity, the device's blobs_dropped flag, the field's end time, and how the
// field is cut into messages (part_index, more_follows, markers per part, field_end_us on every part).
constexpr size_t kHeaders = 4;
constexpr std::array<const char*, kHeaders> kHeaderNames = {"field_parity", "blobs_dropped", "field_end_us", "parts"};
enum Header : size_t { kParity, kBlobsDropped, kFieldEnd, kParts };

// Device times are compared after removing one epoch: the device time at which the recording's t = 0 was played.
std::array<int64_t, kValues> values_of(const proto::Marker& m, int64_t epoch_us) {
    return {m.colour_class, m.flags,  m.bbox_x0, m.bbox_y0,       m.bbox_x1,
            m.bbox_y1,      m.x_q16,  m.y_q16,   m.area_px,       m.intensity_sum,
            static_cast<int64_t>(m.complete_us) - epoch_us};
}

// One camera field as sent: its messages (parts) and their markers in order.
struct SentField {
    std::vector<proto::FieldMarkers> parts;  // markers arrays cleared: the markers are below
    std::vector<proto::Marker> markers;
    bool complete = false;  // its last part (more_follows clear) has come
    int repeats = 0;        // further copies of a complete field (each an extra field)
    bool stray = false;     // a later part of a field that had already ended
    uint64_t end_us() const { return parts.empty() ? 0 : parts.back().field_end_us; }
    bool low_latency() const {
        return std::any_of(parts.begin(), parts.end(), [](const auto& p) { return p.flags & proto::kFieldFlagLowLatency; });
    }
    bool blobs_dropped() const {
        return std::any_of(parts.begin(), parts.end(), [](const auto& p) { return p.flags & proto::kFieldFlagBlobsDropped; });
    }
    void add(const proto::FieldMarkers& m) {
        proto::FieldMarkers head = m;
        head.markers = {};
        parts.push_back(head);
        markers.insert(markers.end(), m.markers.begin(), m.markers.begin() + m.marker_count);
        complete = !(m.flags & proto::kFieldFlagMoreFollows);
    }
};

// Whether the device's parts are cut as a device cuts them: part_index 0, 1, … with more_follows on all but the
// last, one parity; per-field mode also 14 markers in every part but the last and the field end on every part.
bool parts_as_device_cuts(const SentField& d) {
    if (!d.complete || d.stray) return false;
    const bool low = d.low_latency();
    for (size_t p = 0; p < d.parts.size(); ++p) {
        const proto::FieldMarkers& m = d.parts[p];
        const bool last = p + 1 == d.parts.size();
        if (m.part_index != p || bool(m.flags & proto::kFieldFlagMoreFollows) == last ||
            m.field_parity != d.parts[0].field_parity || bool(m.flags & proto::kFieldFlagLowLatency) != low)
            return false;
        if (!low && ((!last && m.marker_count != proto::kMaxMarkersPerMessage) || m.field_end_us != d.end_us()))
            return false;
    }
    return true;
}

// Same blob, perhaps with other values: the same colour class and overlapping boxes.
bool same_blob(const proto::Marker& a, const proto::Marker& b) {
    return a.colour_class == b.colour_class && a.bbox_x0 <= b.bbox_x1 && b.bbox_x0 <= a.bbox_x1 &&
           a.bbox_y0 <= b.bbox_y1 && b.bbox_y0 <= a.bbox_y1;
}

// One step of the alignment of the model's blobs with the device's: a pair, or a blob on one side only.
struct Step {
    int model = -1;   // index into the model's blobs, -1: extra in device
    int device = -1;  // index into the device's blobs, -1: missing in device
};

// Aligns two blob lists in emission order with the fewest differences: a pair of the same blob costs its share of
// differing values (< 1), a blob on one side only costs 1, so a dropped or added blob does not shift every blob
// after it into a run of value mismatches.
std::vector<Step> align(const std::vector<proto::Marker>& m, const std::vector<proto::Marker>& d, int64_t epoch_us) {
    const size_t n = m.size(), k = d.size();
    constexpr double kInf = std::numeric_limits<double>::infinity();
    auto pair_cost = [&](size_t i, size_t j) {
        if (!same_blob(m[i], d[j])) return kInf;
        const auto a = values_of(m[i], 0), b = values_of(d[j], epoch_us);
        int diff = 0;
        for (size_t v = 0; v < kValues; ++v) diff += a[v] != b[v];
        return diff / double(kValues + 1);
    };
    std::vector<double> cost((n + 1) * (k + 1), 0.0);
    auto at = [&](size_t i, size_t j) -> double& { return cost[i * (k + 1) + j]; };
    for (size_t i = 0; i <= n; ++i)
        for (size_t j = 0; j <= k; ++j) {
            if (i == 0 || j == 0) {
                at(i, j) = double(i + j);
                continue;
            }
            at(i, j) = std::min({at(i - 1, j - 1) + pair_cost(i - 1, j - 1), at(i - 1, j) + 1.0, at(i, j - 1) + 1.0});
        }
    std::vector<Step> steps;
    for (size_t i = n, j = k; i > 0 || j > 0;) {
        if (i > 0 && j > 0 && at(i, j) == at(i - 1, j - 1) + pair_cost(i - 1, j - 1)) {
            steps.push_back({int(--i), int(--j)});
        } else if (i > 0 && at(i, j) == at(i - 1, j) + 1.0) {
            steps.push_back({int(--i), -1});
        } else {
            steps.push_back({-1, int(--j)});
        }
    }
    std::reverse(steps.begin(), steps.end());
    return steps;
}

// Where blob `index` of a field travelled: its message (part) and its slot in that message. The model cuts a field
// as the device does in per-field mode (`parts` empty); a device field says it in its parts.
std::pair<size_t, size_t> place(size_t index, const std::vector<proto::FieldMarkers>& parts) {
    if (parts.empty()) return {index / proto::kMaxMarkersPerMessage, index % proto::kMaxMarkersPerMessage};
    size_t p = 0;
    for (; p + 1 < parts.size() && index >= parts[p].marker_count; ++p) index -= parts[p].marker_count;
    return {p, index};
}

nlohmann::json blob_json(const proto::Marker& m, size_t index, int64_t epoch_us,
                         const std::vector<proto::FieldMarkers>& parts) {
    const auto [message, slot] = place(index, parts);
    nlohmann::json j{{"blob", index}, {"message", message}, {"marker", slot}};
    const auto v = values_of(m, epoch_us);
    for (size_t k = 0; k < kValues; ++k) j[kValueNames[k]] = v[k];
    j["x_px"] = m.x_q16 / 65536.0;
    j["y_px"] = m.y_q16 / 65536.0;
    return j;
}

std::string blob_line(const char* side, const nlohmann::json& b) {
    return fmt::format("  {:<6} blob {}: class {} flags 0x{:x} box {},{}-{},{} x {:.6f} y {:.6f} px area {} sum {} "
                       "complete {} us\n",
                       side, b["blob"].get<int>(), b["colour_class"].get<int>(), b["flags"].get<int>(),
                       b["bbox_x0"].get<int>(), b["bbox_y0"].get<int>(), b["bbox_x1"].get<int>(),
                       b["bbox_y1"].get<int>(), b["x_px"].get<double>(), b["y_px"].get<double>(),
                       b["area_px"].get<int64_t>(), b["intensity_sum"].get<int64_t>(), b["complete_us"].get<int64_t>());
}

// The blobs of one side next to blob `centre` (one either side).
nlohmann::json neighbours(const std::vector<proto::Marker>& markers, int centre, int64_t epoch_us,
                          const std::vector<proto::FieldMarkers>& parts) {
    nlohmann::json a = nlohmann::json::array();
    for (int i = centre - 1; i <= centre + 1; ++i)
        if (i >= 0 && i < int(markers.size())) a.push_back(blob_json(markers[size_t(i)], size_t(i), epoch_us, parts));
    return a;
}

struct Counts {
    std::array<int64_t, kValues> value{};
    std::array<int64_t, kHeaders> header{};
    int64_t blob_missing = 0, blob_extra = 0, field_missing = 0, field_extra = 0;
    int64_t total() const {
        int64_t t = blob_missing + blob_extra + field_missing + field_extra;
        for (int64_t v : value) t += v;
        for (int64_t h : header) t += h;
        return t;
    }
};

int run(const CompareOptions& opt) {
    rig::Recording rec = rig::Recording::open(opt.recording);
    const std::vector<int> cams = eyesim::app::parse_cameras(opt.cameras, rec.camera_count());
    std::vector<std::string> warnings;  // the capture's, then the recording's
    const int64_t recorded_fields = rec.common_field_count();
    const int64_t n_fields = opt.max_fields >= 0 ? std::min(recorded_fields, opt.max_fields) : recorded_fields;

    // The device's side: every message of the capture; FieldMarkers gathered per camera field.
    auto replay = std::make_unique<proto::CaptureReplay>();
    if (!replay->open(opt.capture.c_str()))
        throw Error(fmt::format("{}: {}", opt.capture, replay->reader().open_error_message()));
    std::map<std::pair<int, uint32_t>, SentField> sent;
    int64_t field_markers = 0, pedal_states = 0, device_status = 0, replies = 0, commands = 0, register_writes = 0;
    // The device's register map as the capture holds it: the host's register reads and writes (its Sent records,
    // eyesim track --capture-out) paired with the device's acknowledgements by command id, up to the first field.
    struct SentCommand {
        uint8_t opcode;
        uint32_t address;
    };
    std::map<uint32_t, SentCommand> sent_commands;
    std::vector<eyesim::fpga::RegisterMap> captured_maps(size_t(std::max(rec.camera_count(), 0)));
    int64_t registers_read = 0, register_changes_in_stream = 0, host_commands = 0;
    uint32_t first_change_address = 0;
    proto::DecodedFrame frame;
    uint64_t rx_us = 0;
    bool from_host = false;
    while (replay->next(frame, rx_us, from_host)) {
        if (from_host) {
            ++host_commands;
            if (const auto* c = std::get_if<proto::Command>(&frame.message))
                sent_commands[c->command_id] = SentCommand{c->opcode, c->address};
            continue;
        }
        switch (proto::message_type(frame.message)) {
            case proto::MessageType::FieldMarkers: {
                const auto& m = std::get<proto::FieldMarkers>(frame.message);
                ++field_markers;
                SentField& f = sent[{m.camera_id, m.field_counter}];
                if (!f.complete) f.add(m);
                else if (m.part_index == 0) ++f.repeats;  // the same field again
                else f.stray = true;
                break;
            }
            case proto::MessageType::PedalState: ++pedal_states; break;  // the pedal is not the FPGA's
            case proto::MessageType::DeviceStatus: ++device_status; break;
            case proto::MessageType::Reply: {
                const auto& r = std::get<proto::Reply>(frame.message);
                ++replies;
                const bool is_register = r.opcode == uint8_t(proto::Opcode::RegisterWrite) ||
                                         r.opcode == uint8_t(proto::Opcode::RegisterRead);
                if (!is_register || r.status != uint8_t(proto::ReplyStatus::Ack)) break;
                const auto it = sent_commands.find(r.command_id);
                if (it == sent_commands.end() || it->second.opcode != r.opcode) {
                    register_writes += r.opcode == uint8_t(proto::Opcode::RegisterWrite);  // address unknown
                    break;
                }
                // A pipeline register: the broadcast window writes every camera (and reads camera 0), the camera
                // windows one camera; the firmware's own registers do not change what the pipelines find.
                const uint32_t target = it->second.address & firmware::kRegTargetMask;
                const auto offset = uint16_t(it->second.address & firmware::kRegOffsetMask);
                const eyesim::fpga::RegisterInfo* info = eyesim::fpga::find_register(offset);
                if (target > firmware::kRegCameraBase * firmware::kCameras || !info || !info->writable) break;
                size_t first_cam = 0, last_cam = captured_maps.size();
                if (target != 0 || r.opcode == uint8_t(proto::Opcode::RegisterRead)) {
                    first_cam = target == 0 ? 0 : target / firmware::kRegCameraBase - 1;
                    last_cam = std::min(first_cam + 1, captured_maps.size());
                }
                for (size_t c = first_cam; c < last_cam; ++c) {
                    if (field_markers == 0) {
                        registers_read += captured_maps[c].write(offset, r.value) == eyesim::fpga::RegWriteResult::kOk;
                    } else if (captured_maps[c].get(offset) != r.value) {
                        if (register_changes_in_stream++ == 0) first_change_address = it->second.address;
                    }
                }
                break;
            }
            case proto::MessageType::Command: ++commands; break;
            case proto::MessageType::BlobPatch: break;  // pixels, not markers: compared by the patch tests
        }
    }
    const proto::ParserStats& ps = replay->stats();
    if (replay->status() == proto::CaptureStatus::IoError) throw Error(opt.capture + ": read error");
    if (field_markers == 0)
        throw Error(fmt::format("{}: no FieldMarkers messages ({} frames, {} bytes skipped): nothing to compare",
                                opt.capture, ps.frames, ps.skipped_bytes));
    if (replay->reader().corrupt_regions() > 0)
        warnings.push_back(fmt::format("{}: {} damaged stretches ({} bytes) skipped", opt.capture,
                                       replay->reader().corrupt_regions(), replay->reader().corrupt_bytes()));
    if (replay->status() == proto::CaptureStatus::Torn)
        warnings.push_back(fmt::format("{}: torn tail at byte {} ({} bytes) skipped", opt.capture,
                                       replay->reader().bad_offset(), replay->reader().dropped_bytes()));
    // A Reply carries the value, not the address: a write whose command the capture does not hold (a version-1
    // capture, or one written by another tool) leaves the map unknown.
    if (register_writes > 0)
        warnings.push_back(fmt::format("{}: {} register write(s) acknowledged by the device; the capture does not hold "
                                       "their addresses: give the device's writes with --reg", opt.capture,
                                       register_writes));
    if (register_changes_in_stream > 0)
        warnings.push_back(fmt::format("{}: {} register value(s) changed after the first field (first: 0x{:04X}); the "
                                       "model runs with the map from before the first field", opt.capture,
                                       register_changes_in_stream, first_change_address));
    // The model's register maps: the capture's (reset values where it holds none), then --reg on top.
    const std::vector<eyesim::fpga::RegisterMap> maps =
        eyesim::app::register_maps(opt.regs, rec.camera_count(), std::move(captured_maps));
    if (ps.errors() || ps.skipped_bytes || ps.sequence_gaps)
        warnings.push_back(fmt::format("{}: {} damaged frames, {} bytes skipped, {} sequence gaps: what was lost shows "
                                       "as missing fields", opt.capture, ps.errors(), ps.skipped_bytes, ps.sequence_gaps));

    // The model's side, with the register map the device used.
    struct ModelSide {
        int camera;
        int64_t index;
        int parity;
        bool blobs_dropped;
        uint64_t end_us;
        std::vector<proto::Marker> markers;
    };
    std::vector<ModelSide> model;
    model.reserve(size_t(n_fields) * cams.size());
    eyesim::app::FpgaModelRun run(rec, cams, maps);
    const bool progress = eyesim::app::show_progress(opt.json);
    for (int64_t i = 0; i < n_fields; ++i) {
        run.run_field(i, [&](eyesim::app::ModelField& f) {
            ModelSide s{f.camera, f.index, f.parity, false, 0, {}};
            for (const proto::FieldMarkers& m : eyesim::app::field_messages(f)) {
                s.blobs_dropped = s.blobs_dropped || (m.flags & proto::kFieldFlagBlobsDropped);
                s.end_us = m.field_end_us;
                s.markers.insert(s.markers.end(), m.markers.begin(), m.markers.begin() + m.marker_count);
            }
            model.push_back(std::move(s));
        });
        if (progress && (i % 25 == 0 || i + 1 == n_fields))
            std::fprintf(stderr, "\rcompare: model field %lld/%lld", static_cast<long long>(i + 1),
                         static_cast<long long>(n_fields));
    }
    if (progress) std::fprintf(stderr, "\n");
    // The recording's findings, those of reading its fields included (a video field that could not be decoded is
    // modelled black, and its mismatches have this reason).
    warnings.insert(warnings.end(), rec.warnings().begin(), rec.warnings().end());

    // The epoch: the most common difference of the field end times (eyesim-device plays the recording's t = 0 on a
    // whole millisecond after its start-up; `eyesim fpga --out` at 0). One wrong end time does not move it.
    std::map<int64_t, int64_t> offsets;
    for (const ModelSide& s : model)
        if (const auto it = sent.find({s.camera, uint32_t(s.index)}); it != sent.end() && it->second.complete)
            ++offsets[int64_t(it->second.end_us()) - int64_t(s.end_us)];
    int64_t epoch_us = 0, best = 0;
    for (const auto& [off, n] : offsets)
        if (n > best) epoch_us = off, best = n;

    Counts counts;
    int64_t fields_compared = 0, messages_compared = 0, markers_compared = 0, values_compared = 0, low_latency = 0;
    nlohmann::json first;  // the first mismatch in field, camera, blob order
    auto note = [&](nlohmann::json j) {
        if (first.is_null()) first = std::move(j);
    };
    for (const ModelSide& s : model) {
        const auto it = sent.find({s.camera, uint32_t(s.index)});
        const nlohmann::json where{{"camera", s.camera}, {"field", s.index}, {"parity", s.parity}};
        if (it == sent.end()) {
            ++counts.field_missing;
            nlohmann::json j = where;
            j["kind"] = "field_missing";
            j["model_blobs"] = s.markers.size();
            note(j);
            continue;
        }
        const SentField& d = it->second;
        ++fields_compared;
        messages_compared += int64_t(d.parts.size());
        low_latency += d.low_latency();
        const int64_t dev_end = int64_t(d.end_us()) - epoch_us;
        const std::array<std::pair<int64_t, int64_t>, kHeaders> header = {
            std::pair<int64_t, int64_t>{s.parity, d.parts[0].field_parity},
            {s.blobs_dropped, d.blobs_dropped()},
            {int64_t(s.end_us), dev_end},
            {1, parts_as_device_cuts(d)}};
        for (size_t h = 0; h < kHeaders; ++h) {
            if (header[h].first == header[h].second) continue;
            ++counts.header[h];
            nlohmann::json j = where;
            j["kind"] = "header_mismatch";
            j["value"] = kHeaderNames[h];
            if (h == kParts) {
                nlohmann::json parts = nlohmann::json::array();
                for (const auto& p : d.parts)
                    parts.push_back({{"part_index", p.part_index}, {"flags", p.flags}, {"marker_count", p.marker_count},
                                     {"field_end_us", int64_t(p.field_end_us) - epoch_us}});
                j["device_parts"] = parts;
                j["complete"] = d.complete;
            } else {
                j["model"] = header[h].first;
                j["device"] = header[h].second;
            }
            note(j);
        }
        if (d.repeats > 0) {
            counts.field_extra += d.repeats;
            nlohmann::json j = where;
            j["kind"] = "field_extra";
            j["repeats"] = d.repeats;
            note(j);
        }
        for (const Step& st : align(s.markers, d.markers, epoch_us)) {
            nlohmann::json j = where;
            if (st.device < 0) {
                ++counts.blob_missing;
                j["kind"] = "blob_missing";
                j["blob"] = st.model;
            } else if (st.model < 0) {
                ++counts.blob_extra;
                j["kind"] = "blob_extra";
                j["device_blob"] = st.device;
            } else {
                ++markers_compared;
                values_compared += int64_t(kValues);
                const auto a = values_of(s.markers[size_t(st.model)], 0);
                const auto b = values_of(d.markers[size_t(st.device)], epoch_us);
                bool noted = false;
                for (size_t v = 0; v < kValues; ++v) {
                    if (a[v] == b[v]) continue;
                    ++counts.value[v];
                    if (noted || !first.is_null()) continue;
                    j["kind"] = "value_mismatch";
                    j["blob"] = st.model;
                    j["device_blob"] = st.device;
                    j["value"] = kValueNames[v];
                    j["model"] = a[v];
                    j["device"] = b[v];
                    noted = true;
                }
                if (!noted) continue;
            }
            if (first.is_null()) {
                const int mi = st.model >= 0 ? st.model : int(std::min<size_t>(size_t(st.device), s.markers.size()));
                const int di = st.device >= 0 ? st.device : int(std::min<size_t>(size_t(st.model), d.markers.size()));
                j["neighbours"] = {{"model", neighbours(s.markers, mi, 0, {})},
                                   {"device", neighbours(d.markers, di, epoch_us, d.parts)}};
                note(j);
            }
        }
    }
    // Device fields the model has none for: past the recording's end, or of a camera the recording lacks.
    int64_t ignored = 0, beyond_limit = 0;
    std::vector<std::pair<uint32_t, int>> extra;  // (field, camera)
    for (const auto& [key, f] : sent) {
        const auto [cam, counter] = key;
        const bool selected = std::find(cams.begin(), cams.end(), cam) != cams.end();
        if (!selected && cam < rec.camera_count()) {
            ignored += int64_t(f.parts.size());
        } else if (selected && int64_t(counter) < n_fields) {
            continue;  // compared above
        } else if (selected && int64_t(counter) < recorded_fields) {
            beyond_limit += int64_t(f.parts.size());  // after --fields
        } else {
            counts.field_extra += 1 + f.repeats;
            extra.emplace_back(counter, cam);
        }
    }
    std::sort(extra.begin(), extra.end());
    if (!extra.empty())
        note({{"kind", "field_extra"}, {"camera", extra.front().second}, {"field", extra.front().first},
              {"device_blobs", sent.at({extra.front().second, extra.front().first}).markers.size()}});

    const int64_t mismatches = counts.total();
    nlohmann::json values = nlohmann::json::object(), headers = nlohmann::json::object();
    for (size_t v = 0; v < kValues; ++v) values[kValueNames[v]] = counts.value[v];
    for (size_t h = 0; h < kHeaders; ++h) headers[kHeaderNames[h]] = counts.header[h];
    nlohmann::json j{
        {"recording", opt.recording},
        {"capture", opt.capture},
        {"cameras", cams},
        {"registers", opt.regs},
        {"model_fields", model.size()},
        {"compared", {{"fields", fields_compared}, {"messages", messages_compared}, {"markers", markers_compared},
                      {"values", values_compared}}},
        {"device", {{"field_markers", field_markers}, {"pedal_states", pedal_states}, {"device_status", device_status},
                    {"replies", replies}, {"register_writes", register_writes}, {"commands", commands},
                    {"registers_from_capture", registers_read}, {"register_changes_after_first_field",
                                                                 register_changes_in_stream},
                    {"host_commands", host_commands},
                    {"ignored_messages", ignored}, {"after_fields_limit", beyond_limit},
                    {"low_latency_fields", low_latency}}},
        {"device_epoch_us", epoch_us},
        {"counts", {{"value_mismatch", values}, {"blob_missing", counts.blob_missing}, {"blob_extra", counts.blob_extra},
                    {"field_missing", counts.field_missing}, {"field_extra", counts.field_extra},
                    {"header_mismatch", headers}}},
        {"mismatches", mismatches},
        {"identical", mismatches == 0},
        {"first_mismatch", first},
        {"capture_damage", {{"errors", ps.errors()}, {"skipped_bytes", ps.skipped_bytes},
                            {"sequence_gaps", ps.sequence_gaps}, {"corrupt_regions", replay->reader().corrupt_regions()},
                            {"torn", replay->status() == proto::CaptureStatus::Torn}}},
        {"warnings", warnings}};
    for (const std::string& w : warnings) std::fprintf(stderr, "eyesim: warning: %s\n", w.c_str());
    if (opt.json) {
        std::printf("%s\n", j.dump().c_str());
    } else {
        std::string text = fmt::format(
            "{} against {}: {} camera fields, {} messages, {} markers ({} values) compared; device epoch {} us\n",
            opt.recording, opt.capture, fields_compared, messages_compared, markers_compared, values_compared, epoch_us);
        if (mismatches == 0) {
            text += "identical: the device sent what the model computes\n";
        } else {
            std::string per_value;
            for (size_t v = 0; v < kValues; ++v)
                if (counts.value[v]) per_value += fmt::format(" {} {}", kValueNames[v], counts.value[v]);
            std::string per_header;
            for (size_t h = 0; h < kHeaders; ++h)
                if (counts.header[h]) per_header += fmt::format(" {} {}", kHeaderNames[h], counts.header[h]);
            text += fmt::format("{} mismatches: value{}; blob missing in device {}; extra blob in device {}; field "
                                "missing {}; field extra {}; header{}\n",
                                mismatches, per_value.empty() ? " 0" : per_value, counts.blob_missing,
                                counts.blob_extra, counts.field_missing, counts.field_extra,
                                per_header.empty() ? " 0" : per_header);
            const std::string kind = first["kind"];
            text += fmt::format("first mismatch: {} at camera {}, field {}", kind, first["camera"].get<int>(),
                                first["field"].get<int64_t>());
            if (first.contains("blob")) text += fmt::format(", blob {}", first["blob"].get<int>());
            if (first.contains("device_blob")) text += fmt::format(" (device blob {})", first["device_blob"].get<int>());
            if (first.contains("value")) text += fmt::format(": {}", first["value"].get<std::string>());
            if (first.contains("model"))
                text += fmt::format(" model {} device {}", first["model"].dump(), first["device"].dump());
            text += "\n";
            if (first.contains("neighbours")) {
                for (const auto& b : first["neighbours"]["model"]) text += blob_line("model", b);
                for (const auto& b : first["neighbours"]["device"]) text += blob_line("device", b);
            }
        }
        std::fputs(text.c_str(), stdout);
    }
    return mismatches == 0 && fields_compared > 0 ? 0 : 3;
}

eyesim::app::Registrar reg{
    "compare", "Compare a device's capture with the FPGA model run on the same recording", [](CLI::App& sub) {
        auto opt = std::make_shared<CompareOptions>();
        sub.add_option("--recording", opt->recording, "the recording the device played (rig.yaml + cam*.uyvy or video)")
            ->required();
        sub.add_option("--capture", opt->capture, "the device's capture file (or raw protocol stream)")->required();
        sub.add_option("--reg", opt->regs,
                       "register write ADDRESS=VALUE the device had before its first field, on top of the map the "
                       "capture holds (repeatable; 0x0000-0x0FFF every camera, 0x1000/0x2000/0x3000 + offset one "
                       "camera)");
        sub.add_option("--cameras", opt->cameras, "comma-separated camera indices to compare (default: all)");
        sub.add_option("--fields", opt->max_fields, "compare at most this many fields per camera")
            ->check(CLI::Range(int64_t{1}, std::numeric_limits<int64_t>::max()));
        sub.add_flag("--json", opt->json, "print one JSON object on stdout");
        return [opt]() -> int {
            try {
                return run(*opt);
            } catch (const rig::RigError& e) {
                throw Error(e.what());
            }
        };
    }};

}  // namespace
