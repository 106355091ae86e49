#include "eyesim/app/refine.hpp"

#include "eyesim/app/fpga_run.hpp"
#include "eyesim/fpga/wire.hpp"

#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/video.hpp"

#include <algorithm>
#include <cmath>
#include <span>
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
    hinted_.assign(blobs.size(), 0);
    int refined = 0;
    for (std::size_t i = 0; i < blobs.size(); ++i) {
        fpga::Blob& b = blobs[i];
        bool hinted = false;
        const tracking::SphereFitResult r =
            tracking::MarkerHintSource::fit(hints_, field, height, boxes_[i], camera, config_, *work_, hinted);
        hinted_fits_ += hinted;
        hinted_[i] = hinted ? 1 : 0;
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
                       tracking::TrackingFrame& frame, tracking::MarkerHintSource& hints, HintMotion* motion) {
    std::stable_sort(msgs.begin(), msgs.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    for (const auto& [t_us, m] : msgs) {
        tracker.push(m, t_us);
        while (tracker.pop(frame, t_us)) hints.update(frame);
        if (motion) motion->push(m, t_us);
    }
    msgs.clear();
}

namespace {
tracking::TrackerConfig async_config(tracking::TrackerConfig config) {
    config.sync.mode = tracking::SyncMode::Async;
    config.async.report_delay_us = 0.0;  // only its filters' poses are read, never its frames
    return config;
}
}  // namespace

HintMotion::HintMotion(tracking::TrackerConfig config) : tracker_(async_config(std::move(config))) {}

void HintMotion::push(const protocol::FieldMarkers& msg, double received_us) {
    tracker_.push(msg, received_us);
    while (tracker_.pop(frame_, received_us)) {
    }
    frame_pose_ok_ = false;  // the filters moved on: the poses at the frame's time again when next asked
}

bool HintMotion::move_to_field(const tracking::TrackingFrame& frame, int camera, int parity, uint64_t field_start_us,
                               tracking::MarkerHintSource& hints) {
    const auto& timing = tracker_.config().timing;
    const int n = std::min(frame.instrument_count, static_cast<int>(at_frame_.size()));
    if (n <= 0 || camera < 0 || camera >= static_cast<int>(timing.size())) return false;
    // The field's exposure time as the tracker takes it: its end (the last active line's, as the device stamps
    // it) less the camera's end-to-exposure time for the parity.
    const double end_us = static_cast<double>(fpga::field_end_us(field_start_us));
    const double field_us = end_us - timing[static_cast<size_t>(camera)].end_to_sample_us[static_cast<size_t>(parity & 1)];
    // The poses at the frame's time serve every camera's field until the next message (push).
    if (!frame_pose_ok_ || frame_pose_us_ != frame.time_device_us) {
        tracking::EyePose eye1 = frame.eye;
        std::copy_n(frame.instruments.begin(), n, at_frame_.begin());
        frame_pose_ok_ =
            tracker_.pose_at(frame.time_device_us, eye1, std::span<tracking::InstrumentPose>(at_frame_.data(), n));
        frame_pose_us_ = frame.time_device_us;
    }
    follow_one_view(frame, n);
    tracking::EyePose eye2 = frame.eye;
    std::copy_n(frame.instruments.begin(), n, at_field_.begin());
    const bool filtered =
        frame_pose_ok_ && tracker_.pose_at(field_us, eye2, std::span<tracking::InstrumentPose>(at_field_.data(), n));
    tracking::EyePose eye = frame.eye;
    eye.flags = tracking::kPoseHeld;  // the eye's hint stays the frame's (above)
    bool any = false;
    for (int b = 0; b < n; ++b) {
        const auto k = static_cast<size_t>(b);
        const tracking::InstrumentPose &p = frame.instruments[k], &a1 = at_frame_[k], &a2 = at_field_[k];
        tracking::InstrumentPose& o = moved_[k];
        o = p;
        // Placed from one view only: at its placements' own velocity (the filters do not follow it).
        if (!p.measured() && ((frame.one_view_mask >> b) & 1u)) {
            if (move_one_view(b, field_us, o)) {
                any = true;
            } else {
                o.flags = tracking::kPoseHeld;
            }
            continue;
        }
        // From a measured pose only (pose_at leaves a body its filters do not follow as it was: not moved).
        if (!(filtered && p.measured() && a1.measured() && a2.measured())) {
            o.flags = tracking::kPoseHeld;
            continue;
        }
        const Eigen::Quaterniond motion = a2.rotation_body_to_rig * a1.rotation_body_to_rig.inverse();
        o.rotation_body_to_rig = (motion * p.rotation_body_to_rig).normalized();
        o.tip_rig_mm = motion * (p.tip_rig_mm - a1.tip_rig_mm) + a2.tip_rig_mm;
        o.axis_rig = motion * p.axis_rig;
        any = true;
    }
    if (any) hints.predict(eye, std::span<const tracking::InstrumentPose>(moved_.data(), static_cast<size_t>(n)));
    return any;
}

void HintMotion::follow_one_view(const tracking::TrackingFrame& frame, int n) {
    for (int b = 0; b < n; ++b) {
        OneViewTrack& t = one_view_[static_cast<size_t>(b)];
        if (frame.instruments[static_cast<size_t>(b)].measured() || !((frame.one_view_mask >> b) & 1u)) {
            t.n = 0;  // measured (the filters take it), or not placed: the track ends
            continue;
        }
        if (t.n > 0 && t.last_us == frame.time_device_us) continue;  // this frame's placement is taken already
        if (t.n > 0 && !(frame.time_device_us - t.last_us <= kOneViewMotionMaxUs)) t.n = 0;
        t.prev = t.last;
        t.prev_us = t.last_us;
        t.last = frame.one_view[static_cast<size_t>(b)];
        t.last_us = frame.time_device_us;
        t.n = std::min(t.n + 1, 2);
    }
}

bool HintMotion::move_one_view(int body, double field_us, tracking::InstrumentPose& out) const {
    const OneViewTrack& t = one_view_[static_cast<size_t>(body)];
    const double dt_us = t.last_us - t.prev_us;
    if (t.n < 2 || !(dt_us > 0) || std::fabs(field_us - t.last_us) > kOneViewMotionMaxUs) return false;
    // The velocity of the last two placements from the newer one on: through three or four, `occlusion` seeds 155,
    // 169, 171, 172 and 184 lost (the needle's withdrawal speeds up and slows).
    const double s = (field_us - t.last_us) / dt_us;
    const Eigen::Vector3d axis = t.last.axis_rig + s * (t.last.axis_rig - t.prev.axis_rig);
    if (!(axis.norm() > 0.5)) return false;
    // One-view poses have no roll: the newer one's orientation turned onto the moved axis.
    const Eigen::Quaterniond turn = Eigen::Quaterniond::FromTwoVectors(t.last.axis_rig, axis.normalized());
    out = t.last;
    out.tip_rig_mm = t.last.tip_rig_mm + s * (t.last.tip_rig_mm - t.prev.tip_rig_mm);
    out.axis_rig = axis.normalized();
    out.rotation_body_to_rig = (turn * t.last.rotation_body_to_rig).normalized();
    return out.tip_rig_mm.allFinite() && out.axis_rig.allFinite();
}

}  // namespace eyesim::app
