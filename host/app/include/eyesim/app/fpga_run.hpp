#pragma once
/// \file
/// The bit-true FPGA model over a recording as the device runs it: one pipeline per camera with the register map
/// the device powers up with plus register writes in the device's address space, each field stamped on the
/// device clock the way eyesim-device stamps it. Shared by `eyesim fpga` (which writes what it finds) and
/// `eyesim compare` (which holds it against a device's capture).

#include "eyesim/fpga/blob.hpp"
#include "eyesim/fpga/field_stats.hpp"
#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/fpga/register_map.hpp"
#include "eyesim/protocol/messages.hpp"
#include "eyesim/rig/recording.hpp"

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace eyesim::app {

/// Parses "0,1,2" into camera indices below `count` (empty text: every camera). Throws Error (exit 2) naming the
/// bad item.
std::vector<int> parse_cameras(const std::string& text, int count);

/// The register map of each of `camera_count` cameras after the reset values and the `--reg ADDRESS=VALUE`
/// writes (C integer syntax: 0x14=3), in order, in the device's address space (docs/protocol.md section 4.6):
/// 0x0000–0x0FFF writes the pipeline register at that offset of every camera (checked against every camera first,
/// applied to all or none), 0x1000–0x1FFF, 0x2000–0x2FFF, 0x3000–0x3FFF only camera 0, 1, 2's. Throws Error
/// (exit 2) naming the write that is malformed, outside those windows, or refused by the map (read-only, range).
/// `base`: the maps the writes start from (e.g. read from a capture) instead of the reset values.
std::vector<fpga::RegisterMap> register_maps(const std::vector<std::string>& writes, int camera_count,
                                             std::vector<fpga::RegisterMap> base = {});

/// One camera field through the model. `blobs` may be changed (refined) before the field is packed.
struct ModelField {
    int camera = 0;                    ///< camera index
    int64_t index = 0;                 ///< field index in the recording (= the device's field_counter)
    int parity = 0;                    ///< 0 top, 1 bottom
    uint64_t start_us = 0;             ///< device time of the field's cycle 0 (recording clock, see fpga_run.cpp)
    const uint8_t* uyvy = nullptr;     ///< the field's pixels, 720 × rig::kFieldHeight UYVY
    const fpga::FieldStats* stats = nullptr;  ///< the pipeline's counters for this field
    std::vector<fpga::Blob>* blobs = nullptr; ///< the blobs in the order the pipeline emitted them
};

/// The FieldMarkers messages the device sends for `f` in per-field mode: parts of up to 14 markers in blob order
/// (fpga/wire.hpp), every one with the field's end time.
std::vector<protocol::FieldMarkers> field_messages(const ModelField& f);

/// Device time in ns at which `f`'s messages are ready to send: its last active pixel is in and its last blob has
/// left the pipeline (as the device core queues a field).
uint64_t field_ready_ns(const ModelField& f);

/// One pipeline per selected camera over a recording.
class FpgaModelRun {
public:
    /// `cameras`: indices into the recording; `maps`: one register map per recording camera (register_maps()).
    FpgaModelRun(rig::Recording& rec, std::vector<int> cameras, const std::vector<fpga::RegisterMap>& maps);
    ~FpgaModelRun();
    FpgaModelRun(const FpgaModelRun&) = delete;
    FpgaModelRun& operator=(const FpgaModelRun&) = delete;

    /// The selected cameras, in the order fields are processed.
    const std::vector<int>& cameras() const { return cams_; }
    /// Runs field `index` of every selected camera in camera order and calls `on_field` with each. Throws Error
    /// (exit 1) naming the camera and field when the pipeline refuses it; rig::RigError when it cannot be read.
    void run_field(int64_t index, const std::function<void(ModelField&)>& on_field);
    /// Wall time spent inside the pipeline model so far, s.
    double model_seconds() const { return model_s_; }

private:
    rig::Recording& rec_;
    std::vector<int> cams_;
    std::vector<std::unique_ptr<fpga::Pipeline>> pipes_;
    std::vector<uint8_t> field_;
    std::vector<fpga::Blob> blobs_;
    double model_s_ = 0.0;
};

}  // namespace eyesim::app
