#include "eyesim/app/fpga_run.hpp"

#include "eyesim/app/command.hpp"
#include "eyesim/firmware/capacity.hpp"
#include "eyesim/firmware/registers.hpp"
#include "eyesim/fpga/timing.hpp"
#include "eyesim/fpga/wire.hpp"
#include "eyesim/rig/pal.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <sstream>

namespace eyesim::app {

std::vector<int> parse_cameras(const std::string& text, int count) {
    std::vector<int> cams;
    if (text.empty()) {
        for (int c = 0; c < count; ++c) cams.push_back(c);
        return cams;
    }
    std::stringstream ss(text);
    std::string item;
    while (std::getline(ss, item, ',')) {
        size_t used = 0;
        int c = -1;
        try {
            c = std::stoi(item, &used);
        } catch (const std::exception&) {
            used = 0;
        }
        if (used != item.size() || item.empty() || c < 0 || c >= count)
            throw Error(fmt::format("--cameras: '{}': not a camera index 0..{}", item, count - 1), 2);
        if (std::find(cams.begin(), cams.end(), c) == cams.end()) cams.push_back(c);
    }
    if (cams.empty()) throw Error("--cameras: empty list", 2);
    return cams;
}

std::vector<fpga::RegisterMap> register_maps(const std::vector<std::string>& writes, int camera_count,
                                             std::vector<fpga::RegisterMap> base) {
    std::vector<fpga::RegisterMap> maps = std::move(base);
    maps.resize(static_cast<size_t>(std::max(camera_count, 0)));
    for (const std::string& w : writes) {
        const size_t eq = w.find('=');
        unsigned long addr = 0, value = 0;
        bool ok = eq != std::string::npos && eq > 0 && eq + 1 < w.size();
        if (ok) {
            try {
                size_t a = 0, v = 0;
                addr = std::stoul(w.substr(0, eq), &a, 0);
                value = std::stoul(w.substr(eq + 1), &v, 0);
                ok = a == eq && v == w.size() - eq - 1 && addr <= 0xFFFF && value <= 0xFFFFFFFFul;
            } catch (const std::exception&) {
                ok = false;
            }
        }
        if (!ok) throw Error(fmt::format("--reg: '{}': expected ADDRESS=VALUE", w), 2);
        // The device's windows: broadcast at 0x0000, camera c at (c + 1) · 0x1000 (firmware/registers.hpp).
        const uint32_t target = static_cast<uint32_t>(addr) & firmware::kRegTargetMask;
        const auto offset = static_cast<uint16_t>(addr & firmware::kRegOffsetMask);
        size_t first = 0, last = maps.size();
        if (target != 0) {
            first = target / firmware::kRegCameraBase - 1;
            last = first + 1;
            if (target > firmware::kRegCameraBase * firmware::kCameras)
                throw Error(fmt::format("--reg: '{}': not a pipeline register (0x0000–0x3FFF; firmware registers do "
                                        "not change what the pipelines find)", w), 2);
            if (first >= maps.size())
                throw Error(fmt::format("--reg: '{}': camera {} window, but the recording has {} cameras", w, first,
                                        maps.size()), 2);
        }
        for (size_t c = first; c < last; ++c)  // all cameras or none, as the device
            if (const fpga::RegWriteResult r = maps[c].check_write(offset, static_cast<uint32_t>(value));
                r != fpga::RegWriteResult::kOk)
                throw Error(fmt::format("--reg: '{}': register write refused: {}", w, fpga::to_string(r)), 2);
        for (size_t c = first; c < last; ++c) maps[c].write(offset, static_cast<uint32_t>(value));
    }
    return maps;
}

std::vector<protocol::FieldMarkers> field_messages(const ModelField& f) {
    const fpga::FieldInfo info = fpga::field_info(*f.stats, static_cast<uint8_t>(f.camera), static_cast<uint8_t>(f.parity),
                                                  f.start_us);
    std::vector<protocol::FieldMarkers> msgs(fpga::field_markers_messages(f.blobs->size()));
    msgs.resize(fpga::to_field_markers(f.blobs->data(), f.blobs->size(), info, msgs.data(), msgs.size()));
    return msgs;
}

uint64_t field_ready_ns(const ModelField& f) {
    const uint32_t end_cycle = std::max(f.stats->last_emit_cycle, f.stats->last_active_line_end_cycle);
    return f.start_us * 1000u + fpga::cycles_to_ns(end_cycle);
}

FpgaModelRun::FpgaModelRun(rig::Recording& rec, std::vector<int> cameras, const std::vector<fpga::RegisterMap>& maps)
    : rec_(rec), cams_(std::move(cameras)), field_(static_cast<size_t>(rig::kFieldBytes)) {
    for (int c : cams_) {
        fpga::PipelineConfig cfg;
        cfg.camera = static_cast<uint8_t>(c);
        pipes_.push_back(std::make_unique<fpga::Pipeline>(maps.at(static_cast<size_t>(c)), cfg));
    }
    blobs_.reserve(fpga::kMaxBlobSlots);
}

FpgaModelRun::~FpgaModelRun() = default;

void FpgaModelRun::run_field(int64_t index, const std::function<void(ModelField&)>& on_field) {
    for (size_t k = 0; k < cams_.size(); ++k) {
        const int cam = cams_[k];
        rec_.read_field(cam, index, field_.data());
        const int parity = rec_.field_parity(cam, index);
        const rig::FieldTiming timing = rec_.field_timing(cam, index);
        fpga::Pipeline& p = *pipes_[k];
        blobs_.clear();
        p.set_sink([](void* c, const fpga::Blob& b) { static_cast<std::vector<fpga::Blob>*>(c)->push_back(b); },
                   &blobs_);
        const auto t0 = std::chrono::steady_clock::now();
        const fpga::PipelineStatus s = p.process_field(field_.data(), rig::kFieldHeight, static_cast<uint32_t>(index),
                                                       static_cast<uint8_t>(parity));
        model_s_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        if (s != fpga::PipelineStatus::kOk)
            throw Error(fmt::format("{}: camera {} field {}: pipeline status {}", rec_.dir(), cam, index,
                                    static_cast<int>(s)));
        ModelField f;
        f.camera = cam;
        f.index = index;
        f.parity = parity;
        // Device time of the field's cycle 0: vertical sync (+ half a line for a bottom field), as eyesim-device
        // stamps it (after its epoch).
        f.start_us = static_cast<uint64_t>(std::llround(std::max(0.0, timing.start_us + (parity ? 32.0 : 0.0))));
        f.uyvy = field_.data();
        f.stats = &p.field_stats();
        f.blobs = &blobs_;
        on_field(f);
    }
}

}  // namespace eyesim::app
