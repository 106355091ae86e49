#include "eyesim/app/latency_bench.hpp"

#include "eyesim/app/command.hpp"
#include "eyesim/app/frame_loop.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/pal.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/sim/scenes/scene.hpp"

#include <Eigen/LU>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <random>

namespace eyesim::app {

namespace proto = eyesim::protocol;
namespace tr = eyesim::tracking;

double calibration_us() {
    std::vector<double> t;
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    Eigen::MatrixXd a(96, 96);
    Eigen::VectorXd b(96);
    std::vector<float> v(32768);
    double sink = 0;
    for (int r = 0; r < 31; ++r) {
        for (int i = 0; i < a.size(); ++i) a.data()[i] = u(rng);
        for (int i = 0; i < b.size(); ++i) b[i] = u(rng);
        for (auto& x : v) x = float(u(rng));
        const double t0 = host_now_us();
        const Eigen::VectorXd x = a.partialPivLu().solve(b);
        std::sort(v.begin(), v.end());
        t.push_back(host_now_us() - t0);
        sink += x[0] + v[100];
    }
    if (!std::isfinite(sink)) t.push_back(0.0);  // keeps the work observable
    // The minimum: interference from other processes only ever adds time.
    return *std::min_element(t.begin(), t.end());
}

namespace {

/// One scene: per-frame stage times of the median repeat.
nlohmann::json run_scene_once(const std::string& path, const LatencyBenchOptions& opt, std::vector<double>& compute_p50) {
    sim::scenes::Scene scene;
    try {
        scene = sim::scenes::load_scene(path);
    } catch (const sim::scenes::SceneError& e) {
        throw Error(e.what());
    }
    rig::Bodies bodies = rig::load_bodies(rig::default_bodies_path());
    const std::vector<rig::CameraModel> cams = rig::default_rig();
    const double dur_us = opt.seconds * 1e6;
    rig::Scenario scenario = [&] {
        try {
            return rig::Scenario::make(scene.scenario, 1, dur_us, bodies);
        } catch (const rig::RigError&) {
            return rig::Scenario::make("surgery", 1, dur_us, bodies);  // scene for a scenario this rig lacks
        }
    }();
    std::vector<tr::SceneInstrument> instruments;
    for (auto k : scenario.kinds())
        instruments.push_back({k, k == rig::InstrumentKind::kLightPipe ? 1 : 0});
    rig::RenderOptions ropt;
    rig::RigSynth synth(cams, bodies, scenario, ropt);

    // Marker images of every field (truth centroids + 0.03 px noise), made before timing starts.
    const int64_t fields = int64_t(std::lround(opt.seconds * 50));
    std::vector<std::vector<proto::FieldMarkers>> msgs(size_t(fields * int64_t(cams.size())));
    std::mt19937_64 rng(3);
    std::normal_distribution<double> noise(0.0, 0.03);
    rig::FieldTruth truth;
    const std::vector<uint8_t*> none(cams.size(), nullptr);
    for (int64_t i = 0; i < fields; ++i) {
        synth.render(i, none, truth);
        for (size_t c = 0; c < cams.size(); ++c) {
            const rig::FieldTiming ft = rig::field_timing(i, cams[c].field_time_offset_us, cams[c].exposure_us,
                                                          cams[c].first_field_parity);
            auto& list = msgs[size_t(i) * cams.size() + c];
            proto::FieldMarkers m;
            m.camera_id = uint8_t(c);
            m.field_parity = uint8_t(ft.parity);
            m.field_counter = uint32_t(i);
            m.field_end_us = uint64_t(std::llround(std::max(0.0, ft.end_us)));
            for (const auto& mk : truth.markers) {
                const auto& ct = mk.cams[c];
                if (!ct.visible || ct.area_px < 4.0) continue;
                if (m.marker_count == proto::kMaxMarkersPerMessage) {
                    m.flags |= proto::kFieldFlagMoreFollows;
                    list.push_back(m);
                    m.flags = 0;
                    m.marker_count = 0;
                    ++m.part_index;
                }
                proto::Marker& o = m.markers[m.marker_count++];
                o.colour_class = uint8_t(mk.colour_class);
                o.x_q16 = uint32_t(std::llround((ct.centroid_px.x() + noise(rng)) * 65536.0));
                o.y_q16 = uint32_t(std::llround((ct.centroid_px.y() + noise(rng)) * 65536.0));
                o.area_px = uint32_t(ct.area_px);
                o.intensity_sum = uint32_t(ct.area_px * 100);
                o.complete_us = m.field_end_us;
            }
            list.push_back(m);
        }
    }

    struct Run {
        nlohmann::json stages;
        double compute_p50 = 0;
    };
    std::vector<Run> runs;
    for (int r = 0; r < opt.repeats; ++r) {
        Simulator sim(scene);
        sim.inject_collision_delay_us(opt.inject_collision_us);
        HostRun run(tracker_config(cams, bodies, instruments), sim);
        proto::DecodedFrame df;
        for (int64_t i = 0; i < fields; ++i)
            for (size_t c = 0; c < cams.size(); ++c)
                for (const auto& m : msgs[size_t(i) * cams.size() + c]) {
                    df.message = m;
                    run.on_frame(df, double(m.field_end_us) + 100.0);
                }
        run.finish();
        Run out;
        const StageTimer& t = sim.timer();
        for (Stage s : {Stage::kTracking, Stage::kCollision, Stage::kTissue, Stage::kTransfer, Stage::kMisc}) {
            const StageSummary ss = t.summary(s);
            out.stages[to_string(s)] = {{"p50_us", ss.p50_us}, {"p99_us", ss.p99_us}};
        }
        const StageSummary c = t.summary_of_sum({Stage::kTracking, Stage::kCollision, Stage::kTissue});
        out.stages["host_compute"] = {{"p50_us", c.p50_us}, {"p99_us", c.p99_us}, {"max_us", c.max_us}};
        out.stages["frames"] = t.frames();
        out.compute_p50 = c.p50_us;
        runs.push_back(std::move(out));
    }
    // The fastest repeat: interference from other processes only ever adds time.
    std::sort(runs.begin(), runs.end(), [](const Run& a, const Run& b) { return a.compute_p50 < b.compute_p50; });
    compute_p50.push_back(runs.front().compute_p50);
    return runs.front().stages;
}

}  // namespace

nlohmann::json run_latency_bench(const LatencyBenchOptions& opt) {
    std::vector<std::string> scenes = opt.scenes;
    if (scenes.empty())
        for (const char* s : {"abstract-shadow", "membrane-peel", "vitrectomy", "retina-relocation"})
            scenes.push_back(std::string(EYESIM_SCENES_DIR) + "/" + s + ".json");
    nlohmann::json j;
    // Calibration before and after every scene; the least disturbed measurement stands for the machine.
    std::vector<double> cal{calibration_us()};
    nlohmann::json per_scene;
    for (const auto& path : scenes) {
        std::vector<double> c;
        nlohmann::json s = run_scene_once(path, opt, c);
        const std::string name = sim::scenes::load_scene(path).name;
        per_scene[name] = s;
        cal.push_back(calibration_us());
    }
    const double cal_min = *std::min_element(cal.begin(), cal.end());
    for (auto& [name, s] : per_scene.items()) s["ratio"] = s["host_compute"]["p50_us"].get<double>() / cal_min;
    j["calibration_us"] = cal_min;
    j["calibration_spread"] = *std::max_element(cal.begin(), cal.end()) / cal_min;
    j["scenes"] = per_scene;
    j["seconds"] = opt.seconds;
    j["repeats"] = opt.repeats;
    return j;
}

std::vector<std::string> latency_regressions(const nlohmann::json& current, const nlohmann::json& baseline,
                                             double tolerance) {
    std::vector<std::string> out;
    if (!baseline.contains("scenes") || !baseline["scenes"].is_object())
        throw Error("baseline: scenes: missing or not an object");
    for (const auto& [name, b] : baseline["scenes"].items()) {
        if (!current["scenes"].contains(name)) {
            out.push_back(fmt::format("{}: in the baseline but not measured", name));
            continue;
        }
        if (!b.contains("ratio") || !b["ratio"].is_number()) throw Error("baseline: scenes." + name + ".ratio: missing");
        const double was = b["ratio"].get<double>();
        const double now = current["scenes"][name]["ratio"].get<double>();
        if (!(was > 0)) throw Error("baseline: scenes." + name + ".ratio: must be positive");
        if (now > was * (1.0 + tolerance))
            out.push_back(fmt::format("{}: host compute {:.2f}× calibration, baseline {:.2f}× (+{:.0f} %, tolerance {:.0f} %)",
                                      name, now, was, (now / was - 1.0) * 100.0, tolerance * 100.0));
    }
    return out;
}

}  // namespace eyesim::app
