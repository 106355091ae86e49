// `eyesim synth`: render a synthetic three-camera recording with ground truth.
#include "eyesim/app/command.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/scenario.hpp"
#include "eyesim/rig/synth.hpp"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <memory>

namespace {

/// Largest accepted read-noise sigma, 8-bit levels: a seventh of the 219-level studio luma swing (16..235), far
/// beyond the 0–2 the benchmarks sweep; larger values only drive the pixels into the clamps.
constexpr double kMaxNoiseSigma = 32.0;

struct SynthOptions {
    std::string scenario = "static";
    double seconds = 1.0;
    uint64_t seed = 1;
    std::string out;
    std::string format = "uyvy";
    std::string encoder_options;
    double noise = 1.0;
    std::string bodies;
    std::string rig;
    bool synchronised = false;
    double exposure_us = 0;
    bool json = false;
};

eyesim::app::Registrar reg{"synth", "Render a synthetic three-camera PAL recording with ground truth", [](CLI::App& sub) {
    auto opt = std::make_shared<SynthOptions>();
    sub.add_option("--scenario", opt->scenario, "motion scenario or synthetic surgeon (docs/validation.md)")
        ->check(CLI::IsMember(eyesim::rig::scenario_names()));
    sub.add_option("--seconds", opt->seconds,
                   "recording length in seconds, 0.02 (one field) to 3600 (50 fields per second)")
        ->check(eyesim::app::finite_in(0.02, 3600.0));
    sub.add_option("--seed", opt->seed, "seed of the motion and the sensor noise (0 to 2^64 - 1)")
        ->check(eyesim::app::unsigned_integer());
    sub.add_option("--out", opt->out, "output recording directory (created)")->required();
    sub.add_option("--format", opt->format,
                   "uyvy (raw fields), or interlaced PAL video as cameras record it (720x576, 25 frames/s, the "
                   "rig's first field first): ffv1 (lossless 4:2:2 .mkv; also: video), dv (DV 4:2:0 .avi), dv411 "
                   "(DVCPRO25 4:1:1 .avi), mpeg2 (4:2:0 .mpg, quantiser 2, <= 15 Mbit/s), mpeg2-422 (D-10/IMX: 4:2:2 "
                   "intra .mpg, quantiser 1, <= 50 Mbit/s), h264 (libx264 CRF 8 4:2:0 .mp4); "
                   "ffv1-420, ffv1-411: lossless .mkv of a 4:2:0 / 4:1:1 camera's planes (subsampling alone)")
        ->check(CLI::IsMember({"uyvy", "video", "ffv1", "dv", "dv411", "mpeg2", "mpeg2-422", "h264", "ffv1-420", "ffv1-411"}));
    sub.add_option("--encoder-options", opt->encoder_options,
                   "video: FFmpeg encoder options over the format's, key=value pairs separated by ':' (e.g. crf=6)");
    sub.add_option("--noise", opt->noise, "read-noise sigma in 8-bit levels, 0 to 32 (0: no noise at all)")
        ->check(eyesim::app::finite_in(0.0, kMaxNoiseSigma));
    sub.add_option("--bodies", opt->bodies, "marker bodies JSON (default: scenes/bodies.json)");
    sub.add_option("--rig", opt->rig, "rig.yaml to use instead of the default three cameras");
    sub.add_flag("--synchronised", opt->synchronised, "give every camera the same field clock (default: unsynchronised)");
    sub.add_option("--exposure-us", opt->exposure_us, "shutter time per field in us (default: rig.yaml / 4000)");
    sub.add_flag("--json", opt->json, "print one JSON summary object on stdout");
    return [opt]() -> int {
        namespace rig = eyesim::rig;
        try {
            rig::SynthRequest req;
            req.out_dir = opt->out;
            req.scenario = opt->scenario;
            req.seconds = opt->seconds;
            req.seed = opt->seed;
            req.format = opt->format;
            req.encoder_options = opt->encoder_options;
            req.render.noise_sigma = opt->noise;
            if (!opt->bodies.empty()) req.bodies_path = opt->bodies;
            if (!opt->rig.empty()) req.cameras = rig::load_rig_yaml(opt->rig);
            for (auto& cam : req.cameras) {
                if (opt->synchronised) cam.field_time_offset_us = 0.0;
                if (opt->exposure_us != 0.0) {
                    if (!(opt->exposure_us > 0.0) || opt->exposure_us > rig::kFieldPeriodUs)
                        throw eyesim::app::Error(fmt::format("synth: --exposure-us: must be in (0, 20000], got {}",
                                                             opt->exposure_us),
                                                 2);
                    cam.exposure_us = opt->exposure_us;
                }
            }
            const bool progress = eyesim::app::show_progress(opt->json);
            const auto summary = rig::write_recording(req, [&](int64_t done, int64_t total) {
                if (progress && (done % 10 == 0 || done == total))
                    std::fprintf(stderr, "\rsynth: field %lld/%lld", static_cast<long long>(done),
                                 static_cast<long long>(total));
            });
            if (progress) std::fprintf(stderr, "\n");
            if (opt->json) {
                nlohmann::json j;
                j["out"] = opt->out;
                j["scenario"] = opt->scenario;
                j["seed"] = opt->seed;
                j["format"] = opt->format;
                j["fields"] = summary.fields;
                j["cameras"] = summary.cameras;
                j["fields_per_s"] = summary.fields_per_s;
                j["render_us"] = summary.render_s * 1e6;
                j["visible_marker_views"] = summary.visible_marker_views;
                j["files"] = summary.files;
                j["errors"] = 0;
                std::printf("%s\n", j.dump().c_str());
            } else {
                std::printf("%s: %lld fields x %d cameras, %s, %.0f fields/s\n", opt->out.c_str(),
                            static_cast<long long>(summary.fields), summary.cameras, opt->scenario.c_str(),
                            summary.fields_per_s);
            }
            return 0;
        } catch (const rig::RigError& e) {
            throw eyesim::app::Error(e.what());
        }
    };
}};

}  // namespace
