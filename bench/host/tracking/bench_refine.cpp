// Blob refinement (tracking/refine.hpp): run time per blob against centroid error, beside the pipeline's own
// centroid, on fields with known truth:
//  - rig: shaded spheres from the rig renderer (perspective, lens distortion, shading, motion blur, shot noise,
//    the eye's limb), one recording per seed, truth = the rendered intensity centroid (of the visible part);
//    unoccluded markers, and apart the markers their shaft or the eye partly hides;
//  - discs: flat discs from the pipeline tests' generator (field_gen.hpp), 24 per field with random sub-pixel
//    centres and diameters, truth = the coverage centroid; the fit with its flat-disc model.
// Each fit configuration runs on the same blobs; time is thread CPU per blob (every blob of every field, refused
// ones included), error is the RMS (and the mean, the bias) over matched markers of the fit's centroid where it
// accepts and the pipeline's where it refuses. The occlusion-aware fit takes its hints (tracking::MarkerHintSource)
// from the rig's eye and instrument poses at each field's reference time (cam0's exposure: the other cameras'
// are up to a field off, as old as the live chain's poses).
//
// Usage: bench_refine [--seeds N=6] [--first-seed K=1] [--seconds S=0.4] [--scenario sweep] [--disc-fields F=20]
//                     [--data all|rig|discs] [--fit-repeats R=1] [--first-step-px P=0.05] [--no-reference] [--json]
// --fit-repeats R fits each blob R times in a row and takes the mean time of one (steadier per-blob times on a
// loaded machine; the patch is then in the cache, as it is in the live path, which fits a blob as it arrives).
// --first-step-px P: the faster setting's threshold (SphereFitConfig::first_step_unverified_px), a row of its own.
// Seeds K .. K + N − 1 (a range no parameter was tuned on: --first-seed 21).
#include "field_gen.hpp"

#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/match.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/rig/truth.hpp"
#include "eyesim/tracking/marker_prediction.hpp"
#include "eyesim/tracking/refine.hpp"
#include "eyesim/tracking/rig_adapter.hpp"
#include "thread_cpu.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <ctime>
#include <filesystem>
#include <map>
#include <memory>
#include <random>
#include <span>
#include <string>
#include <vector>

#include <unistd.h>

namespace fpga = eyesim::fpga;
namespace rig = eyesim::rig;
namespace tracking = eyesim::tracking;

