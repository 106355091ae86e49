#include "eyesim/app/refine.hpp"

#include "eyesim/app/fpga_run.hpp"

#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/video.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

namespace eyesim::app {

tracking::SphereFitConfig rig_sphere_fit_config() {
    tracking::SphereFitConfig cfg;
    for (int c = 1; c <= 4; ++c) {
        const auto rgb = rig::marker_class_rgb(c);
        cfg.colour[static_cast<size_t>(c)] = tracking::MarkerColour::from_rgb(rgb[0], rgb[1], rgb[2]);
    }
    return cfg;
}

tracking::SphereFitConfig recording_sphere_fit_config(const rig::Recording& rec) {
    tracking::SphereFitConfig cfg = rig_sphere_fit_config();
    if (rec.camera_count() < 1 || rec.format(0) != rig::StreamFormat::kVideo) return cfg;
    // Opening reads the header and one frame: what the decoder gives (codec, pixel format).
    const rig::VideoInfo info = rig::VideoReader(rec.stream_path(0)).info();
    const bool lossless = info.codec == "ffv1" || info.codec == "rawvideo" || info.codec == "huffyuv" ||
                          info.codec == "ffvhuff" || info.codec == "utvideo";
    cfg = tracking::sphere_fit_config_for_source(cfg, info.chroma.c_str(), lossless);
    // The chroma modelled as the reader gives it, at the sensor's σ where the codec is lossless: 4:2:0 down the
    // lines (tracking::chroma_chain_420), 4:1:1 across the columns for the fits without a hint (chroma_chain_411).
    cfg.chain_chroma_noise_dn = lossless ? cfg.noise_dn : tracking::kLossyChainChromaNoiseDn;
    if (info.chroma == "4:2:0") {
        double site[2][2];
        for (int parity = 0; parity < 2; ++parity)
            for (int c = 0; c < 2; ++c) site[parity][c] = rig::field_chroma_site(info, parity, c);
        tracking::chroma_chain_420(cfg, site, rig::kFieldHeight);
    }
    if (info.chroma == "4:1:1") tracking::chroma_chain_411(cfg, rig::chroma_column_site(info));
    return cfg;
}

BlobRefiner::BlobRefiner() : BlobRefiner(rig_sphere_fit_config()) {}

BlobRefiner::BlobRefiner(const tracking::SphereFitConfig& config)
    : config_(config), work_(std::make_unique<tracking::SphereFitWorkspace>()) {}

int BlobRefiner::refine(const uint8_t* field, int height, std::vector<fpga::Blob>& blobs, int camera) {
    boxes_.clear();
    for (const fpga::Blob& b : blobs) boxes_.push_back(tracking::blob_box(b));
    tracking::mark_foreign_overlaps(boxes_);
    outcomes_.assign(blobs.size(), "kept");
    int refined = 0;
    for (std::size_t i = 0; i < blobs.size(); ++i) {
        fpga::Blob& b = blobs[i];
        bool hinted = false;
        const tracking::SphereFitResult r =
            tracking::MarkerHintSource::fit(hints_, field, height, boxes_[i], camera, config_, *work_, hinted);
        hinted_fits_ += hinted;
        if (!r.ok) {
            ++refusals_[static_cast<size_t>(r.refusal)];
            outcomes_[i] = tracking::to_string(r.refusal);
            continue;
        }
        if (r.cx_px < 0 || r.cy_px < 0) continue;  // the wire's unsigned Q16 cannot hold it: keep the pipeline's
        outcomes_[i] = hinted ? "hinted" : "fitted";
        b.cx_q16 = static_cast<uint32_t>(std::llround(r.cx_px * 65536.0));
        b.cy_q16 = static_cast<uint32_t>(std::llround(r.cy_px * 65536.0));
        ++refined;
    }
    return refined;
}

nlohmann::json BlobRefiner::refusals_json() const {
    nlohmann::json why = nlohmann::json::object();
    for (int r = 1; r < tracking::kFitRefusalCount; ++r)
        why[tracking::to_string(static_cast<tracking::FitRefusal>(r))] = refusals_[static_cast<size_t>(r)];
    return why;
}

int64_t prime_marker_hints(const std::string& dir, const std::vector<int>& cams,
                           const std::vector<fpga::RegisterMap>& maps, const tracking::SphereFitConfig& fit,
                           tracking::TrackerConfig tracker_config, int64_t max_fields,
                           tracking::MarkerHintSource& hints) {
    // A second opening: its own decoder state and warnings (the tool's pass reports what the fields hold).
    rig::Recording rec = rig::Recording::open(dir);
    const int64_t n = std::min(max_fields, rec.common_field_count());
    FpgaModelRun model(rec, cams, maps);
    BlobRefiner refiner(fit);
    tracking::Tracker tracker(std::move(tracker_config));
    tracking::TrackingFrame frame;
    std::vector<std::pair<double, protocol::FieldMarkers>> msgs;
    int64_t i = 0;
    while (i < n && !hints.ready()) {
        model.run_field(i, [&](ModelField& f) {
            refiner.refine(f.uyvy, rig::kFieldHeight, *f.blobs, f.camera);
            const double ready_us = 1e-3 * static_cast<double>(field_ready_ns(f));
            for (const protocol::FieldMarkers& m : field_messages(f)) msgs.push_back({ready_us, m});
        });
        ++i;
        feed_hint_tracker(msgs, tracker, frame, hints);
    }
    return i;
}

void feed_hint_tracker(std::vector<std::pair<double, protocol::FieldMarkers>>& msgs, tracking::Tracker& tracker,
                       tracking::TrackingFrame& frame, tracking::MarkerHintSource& hints) {
    std::stable_sort(msgs.begin(), msgs.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    for (const auto& [t_us, m] : msgs) {
        tracker.push(m, t_us);
        while (tracker.pop(frame, t_us)) hints.update(frame);
    }
    msgs.clear();
}

}  // namespace eyesim::app
