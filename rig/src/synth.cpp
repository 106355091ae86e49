#include "eyesim/rig/synth.hpp"

#include "eyesim/rig/error.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/video.hpp"

#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>

namespace eyesim::rig {

RigSynth::RigSynth(std::vector<CameraModel> cams, Bodies bodies, Scenario scenario, const RenderOptions& opt)
    : cams_(std::move(cams)), bodies_(std::move(bodies)), scenario_(std::move(scenario)) {
    markers_ = scene_markers(bodies_, scenario_.kinds(), scenario_.has_wand());
    for (size_t c = 0; c < cams_.size(); ++c)
        renderers_.emplace_back(cams_[c], static_cast<int>(c), bodies_.eye.center_rig_mm, bodies_.eye.radius_mm, opt);
}

void RigSynth::render(int64_t index, const std::vector<uint8_t*>& uyvy, FieldTruth& truth) {
    const GeometryAt geo = [this](double t_us, SceneGeometry& out) {
        scene_geometry(scenario_.state_at(t_us), bodies_, markers_, out);
    };
    truth.field = index;
    truth.cameras.resize(cams_.size());
    for (size_t c = 0; c < cams_.size(); ++c) {
        const FieldTiming ft = cams_[c].field_timing(index);
        truth.cameras[c] = {index, ft.parity, ft.exposure_mid_us, cams_[c].exposure_us, ft.end_us};
    }
    truth.t_us = truth.cameras.empty() ? 0.0 : truth.cameras[0].exposure_mid_us;
    const SceneState st = scenario_.state_at(truth.t_us);
    truth.eye_center_rig_mm = st.eye_center_rig_mm;
    truth.q_eye_to_rig = st.q_eye_to_rig;
    truth.pedal = st.pedal;
    truth.board.reset();
    if (const BoardMotion* board = scenario_.board()) truth.board = board_truth(*board, cams_, index, truth.t_us);
    truth.instruments.clear();
    for (const InstrumentPose& p : st.instruments) {
        InstrumentTruth it;
        it.kind = p.kind;
        it.trocar = p.trocar;
        it.tip_eye_mm = p.tip_eye_mm;
        it.axis_eye = p.axis_eye;
        it.tip_rig_mm = st.eye_to_rig(p.tip_eye_mm);
        it.axis_rig = st.q_eye_to_rig * p.axis_eye;
        it.insertion_mm = p.insertion_mm;
        it.jaw_opening = p.jaw_opening;
        truth.instruments.push_back(it);
    }
    truth.markers.resize(markers_.size());
    for (size_t m = 0; m < markers_.size(); ++m) {
        MarkerTruth& mt = truth.markers[m];
        mt.body = markers_[m].body;
        mt.id = markers_[m].id;
        mt.colour_class = markers_[m].colour_class;
        mt.radius_mm = markers_[m].radius_mm;
        mt.center_rig_mm = marker_center_rig(markers_[m], st);
        mt.cams.resize(cams_.size());
    }
    for (size_t c = 0; c < cams_.size(); ++c) {
        renderers_[c].render_field(geo, index, c < uyvy.size() ? uyvy[c] : nullptr, cam_truth_);
        for (size_t m = 0; m < markers_.size(); ++m) truth.markers[m].cams[c] = cam_truth_[m];
    }
}

SynthSummary write_recording(const SynthRequest& req, const std::function<void(int64_t, int64_t)>& progress) {
    namespace fs = std::filesystem;
    if (!(req.seconds > 0) || !std::isfinite(req.seconds) || req.seconds > 3600)
        throw RigError(fmt::format("synth: seconds: must be in (0, 3600], got {}", req.seconds));
    VideoCodec codec = VideoCodec::kFfv1;
    VideoChroma chroma = VideoChroma::kCodec;
    const bool video = req.format != "uyvy";
    if (video && !parse_video_format(req.format, codec, chroma))
        throw RigError(fmt::format(
            "synth: format: must be uyvy, ffv1 (or video), dv, dv411, mpeg2, mpeg2-422, h264, ffv1-420 or ffv1-411, got '{}'",
            req.format));
    if (video && !encoder_available(codec))
        throw RigError(fmt::format("synth: format {}: this FFmpeg has no {} encoder", req.format,
                                   codec == VideoCodec::kH264 ? "libx264 (H.264)" : to_string(codec)));
    if (!video && !req.encoder_options.empty())
        throw RigError("synth: encoder options: only for a video format, not uyvy");
    if (!(req.render.noise_sigma >= 0) || !std::isfinite(req.render.noise_sigma))
        throw RigError(fmt::format("synth: noise: must be >= 0, got {}", req.render.noise_sigma));
    std::error_code ec;
    fs::create_directories(req.out_dir, ec);
    if (ec || !fs::is_directory(req.out_dir))
        throw RigError(fmt::format("{}: directory: cannot be created", req.out_dir));

    const Bodies bodies = load_bodies(req.bodies_path);
    int64_t fields = std::max<int64_t>(1, std::llround(req.seconds * kFieldRateHz));
    if (video && (fields & 1)) ++fields;
    const double duration_us = static_cast<double>(fields) * kFieldPeriodUs;
    RenderOptions ro = req.render;
    ro.seed = req.seed;
    RigSynth synth(req.cameras, bodies, Scenario::make(req.scenario, req.seed, duration_us, bodies, req.cameras), ro);
    const size_t nc = req.cameras.size();

    SynthSummary sum;
    sum.cameras = static_cast<int>(nc);
    sum.fields = fields;
    save_rig_yaml((fs::path(req.out_dir) / "rig.yaml").string(), req.cameras);
    sum.files.push_back("rig.yaml");

    // Outputs.
    std::vector<std::ofstream> raw(nc);
    std::vector<VideoWriter> vids;
    std::vector<std::string> names(nc);
    for (size_t c = 0; c < nc; ++c) {
        if (!video) {
            names[c] = fmt::format("cam{}.uyvy", c);
            raw[c].open(fs::path(req.out_dir) / names[c], std::ios::binary | std::ios::trunc);
            if (!raw[c]) throw RigError(fmt::format("{}/{}: file: cannot be created", req.out_dir, names[c]));
        } else {
            // As a PAL camera records: woven frames, the camera's first field first.
            names[c] = fmt::format("cam{}{}", c, extension(codec));
            vids.emplace_back((fs::path(req.out_dir) / names[c]).string(), codec,
                              req.cameras[c].first_field_parity == 0 ? FieldOrder::kTopFirst : FieldOrder::kBottomFirst,
                              chroma, req.encoder_options);
        }
        sum.files.push_back(names[c]);
    }
    TruthWriter tw((fs::path(req.out_dir) / "truth.jsonl").string());
    sum.files.push_back("truth.jsonl");

    std::vector<std::vector<uint8_t>> buf(nc, std::vector<uint8_t>(kFieldBytes));
    std::vector<std::vector<uint8_t>> prev(nc, std::vector<uint8_t>(kFieldBytes));
    std::vector<uint8_t*> ptrs(nc);
    for (size_t c = 0; c < nc; ++c) ptrs[c] = buf[c].data();
    FieldTruth truth;
    double render_s = 0;
    for (int64_t i = 0; i < fields; ++i) {
        const auto t0 = std::chrono::steady_clock::now();
        synth.render(i, ptrs, truth);
        render_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        for (const auto& m : truth.markers)
            for (const auto& mc : m.cams) sum.visible_marker_views += mc.visible;
        tw.write(truth);
        for (size_t c = 0; c < nc; ++c) {
            if (!video) {
                raw[c].write(reinterpret_cast<const char*>(buf[c].data()), kFieldBytes);
                if (!raw[c]) throw RigError(fmt::format("{}/{}: file: write failed", req.out_dir, names[c]));
            } else if (i & 1) {
                vids[c].write(prev[c].data(), buf[c].data());  // fields i-1 and i make frame (i-1)/2
            } else {
                prev[c].swap(buf[c]);
                ptrs[c] = buf[c].data();
            }
        }
        if (progress) progress(i + 1, fields);
    }
    tw.close();
    for (auto& r : raw)
        if (r.is_open()) r.close();
    for (auto& v : vids) v.close();
    sum.render_s = render_s;
    sum.fields_per_s = render_s > 0 ? static_cast<double>(fields * static_cast<int64_t>(nc)) / render_s : 0.0;

    Manifest man;
    man.format = video ? "video" : "uyvy";
    if (video) man.codec = req.format == "video" ? to_string(codec) : req.format;
    man.files = names;
    man.fields.assign(nc, fields);
    man.scenario = req.scenario;
    man.seed = req.seed;
    write_manifest(req.out_dir, man);
    sum.files.push_back("manifest.json");
    return sum;
}

}  // namespace eyesim::rig
