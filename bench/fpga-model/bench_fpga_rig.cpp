// Centroid accuracy of the FPGA model on a rig recording (rendered truth), per marker size, beside a binary
// centroid of the same model and the naive OpenCV baseline (opencv_baseline.hpp; the fair peer is in
// bench_fpga_model); with fields/s of each on the same fields. Then the
// refinement stage (tracking/refine.hpp) alone: its run time against error by sub-samples per pixel, and its
// effect and refusals by marker size and body (instrument markers, eye markers off and beside the eye's limb).
//
// Usage: bench_fpga_rig RECORDING_DIR [max_fields]
//   (make one with: eyesim synth --scenario surgery --seconds 2 --out DIR)
#include "luma_estimate.hpp"
#include "opencv_baseline.hpp"

#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/match.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/truth.hpp"
#include "eyesim/tracking/refine.hpp"
#include "thread_cpu.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

using eyesim::fpga::bench::Detection;
using eyesim::fpga::bench::OpenCvPipeline;
namespace fpga = eyesim::fpga;
namespace rig = eyesim::rig;
namespace tracking = eyesim::tracking;

namespace {

struct Acc {
    double se = 0;
    int n = 0, missed = 0;
    double rms() const { return n ? std::sqrt(se / n) : 0.0; }
};

// Size bin of a marker: its projected diameter in frame px.
int size_bin(double radius_px) {
    const double d = 2 * radius_px;
    return d < 6 ? 4 : d < 8 ? 6 : d < 10 ? 8 : d < 12 ? 10 : 12;
}

// Scores detections against the visible, unoccluded markers of camera `cam` in `truth` (class + nearest ≤ 3 px).
void score(const std::vector<Detection>& det, const rig::FieldTruth& truth, int cam, std::map<int, Acc>& bins) {
    std::vector<rig::DetectedMarker> found;
    found.reserve(det.size());
    for (const Detection& d : det) found.push_back({d.cls, Eigen::Vector2d(d.x, d.y)});
    std::vector<bool> used;
    rig::match_markers(
        truth, cam, found, 3.0,
        [](const rig::MarkerTruth&, const rig::MarkerCameraTruth& v) {
            return v.visible && !(v.area_px < 2.0) && !(v.occluded_fraction > 0.0);
        },
        [&](const rig::MarkerMatch& m) {
            Acc& a = bins[size_bin(m.view->radius_px)];
            if (m.detection < 0) {
                ++a.missed;
                return;
            }
            a.se += m.distance_px * m.distance_px;
            ++a.n;
        },
        used);
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: bench_fpga_rig RECORDING_DIR [max_fields]\n");
        return 2;
    }
    try {
        rig::Recording rec = rig::Recording::open(argv[1]);
        if (rec.truth_path().empty()) {
            std::fprintf(stderr, "%s: truth.jsonl: missing\n", argv[1]);
            return 1;
        }
        const std::vector<rig::FieldTruth> truth = rig::read_truth(rec.truth_path());
        int64_t n = std::min<int64_t>(rec.common_field_count(), static_cast<int64_t>(truth.size()));
        if (argc > 2) n = std::min<int64_t>(n, std::atoll(argv[2]));
        cv::setNumThreads(1);

        std::vector<std::vector<uint8_t>> fields;  // all cameras' fields in memory, read once
        std::vector<std::pair<int, int64_t>> ids;
        for (int64_t i = 0; i < n; ++i)
            for (int c = 0; c < rec.camera_count(); ++c) {
                fields.emplace_back(static_cast<size_t>(rig::kFieldBytes));
                rec.read_field(c, i, fields.back().data());
                ids.emplace_back(c, i);
            }

        fpga::RegisterMap reset, map11, binary;
        map11.write(fpga::reg::kBgTrack, 0);  // register map 1.1's reset: no background tracking
        map11.write(fpga::reg::kWeightBg, 0x05030303u);
        binary.write(fpga::reg::kWeightMode, 0);
        struct Method {
            std::string name;
            std::function<std::vector<Detection>(const uint8_t*)> run;
            std::map<int, Acc> bins;
            double fields_per_s = 0;
        };
        fpga::Pipeline pm(reset), p11(map11), pb(binary);
        std::vector<fpga::Blob> blobs;
        blobs.reserve(256);
        auto model = [&](fpga::Pipeline& p) {
            return [&](const uint8_t* f) {
                blobs.clear();
                p.set_sink([](void* c, const fpga::Blob& b) { static_cast<std::vector<fpga::Blob>*>(c)->push_back(b); },
                           &blobs);
                p.process_field(f, rig::kFieldHeight, 0, 0);
                std::vector<Detection> det;
                for (const fpga::Blob& b : blobs) det.push_back({b.class_id, b.cx_px(), b.cy_px()});
                return det;
            };
        };
        // The offline luma estimator on the reset model's blobs (luma_estimate.hpp), alone and mixed.
        auto luma = [&](bool mixed) {
            return [&, mixed](const uint8_t* f) {
                blobs.clear();
                pm.set_sink([](void* c, const fpga::Blob& b) { static_cast<std::vector<fpga::Blob>*>(c)->push_back(b); },
                            &blobs);
                pm.process_field(f, rig::kFieldHeight, 0, 0);
                std::vector<Detection> det;
                for (const fpga::Blob& b : blobs) {
                    fpga::bench::LumaEstimate l;
                    if (!fpga::bench::luma_centroid(f, rig::kFieldHeight, b, l)) {
                        det.push_back({b.class_id, b.cx_px(), b.cy_px()});
                        continue;
                    }
                    double x = l.x_px, y = l.y_px;
                    if (mixed) fpga::bench::mix_centroids(b, l, x, y);
                    det.push_back({b.class_id, x, y});
                }
                return det;
            };
        };
        // The refinement stage (sphere fit on each blob's patch), falling back to the pipeline's centroid.
        tracking::SphereFitConfig fit_cfg;
        for (int c = 1; c <= 4; ++c) {
            const auto rgb = rig::marker_class_rgb(c);
            fit_cfg.colour[static_cast<size_t>(c)] = tracking::MarkerColour::from_rgb(rgb[0], rgb[1], rgb[2]);
        }
        auto fit_work = std::make_unique<tracking::SphereFitWorkspace>();
        int fit_ok = 0, fit_all = 0;
        auto fitted = [&](const uint8_t* f) {
            blobs.clear();
            pm.set_sink([](void* c, const fpga::Blob& b) { static_cast<std::vector<fpga::Blob>*>(c)->push_back(b); }, &blobs);
            pm.process_field(f, rig::kFieldHeight, 0, 0);
            std::vector<Detection> det;
            for (const fpga::Blob& b : blobs) {
                const tracking::SphereFitResult r = tracking::fit_sphere(f, rig::kFieldHeight, tracking::blob_box(b), fit_cfg, *fit_work);
                ++fit_all;
                fit_ok += r.ok;
                det.push_back({b.class_id, r.ok ? r.cx_px : b.cx_px(), r.ok ? r.cy_px : b.cy_px()});
            }
            return det;
        };
        OpenCvPipeline cvw, cvb;
        cvb.weighted = false;
        std::vector<Method> methods;
        methods.push_back({"model (reset registers)", model(pm), {}, 0});
        methods.push_back({"model + sphere fit", fitted, {}, 0});
        methods.push_back({"model, map 1.1 (no BG_TRACK)", model(p11), {}, 0});
        methods.push_back({"model, binary centroid", model(pb), {}, 0});
        methods.push_back({"luma, local bg (offline)", luma(false), {}, 0});
        methods.push_back({"model + luma (offline)", luma(true), {}, 0});
        methods.push_back({"naive OpenCV weighted moments", [&](const uint8_t* f) { return cvw.run(f, rig::kFieldHeight); }, {}, 0});
        methods.push_back({"naive OpenCV binary centroid", [&](const uint8_t* f) { return cvb.run(f, rig::kFieldHeight); }, {}, 0});
        for (Method& m : methods) {
            const double t0 = eyesim::bench::thread_cpu_s();
            for (size_t k = 0; k < fields.size(); ++k)
                score(m.run(fields[k].data()), truth[static_cast<size_t>(ids[k].second)], ids[k].first, m.bins);
            m.fields_per_s = static_cast<double>(fields.size()) / (eyesim::bench::thread_cpu_s() - t0);
        }

        std::printf("recording %s: %lld fields x %d cameras; unoccluded visible markers; fields/s per thread-CPU "
                    "second (including scoring)\n\n",
                    argv[1], static_cast<long long>(n), rec.camera_count());
        std::printf("| diameter px | markers |");
        for (const Method& m : methods) std::printf(" %s |", m.name.c_str());
        std::printf("\n|---|---:|");
        for (size_t i = 0; i < methods.size(); ++i) std::printf("---:|");
        std::printf("\n");
        for (const auto& [bin, acc] : methods[0].bins) {
            std::printf("| %d–%d | %d |", bin, bin == 12 ? 99 : bin + 2, acc.n + acc.missed);
            for (Method& m : methods) std::printf(" %.4f (%d missed) |", m.bins[bin].rms(), m.bins[bin].missed);
            std::printf("\n");
        }
        std::printf("sphere fit: %d of %d blobs refined, the rest keep the pipeline's centroid\n\n", fit_ok, fit_all);
        std::printf("| fields/s | |");
        for (const Method& m : methods) std::printf(" %.0f |", m.fields_per_s);
        std::printf("\n");

        // Where the refinement stage helps and why it refuses: unoccluded markers by size and body.
        struct Split {
            int n = 0, refined = 0;
            int refusals[tracking::kFitRefusalCount] = {};
            double se_model_refined = 0, se_fit_refined = 0, se_model_refused = 0;
        };
        std::map<std::pair<int, int>, Split> split;  // (size bin, 0 instrument / 1 eye / 2 eye on its outline)
        for (size_t k = 0; k < fields.size(); ++k) {
            const uint8_t* f = fields[k].data();
            blobs.clear();
            pm.set_sink([](void* c, const fpga::Blob& b) { static_cast<std::vector<fpga::Blob>*>(c)->push_back(b); },
                        &blobs);
            pm.process_field(f, rig::kFieldHeight, 0, 0);
            std::vector<rig::DetectedMarker> found;
            std::vector<tracking::SphereFitResult> fits;
            for (const fpga::Blob& b : blobs) {
                found.push_back({b.class_id, Eigen::Vector2d(b.cx_px(), b.cy_px())});
                fits.push_back(tracking::fit_sphere(f, rig::kFieldHeight, tracking::blob_box(b), fit_cfg, *fit_work));
            }
            std::vector<bool> used;
            rig::match_markers(
                truth[static_cast<size_t>(ids[k].second)], ids[k].first, found, 3.0,
                [](const rig::MarkerTruth&, const rig::MarkerCameraTruth& v) {
                    return v.visible && !(v.area_px < 2.0) && !(v.occluded_fraction > 0.0);
                },
                [&](const rig::MarkerMatch& m) {
                    if (m.detection < 0) return;
                    const fpga::Blob& b = blobs[static_cast<size_t>(m.detection)];
                    const tracking::SphereFitResult& r = fits[static_cast<size_t>(m.detection)];
                    Split& sp = split[{size_bin(m.view->radius_px), m.marker->body != "eye" ? 0 : r.outline ? 2 : 1}];
                    const Eigen::Vector2d t = m.view->centroid_px, pipe(b.cx_px(), b.cy_px());
                    ++sp.n;
                    ++sp.refusals[static_cast<int>(r.refusal)];
                    if (r.ok) {
                        ++sp.refined;
                        sp.se_model_refined += (pipe - t).squaredNorm();
                        sp.se_fit_refined += (Eigen::Vector2d(r.cx_px, r.cy_px) - t).squaredNorm();
                    } else {
                        sp.se_model_refused += (pipe - t).squaredNorm();
                    }
                },
                used);
        }
        // The refinement stage alone, on every blob of every field.
        std::vector<std::vector<fpga::Blob>> field_blobs(fields.size());
        size_t n_blobs = 0;
        for (size_t k = 0; k < fields.size(); ++k) {
            pm.set_sink([](void* c, const fpga::Blob& b) { static_cast<std::vector<fpga::Blob>*>(c)->push_back(b); },
                        &field_blobs[k]);
            pm.process_field(fields[k].data(), rig::kFieldHeight, 0, 0);
            n_blobs += field_blobs[k].size();
        }
        // Run time against error of the stage: the analytic pixel integrals, and sub-samples per pixel side.
        std::printf("\nRefinement stage alone (every blob of every field, thread CPU time, best of 3 repeats; %zu blobs, "
                    "%.1f per field) against centroid RMS px of the unoccluded markers (pipeline where it refuses)\n\n",
                    n_blobs, static_cast<double>(n_blobs) / static_cast<double>(fields.size()));
        std::printf("| sub-samples | us per blob | fields/s per core | refined |");
        for (const auto& [bin, acc] : methods[0].bins) std::printf(" %d–%d px |", bin, bin == 12 ? 99 : bin + 2);
        std::printf("\n|---:|---:|---:|---:|");
        for (size_t i = 0; i < methods[0].bins.size(); ++i) std::printf("---:|");
        std::printf("\n");
        for (int ss : {0, 3, 4, 6}) {  // 0: the analytic pixel integrals (the default)
            tracking::SphereFitConfig cfg = fit_cfg;
            if (ss > 0) {
                cfg.model = tracking::SphereFitModel::kSupersampled;
                cfg.supersample = ss;
            }
            double best_s = 1e30;
            for (int rep = 0; rep < 3; ++rep) {
                const double t0 = eyesim::bench::thread_cpu_s();
                for (size_t k = 0; k < fields.size(); ++k)
                    for (const fpga::Blob& b : field_blobs[k]) tracking::fit_sphere(fields[k].data(), rig::kFieldHeight, tracking::blob_box(b), cfg, *fit_work);
                best_s = std::min(best_s, eyesim::bench::thread_cpu_s() - t0);
            }
            std::map<int, Acc> bins;
            int ok = 0;
            for (size_t k = 0; k < fields.size(); ++k) {
                std::vector<Detection> det;
                for (const fpga::Blob& b : field_blobs[k]) {
                    const tracking::SphereFitResult r = tracking::fit_sphere(fields[k].data(), rig::kFieldHeight, tracking::blob_box(b), cfg, *fit_work);
                    ok += r.ok;
                    det.push_back({b.class_id, r.ok ? r.cx_px : b.cx_px(), r.ok ? r.cy_px : b.cy_px()});
                }
                score(det, truth[static_cast<size_t>(ids[k].second)], ids[k].first, bins);
            }
            std::printf("| %s | %.1f | %.0f | %d |", ss == 0 ? "analytic (default)" : std::to_string(ss).c_str(),
                        1e6 * best_s / static_cast<double>(n_blobs), static_cast<double>(fields.size()) / best_s, ok);
            for (const auto& [bin, acc] : methods[0].bins) std::printf(" %.4f |", bins[bin].rms());
            std::printf("\n");
        }

        std::printf("\nRefinement by marker size and body (unoccluded, matched): RMS px of the refined markers before "
                    "and after the fit, of the refused ones, and the refusals by reason\n\n");
        std::printf("| diameter px | body | markers | refined | refined: model | refined: fit | refused: model | "
                    "chi2 | implausible | outliers | shift | storage |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
        auto rms = [](double se, int cnt) { return cnt ? std::sqrt(se / cnt) : 0.0; };
        for (const auto& [key, sp] : split)
            std::printf("| %d–%d | %s | %d | %d | %.4f | %.4f | %.4f | %d | %d | %d | %d | %d |\n", key.first,
                        key.first == 12 ? 99 : key.first + 2, key.second == 0 ? "instrument" : key.second == 1 ? "eye" : "eye, on the outline", sp.n, sp.refined,
                        rms(sp.se_model_refined, sp.refined), rms(sp.se_fit_refined, sp.refined),
                        rms(sp.se_model_refused, sp.n - sp.refined),
                        sp.refusals[static_cast<int>(tracking::FitRefusal::kChi2)],
                        sp.refusals[static_cast<int>(tracking::FitRefusal::kImplausible)],
                        sp.refusals[static_cast<int>(tracking::FitRefusal::kOutliers)],
                        sp.refusals[static_cast<int>(tracking::FitRefusal::kShift)],
                        sp.refusals[static_cast<int>(tracking::FitRefusal::kStorage)]);
    } catch (const rig::RigError& e) {
        std::fprintf(stderr, "%s\n", e.what());
        return 1;
    }
    return 0;
}
