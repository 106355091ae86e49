#pragma once
// A firmware core wired to fake hardware: three in-memory camera streams on a modelled clock, a memory sink and
// a command source. Shared by the core tests and the benchmark.
#include "eyesim/firmware/device_core.hpp"
#include "eyesim/firmware/pc/field_source.hpp"
#include "eyesim/firmware/pc/latency_log.hpp"
#include "eyesim/firmware/pc/modelled_clock.hpp"
#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/fpga/wire.hpp"

#include "fake_hal.hpp"
#include "field_gen.hpp"

#include <cstring>
#include <map>
#include <memory>
#include <utility>
#include <vector>

namespace eyesim::test {

struct CoreRig {
    std::array<std::vector<std::uint8_t>, 3> streams;
    firmware::pc::ModelledClock clock;
    std::vector<std::unique_ptr<firmware::pc::FieldSource>> cams;
    MemorySink sink;
    QueueSource source;
    firmware::pc::LatencyLog latency{1u << 16};
    std::unique_ptr<firmware::DeviceCore> core;

    /// `camera_offset_us`: each camera's field starts that much after the genlocked time (unsynchronised cameras).
    CoreRig(int fields, int markers, const firmware::CoreConfig& config = {},
            const std::array<std::uint64_t, 3>& camera_offset_us = {}) {
        for (int c = 0; c < 3; ++c) streams[c] = make_stream(c, fields, markers);
        firmware::DeviceHal hal;
        for (int c = 0; c < 3; ++c) {
            const std::vector<std::uint8_t>* s = &streams[c];
            const std::uint64_t offset_us = camera_offset_us[std::size_t(c)];
            cams.push_back(std::make_unique<firmware::pc::FieldSource>(
                [s, offset_us](std::uint64_t k, std::uint8_t* out, std::uint8_t& parity, std::uint64_t& start_us) {
                    if ((k + 1) * kFieldBytes > s->size()) return false;
                    std::memcpy(out, s->data() + k * kFieldBytes, kFieldBytes);
                    parity = static_cast<std::uint8_t>(k % 2);
                    start_us += offset_us;
                    return true;
                }));
            hal.cameras[c] = cams.back().get();
        }
        hal.sink = &sink;
        hal.source = &source;
        hal.clock = &clock;
        hal.latency = &latency;
        core = std::make_unique<firmware::DeviceCore>(hal, config);
    }

    void command(const protocol::Command& c) { source.push(command_frame(c)); }

    /// Runs the streams to their end, servicing the host side after every line step, then drains.
    void run() {
        while (core->step_cameras() != firmware::StepStatus::finished) core->service();
        for (int i = 0; i < 1000 && !core->tx_idle(); ++i) core->service();
        core->service();
    }
};

/// Markers of one camera field as the host assembles them from its parts.
using FieldKey = std::pair<int, std::uint32_t>;
using FieldMap = std::map<FieldKey, std::vector<protocol::Marker>>;

/// What `eyesim fpga --out` writes for the same streams: the FPGA model run directly, each field's blobs
/// converted with the shared conversion (fpga/wire.hpp). Field k starts at device time k·20 000 µs.
struct Reference {
    FieldMap markers;                                // per (camera, field)
    std::vector<protocol::FieldMarkers> messages;    // camera by camera, field by field
};

inline Reference reference_output(const std::array<std::vector<std::uint8_t>, 3>& streams,
                                  const fpga::RegisterMap& regs = {}) {
    Reference out;
    for (int c = 0; c < 3; ++c) {
        fpga::PipelineConfig pc;
        pc.camera = static_cast<std::uint8_t>(c);
        auto pipe = std::make_unique<fpga::Pipeline>(regs, pc);
        const int fields = static_cast<int>(streams[c].size() / kFieldBytes);
        for (int k = 0; k < fields; ++k) {
            const auto parity = static_cast<std::uint8_t>(k % 2);
            const std::uint64_t start_us = static_cast<std::uint64_t>(k) * 20000;
            pipe->process_field(streams[c].data() + kFieldBytes * k, kH, static_cast<std::uint32_t>(k), parity);
            std::vector<fpga::Blob> blobs;
            fpga::Blob b;
            while (pipe->pop_blob(b)) blobs.push_back(b);
            auto& v = out.markers[{c, static_cast<std::uint32_t>(k)}];
            for (const auto& blob : blobs) v.push_back(fpga::to_marker(blob, start_us));
            std::vector<protocol::FieldMarkers> parts(fpga::field_markers_messages(blobs.size()));
            const auto info = fpga::field_info(pipe->field_stats(), static_cast<std::uint8_t>(c), parity, start_us);
            parts.resize(fpga::to_field_markers(blobs.data(), blobs.size(), info, parts.data(), parts.size()));
            out.messages.insert(out.messages.end(), parts.begin(), parts.end());
        }
    }
    return out;
}

}  // namespace eyesim::test