namespace {

// Size bins by diameter in frame px: 4–6, 6–10, 10–16 (others are not reported).
int size_bin(double diameter_px) {
    if (diameter_px >= 4 && diameter_px < 6) return 0;
    if (diameter_px >= 6 && diameter_px < 10) return 1;
    if (diameter_px >= 10 && diameter_px < 16) return 2;
    return -1;
}
const char* kBinName[3] = {"4-6", "6-10", "10-16"};

struct Method {
    std::string name;
    bool fit = true;  // false: the pipeline's centroid
    tracking::SphereFitConfig cfg;
    bool hints = false;  // the occlusion-aware fit (MarkerHintSource)
};

// One (data, noise, method, size) cell.
struct Cell {
    double se = 0;
    double sum_dx = 0, sum_dy = 0;  // Σ error in x and y (bias = mean)
    int n = 0, refined = 0;
    double iterations = 0;
    std::vector<double> us;  // fit time of each matched marker's blob
};

// Per blob of one field: the method's centroid, whether it was refined, thread-CPU µs.
struct Out {
    double x = 0, y = 0, us = 0;
    bool ok = false;
    int iterations = 0;
};

std::vector<Out> run_method(const Method& m, const uint8_t* field, int height, const std::vector<fpga::Blob>& blobs,
                            tracking::SphereFitWorkspace& work, std::vector<double>& all_us,
                            int fit_repeats, const tracking::MarkerHintSource* hints = nullptr, int camera = -1) {
    std::vector<Out> out;
    out.reserve(blobs.size());
    for (const fpga::Blob& b : blobs) {
        Out o{b.cx_px(), b.cy_px(), 0, false};
        if (m.fit) {
            const tracking::BlobBox box = tracking::blob_box(b);
            const double t0 = eyesim::bench::thread_cpu_s();
            // The hint's prediction is part of the fit's cost.
            bool hinted = false;
            tracking::SphereFitResult r;
            for (int k = 0; k < fit_repeats; ++k)
                r = tracking::MarkerHintSource::fit(m.hints ? hints : nullptr, field, height, box, camera, m.cfg, work, hinted);
            o.us = 1e6 * (eyesim::bench::thread_cpu_s() - t0) / fit_repeats;
            all_us.push_back(o.us);
            o.iterations = r.iterations;
            if (r.ok) {
                o.x = r.cx_px;
                o.y = r.cy_px;
                o.ok = true;
            }
        }
        out.push_back(o);
    }
    return out;
}

double pct(std::vector<double> v, double p) {
    if (v.empty()) return std::nan("");
    std::sort(v.begin(), v.end());
    const size_t i = std::min(v.size() - 1, static_cast<size_t>(p * static_cast<double>(v.size())));
    return v[i];
}

nlohmann::json num(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

std::vector<fpga::Blob> blobs_of(fpga::Pipeline& p, const uint8_t* field, int height) {
    std::vector<fpga::Blob> blobs;
    p.set_sink([](void* c, const fpga::Blob& b) { static_cast<std::vector<fpga::Blob>*>(c)->push_back(b); }, &blobs);
    p.process_field(field, height, 0, 0);
    return blobs;
}

}  // namespace

int main(int argc, char** argv) {
    int seeds = 6, disc_fields = 20, first_seed = 1, fit_repeats = 1;
    double seconds = 0.4, first_step_px = 0.05;
    std::string scenario = "sweep", data_set = "all";
    bool json = false, reference = true;
    for (int i = 1; i < argc; ++i) {
        const bool has = i + 1 < argc;
        if (!std::strcmp(argv[i], "--json")) json = true;
        else if (!std::strcmp(argv[i], "--no-reference")) reference = false;
        else if (!std::strcmp(argv[i], "--seeds") && has) seeds = std::max(1, std::atoi(argv[++i]));
        else if (!std::strcmp(argv[i], "--first-seed") && has) first_seed = std::max(1, std::atoi(argv[++i]));
        else if (!std::strcmp(argv[i], "--seconds") && has) seconds = std::atof(argv[++i]);
        else if (!std::strcmp(argv[i], "--scenario") && has) scenario = argv[++i];
        else if (!std::strcmp(argv[i], "--disc-fields") && has) disc_fields = std::max(1, std::atoi(argv[++i]));
        else if (!std::strcmp(argv[i], "--fit-repeats") && has) fit_repeats = std::max(1, std::atoi(argv[++i]));
        else if (!std::strcmp(argv[i], "--first-step-px") && has) first_step_px = std::atof(argv[++i]);
        else if (!std::strcmp(argv[i], "--data") && has) {
            data_set = argv[++i];
            if (data_set != "all" && data_set != "rig" && data_set != "discs") {
                std::fprintf(stderr, "eyesim: error: bench_refine: --data must be all, rig or discs\n");
                return 2;
            }
        }
        else {
            std::fprintf(stderr, "eyesim: error: bench_refine: unknown or incomplete option %s\n", argv[i]);
            return 2;
        }
    }
    if (!(first_step_px > 0) || first_step_px > 1) {
        std::fprintf(stderr, "eyesim: error: bench_refine: --first-step-px must be in (0, 1]\n");
        return 2;
    }
    if (!(seconds > 0) || seconds > 60) {
        std::fprintf(stderr, "eyesim: error: bench_refine: --seconds must be in (0, 60]\n");
        return 2;
    }

    // The configurations compared: the rig's marker colours; the disc data's own colours and flat-disc model.
    tracking::SphereFitConfig rig_cfg;
    for (int c = 1; c <= 4; ++c) {
        const auto rgb = rig::marker_class_rgb(c);
        rig_cfg.colour[static_cast<size_t>(c)] = tracking::MarkerColour::from_rgb(rgb[0], rgb[1], rgb[2]);
    }
    tracking::SphereFitConfig disc_cfg;
    for (int c = 1; c <= 4; ++c) {
        const auto& rgb = fpga::test::kColours[static_cast<size_t>(c)];
        disc_cfg.colour[static_cast<size_t>(c)] = tracking::MarkerColour::from_rgb(rgb[0], rgb[1], rgb[2]);
    }
    disc_cfg.shade_ambient = 1.0;
    disc_cfg.shade_diffuse = 0.0;
    disc_cfg.shot_gain = 0.0;
    disc_cfg.aperture_lines_px = 2.0;
    auto methods_for = [reference, first_step_px](const tracking::SphereFitConfig& base, double noise) {
        std::vector<Method> ms;
        ms.push_back({"pipeline", false, base});
        tracking::SphereFitConfig ref = base;
        ref.noise_dn = noise;
        ref.model = tracking::SphereFitModel::kSupersampled;
        if (reference) ms.push_back({"sphere fit, 4x4 supersampled (reference)", true, ref});
        tracking::SphereFitConfig fast = base;
        fast.noise_dn = noise;
        ms.push_back({"sphere fit, analytic coverage (default)", true, fast});
        // The faster setting: a small first step taken unconfirmed (SphereFitConfig::first_step_unverified_px).
        tracking::SphereFitConfig quick = fast;
        quick.first_step_unverified_px = first_step_px;
        ms.push_back({"sphere fit, first step unverified (--first-step-px)", true, quick});
        return ms;
    };
    auto rig_methods = [&](double noise) {
        std::vector<Method> ms = methods_for(rig_cfg, noise);
        tracking::SphereFitConfig fast = rig_cfg;
        fast.noise_dn = noise;
        ms.push_back({"sphere fit, occlusion hints (default with poses)", true, fast, true});
        return ms;
    };

    auto work = std::make_unique<tracking::SphereFitWorkspace>();
    fpga::Pipeline pipe{fpga::RegisterMap{}};
    // results[data][noise][method] → cells per size bin, and every blob's time.
    struct Row {
        std::string data, method;
        double noise = 0;
        Cell bins[3];
        std::vector<double> all_us;
    };
    std::deque<Row> rows;  // references stay valid as rows are added
    auto row_for = [&](const std::string& data, double noise, const std::string& method) -> Row& {
        for (Row& r : rows)
            if (r.data == data && r.noise == noise && r.method == method) return r;
        rows.push_back({data, method, noise, {}, {}});
        return rows.back();
    };
    std::vector<uint64_t> seed_list;
    for (int s = first_seed; s < first_seed + seeds; ++s) seed_list.push_back(static_cast<uint64_t>(s));

    try {
        const rig::Bodies bodies = rig::load_bodies(rig::default_bodies_path());
        for (double noise : {1.0, 2.0}) {
            if (data_set == "discs") break;
            const std::vector<Method> ms = rig_methods(noise);
            for (uint64_t seed : seed_list) {
                // The process id in the name: two runs at once (another scenario, the same seed) must not share it.
                const std::string dir = (std::filesystem::temp_directory_path() /
                                         ("eyesim_bench_refine_" + std::to_string(::getpid()) + "_" + std::to_string(seed)))
                                            .string();
                std::filesystem::remove_all(dir);
                rig::SynthRequest req;
                req.out_dir = dir;
                req.scenario = scenario;
                req.seconds = seconds;
                req.seed = seed;
                req.render.noise_sigma = noise;
                rig::write_recording(req);
                rig::Recording rec = rig::Recording::open(dir);
                const std::vector<rig::FieldTruth> truth = rig::read_truth(rec.truth_path());
                const int64_t n = std::min<int64_t>(rec.common_field_count(), static_cast<int64_t>(truth.size()));
                std::vector<uint8_t> field(static_cast<size_t>(rig::kFieldBytes));
                std::vector<tracking::SceneInstrument> scene;
                for (const rig::InstrumentTruth& it : truth.front().instruments) scene.push_back({it.kind, it.trocar});
                std::vector<tracking::CameraGeometry> cams;
                for (const rig::CameraModel& cm : rec.cameras()) cams.push_back(tracking::camera_geometry(cm));
                tracking::MarkerHintSource hints(cams, tracking::body_set(bodies, scene));
                for (int64_t i = 0; i < n; ++i) {
                    const rig::FieldTruth& tr = truth[static_cast<size_t>(i)];
                    std::array<tracking::InstrumentPose, tracking::kMaxInstruments> poses{};
                    tracking::EyePose eye;
                    const int ni = tracking::truth_poses(tr, eye, poses);
                    hints.update(eye, std::span<const tracking::InstrumentPose>(poses.data(), static_cast<size_t>(ni)));
                    for (int cam = 0; cam < rec.camera_count(); ++cam) {
                        rec.read_field(cam, i, field.data());
                        const std::vector<fpga::Blob> blobs = blobs_of(pipe, field.data(), rig::kFieldHeight);
                        std::vector<rig::DetectedMarker> det;
                        for (const fpga::Blob& b : blobs) det.push_back({b.class_id, Eigen::Vector2d(b.cx_px(), b.cy_px())});
                        // Match once on the pipeline's centroids: every method is scored on the same markers.
                        std::vector<std::pair<int, const rig::MarkerCameraTruth*>> matched;
                        std::vector<bool> used;
                        rig::match_markers(
                            tr, cam, det, 3.0,
                            [](const rig::MarkerTruth&, const rig::MarkerCameraTruth& v) {
                                return v.visible && !(v.area_px < 2.0);
                            },
                            [&](const rig::MarkerMatch& m) {
                                if (m.detection >= 0) matched.emplace_back(m.detection, m.view);
                            },
                            used);
                        for (const Method& m : ms) {
                            Row& row = row_for("rig " + scenario, noise, m.name);
                            Row& hidden = row_for("rig " + scenario + ", partly hidden", noise, m.name);
                            const std::vector<Out> out =
                                run_method(m, field.data(), rig::kFieldHeight, blobs, *work, row.all_us, fit_repeats, &hints, cam);
                            for (const auto& [d, v] : matched) {
                                const int bin = size_bin(2.0 * v->radius_px);
                                if (bin < 0) continue;
                                const Out& o = out[static_cast<size_t>(d)];
                                Cell& c = (v->occluded_fraction > 0.0 ? hidden : row).bins[bin];
                                c.se += std::pow(o.x - v->centroid_px.x(), 2) + std::pow(o.y - v->centroid_px.y(), 2);
                                c.sum_dx += o.x - v->centroid_px.x();
                                c.sum_dy += o.y - v->centroid_px.y();
                                ++c.n;
                                c.refined += o.ok;
                                c.iterations += o.iterations;
                                if (m.fit) c.us.push_back(o.us);
                            }
                        }
                    }
                }
                std::filesystem::remove_all(dir);
            }
        }
    } catch (const rig::RigError& e) {
        std::fprintf(stderr, "eyesim: error: bench_refine: %s\n", e.what());
        return 1;
    }

    // Flat discs from the generator: 24 per field on a 6 × 4 grid, every class, diameter uniform in the bin.
    for (double noise : {1.0, 2.0}) {
        if (data_set == "rig") break;
        const std::vector<Method> ms = methods_for(disc_cfg, noise);
        for (int bin = 0; bin < 3; ++bin) {
            const double lo = bin == 0 ? 4.0 : bin == 1 ? 6.0 : 10.0, hi = bin == 0 ? 6.0 : bin == 1 ? 10.0 : 16.0;
            for (uint64_t seed : seed_list)
                for (int fi = 0; fi < disc_fields; ++fi) {
                    std::mt19937 rng(static_cast<uint32_t>(1000 * seed + 100 * bin + fi));
                    std::uniform_real_distribution<double> u01(0, 1), ud(lo, hi);
                    std::vector<fpga::test::Marker> markers;
                    for (int k = 0; k < 24; ++k) {
                        const double d = ud(rng);
                        markers.push_back({1 + k % 4, 60.0 + 110.0 * (k % 6) + u01(rng), 30.0 + 60.0 * (k / 6) + u01(rng),
                                           0.5 * d, 0.25 * d});
                    }
                    std::vector<std::array<double, 2>> truth;
                    const fpga::test::Field f = fpga::test::render_markers(
                        markers, noise, static_cast<uint32_t>(7919 * seed + 31 * bin + fi), 288, 8, {14, 14, 18}, &truth);
                    const std::vector<fpga::Blob> blobs = blobs_of(pipe, f.bytes.data(), f.height);
                    for (const Method& m : ms) {
                        Row& row = row_for("discs", noise, m.name);
                        const std::vector<Out> out = run_method(m, f.bytes.data(), f.height, blobs, *work, row.all_us, fit_repeats);
                        for (size_t i = 0; i < markers.size(); ++i) {
                            int best = -1;
                            double bd = 2.0;
                            for (size_t k = 0; k < blobs.size(); ++k) {
                                const double d = std::hypot(blobs[k].cx_px() - truth[i][0], blobs[k].cy_px() - truth[i][1]);
                                if (blobs[k].class_id == markers[i].cls && d < bd) {
                                    bd = d;
                                    best = static_cast<int>(k);
                                }
                            }
                            if (best < 0) continue;
                            const Out& o = out[static_cast<size_t>(best)];
                            Cell& c = row.bins[bin];
                            c.se += std::pow(o.x - truth[i][0], 2) + std::pow(o.y - truth[i][1], 2);
                            c.sum_dx += o.x - truth[i][0];
                            c.sum_dy += o.y - truth[i][1];
                            ++c.n;
                            c.refined += o.ok;
                            c.iterations += o.iterations;
                            if (m.fit) c.us.push_back(o.us);
                        }
                    }
                }
        }
    }

    nlohmann::json j;
    j["command"] = "bench_refine";
    j["seeds"] = seed_list;
    j["scenario"] = scenario;
    j["seconds"] = seconds;
    j["disc_fields_per_seed_and_size"] = disc_fields;
    j["data"] = data_set;
    j["fit_repeats"] = fit_repeats;
    j["first_step_px"] = first_step_px;
    j["rows"] = nlohmann::json::array();
    if (!json)
        std::printf("Blob refinement: thread CPU per blob against centroid RMS (matched markers, unoccluded and partly "
                    "hidden apart; the pipeline's centroid where a fit refuses). Seeds %d-%d; rig: %s, %.2f s per "
                    "seed.\n\n"
                    "| data | noise σ DN | method | size px | markers | refined | RMS px | bias x / y px | iterations | µs/blob p50 | µs/blob p99 |\n"
                    "|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|\n",
                    first_seed, first_seed + seeds - 1, scenario.c_str(), seconds);
    for (const Row& r : rows) {
        for (int b = 0; b < 3; ++b) {
            const Cell& c = r.bins[b];
            if (c.n == 0) continue;
            const double rms = std::sqrt(c.se / c.n), p50 = pct(c.us, 0.5), p99 = pct(c.us, 0.99);
            j["rows"].push_back({{"data", r.data},
                                 {"noise_dn", r.noise},
                                 {"method", r.method},
                                 {"size_px", kBinName[b]},
                                 {"markers", c.n},
                                 {"refined", c.refined},
                                 {"rms_px", num(rms)},
                                 {"bias_px", {{"x", num(c.sum_dx / c.n)}, {"y", num(c.sum_dy / c.n)}}},
                                 {"iterations_mean", c.us.empty() ? nlohmann::json(nullptr) : num(c.iterations / c.n)},
                                 {"us_per_blob", {{"p50", num(p50)}, {"p99", num(p99)}}}});
            if (!json) {
                auto us = [](double v) { return std::isfinite(v) ? std::to_string(v).substr(0, std::to_string(v).find('.') + 2) : std::string("–"); };
                const std::string it = c.us.empty() ? "–" : us(c.iterations / c.n);
                std::printf("| %s | %.0f | %s | %s | %d | %d | %.4f | %+.4f / %+.4f | %s | %s | %s |\n", r.data.c_str(),
                            r.noise, r.method.c_str(), kBinName[b], c.n, c.refined, rms, c.sum_dx / c.n, c.sum_dy / c.n,
                            it.c_str(), us(p50).c_str(), us(p99).c_str());
            }
        }
        if (!r.all_us.empty()) {
            j["all_blobs"].push_back({{"data", r.data},
                                      {"noise_dn", r.noise},
                                      {"method", r.method},
                                      {"blobs", r.all_us.size()},
                                      {"us_per_blob", {{"p50", num(pct(r.all_us, 0.5))}, {"p99", num(pct(r.all_us, 0.99))}}}});
            if (!json)
                std::printf("| %s | %.0f | %s | every blob | %zu | | | | | %.1f | %.1f |\n", r.data.c_str(), r.noise,
                            r.method.c_str(), r.all_us.size(), pct(r.all_us, 0.5), pct(r.all_us, 0.99));
        }
    }
    if (json) std::printf("%s\n", j.dump(2).c_str());
    return 0;
}
