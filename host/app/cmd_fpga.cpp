// `eyesim fpga`: run the FPGA pipeline model over a recording; write protocol FieldMarkers packets and/or CSV.
#include "eyesim/app/command.hpp"
#include "eyesim/app/fpga_run.hpp"
#include "eyesim/app/refine.hpp"
#include "eyesim/frame/session.hpp"
#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/fpga/wire.hpp"
#include "eyesim/firmware/latency.hpp"
#include "eyesim/firmware/pc/pedal_track.hpp"
#include "eyesim/protocol/capture.hpp"
#include "eyesim/protocol/codec.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/match.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/truth.hpp"
#include "eyesim/tracking/marker_prediction.hpp"
#include "eyesim/tracking/refine.hpp"
#include "eyesim/tracking/rig_adapter.hpp"
#include "eyesim/tracking/tracker.hpp"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fpga = eyesim::fpga;
namespace proto = eyesim::protocol;
namespace rig = eyesim::rig;

struct FpgaOptions {
    std::string recording;
    std::string cameras;
    std::string out;
    std::string csv;
    int64_t max_fields = -1;
    std::vector<std::string> regs;
    bool json = false;
    bool refine = false;
    bool no_hints = false;  ///< --refine without occlusion hints
};

// Percentile of a sorted vector (nearest rank).
double percentile(const std::vector<double>& sorted, double p) {
    if (sorted.empty()) return 0.0;
    const size_t i = std::min(sorted.size() - 1, static_cast<size_t>(std::ceil(p * sorted.size())) - (p > 0 ? 1 : 0));
    return sorted[i];
}

nlohmann::json latency_json(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return {{"p50", percentile(v, 0.5)}, {"p99", percentile(v, 0.99)}, {"max", v.empty() ? 0.0 : v.back()}};
}

// Squared and signed centroid errors (blob − rendered centroid), the signed ones per field parity: a video whose
// chroma is sited wrongly shows a bias that alternates with the parity.
struct ErrorSums {
    double se = 0;
    int64_t n = 0;
    std::array<double, 2> sum_dx{}, sum_dy{};
    std::array<int64_t, 2> n_parity{};
    void add(const Eigen::Vector2d& d, int parity) {
        se += d.squaredNorm();
        ++n;
        sum_dx[parity & 1] += d.x();
        sum_dy[parity & 1] += d.y();
        ++n_parity[parity & 1];
    }
    void add(const ErrorSums& o) {
        se += o.se;
        n += o.n;
        for (int p = 0; p < 2; ++p) {
            sum_dx[p] += o.sum_dx[p];
            sum_dy[p] += o.sum_dy[p];
            n_parity[p] += o.n_parity[p];
        }
    }
};

struct CameraStats {
    int camera = 0;
    int64_t fields = 0;
    int64_t blobs = 0;
    int64_t overflows = 0;
    int64_t refined = 0;
    int64_t missed = 0, extra = 0;
    ErrorSums err;  // every matched marker
    // Split by the truth's visibility: clear markers, and partly hidden ones (an instrument's own shaft in front of
    // it, the eye's outline), whose visible part's centroid is the harder target.
    std::array<ErrorSums, 2> vis;
    std::vector<double> latency_us;        // blob: emission after its last pixel
    std::vector<double> field_latency_us;  // field: last blob after the last active line
};

// The truth marker a blob was matched to, for the CSV: which marker, the blob's error and how hidden it was.
struct BlobTruth {
    const rig::MarkerTruth* marker = nullptr;  // null: not matched (or no truth)
    Eigen::Vector2d error_px = Eigen::Vector2d::Zero();
    double occluded_fraction = 0.0;
};

// Matches blobs to the visible truth markers of one camera by class and nearest centroid (≤ 3 px); `per_blob`
// (one entry per blob) gets each matched blob's marker and error.
void score(const std::vector<fpga::Blob>& blobs, const rig::FieldTruth& truth, int cam, int parity, CameraStats& st,
           std::vector<BlobTruth>& per_blob) {
    per_blob.assign(blobs.size(), BlobTruth{});
    std::vector<rig::DetectedMarker> det;
    det.reserve(blobs.size());
    for (const fpga::Blob& b : blobs) det.push_back({b.class_id, Eigen::Vector2d(b.cx_px(), b.cy_px())});
    std::vector<bool> used;
    rig::match_markers(
        truth, cam, det, 3.0,
        [](const rig::MarkerTruth&, const rig::MarkerCameraTruth& v) { return v.visible && !(v.area_px < 2.0); },
        [&](const rig::MarkerMatch& m) {  // area ≥ 2: the reset MIN_AREA
            if (m.detection < 0) {
                ++st.missed;
                return;
            }
            const Eigen::Vector2d d = det[static_cast<size_t>(m.detection)].centroid_px - m.view->centroid_px;
            st.err.add(d, parity);
            st.vis[m.view->occluded_fraction > 0.0 ? 1 : 0].add(d, parity);
            per_blob[static_cast<size_t>(m.detection)] = {m.marker, d, m.view->occluded_fraction};
        },
        used);
    for (bool u : used) st.extra += !u;
}

// Mean signed centroid error, x and y, and y by field parity (top, bottom); null where nothing was matched.
nlohmann::json bias_json(const ErrorSums& e) {
    const auto mean = [](double sum, int64_t n) {
        return n ? nlohmann::json(sum / static_cast<double>(n)) : nlohmann::json();
    };
    const int64_t n = e.n_parity[0] + e.n_parity[1];
    return {{"x", mean(e.sum_dx[0] + e.sum_dx[1], n)}, {"y", mean(e.sum_dy[0] + e.sum_dy[1], n)},
            {"y_top", mean(e.sum_dy[0], e.n_parity[0])}, {"y_bottom", mean(e.sum_dy[1], e.n_parity[1])}};
}

double rms(const ErrorSums& e) { return e.n ? std::sqrt(e.se / static_cast<double>(e.n)) : 0.0; }

// Centroid RMS and bias over clear and over partly hidden markers:
// {"clear": {"rms_px", "matched", "bias_px"}, "partly_hidden": …}.
nlohmann::json visibility_json(const std::array<ErrorSums, 2>& vis) {
    nlohmann::json j;
    const char* names[2] = {"clear", "partly_hidden"};
    for (size_t h = 0; h < 2; ++h)
        j[names[h]] = {{"rms_px", vis[h].n ? nlohmann::json(rms(vis[h])) : nlohmann::json()},
                       {"matched", vis[h].n},
                       {"bias_px", bias_json(vis[h])}};
    return j;
}

int run(const FpgaOptions& opt) {
    rig::Recording rec = rig::Recording::open(opt.recording);
    const std::vector<int> cams = eyesim::app::parse_cameras(opt.cameras, rec.camera_count());
    // Warnings as they are found: the recording's at open, then the fields a video could not give.
    std::vector<std::string> warnings;
    const auto print_warnings = [&] {
        for (std::string& w : rec.take_warnings()) {
            std::fprintf(stderr, "eyesim: warning: %s\n", w.c_str());
            warnings.push_back(std::move(w));
        }
    };
    print_warnings();
    int64_t n_fields = rec.common_field_count();
    if (opt.max_fields >= 0) n_fields = std::min(n_fields, opt.max_fields);

    std::vector<rig::FieldTruth> truth;
    if (!rec.truth_path().empty()) {
        truth = rig::read_truth(rec.truth_path());
        if (truth.empty()) throw eyesim::app::Error(rec.truth_path() + ": no lines");  // present but empty: not a truth file
    }

    proto::CaptureWriter capture;
    const bool capture_on = !opt.out.empty();
    if (capture_on && !capture.create(opt.out.c_str()))
        throw eyesim::app::Error(fmt::format("{}: cannot create capture file", opt.out));
    capture.set_flush_each(false);
    std::ofstream csv;
    if (!opt.csv.empty()) {
        csv.open(opt.csv);
        if (!csv) throw eyesim::app::Error(fmt::format("{}: cannot create CSV file", opt.csv));
        csv << "camera,field,parity,index,class,x_px,y_px,area_px,sum_w,bbox_x0,bbox_y0,bbox_x1,bbox_y1,flags,"
               "complete_us,emit_us,latency_us,refine,truth_body,truth_marker,error_x_px,error_y_px,occluded_fraction,"
               "refine_hint\n";
    }

    // One pipeline per camera with the reset register map, as the device powers up, plus any --reg writes.
    const std::vector<fpga::RegisterMap> maps = eyesim::app::register_maps(opt.regs, rec.camera_count());
    eyesim::app::FpgaModelRun model(rec, cams, maps);
    std::vector<CameraStats> stats;
    for (int c : cams) stats.push_back(CameraStats{c});
    std::vector<BlobTruth> blob_truth;  // per blob of the current field, reused
    const std::vector<const char*> no_outcomes;
    const std::vector<std::uint8_t> no_hints;
    std::array<uint8_t, proto::kMaxFrameBytes> frame{};
    // Receive times. There is no host on this path: the capture uses the device clock as the host clock (offset 0)
    // and stamps each record with the modelled time its frame has left the device (docs/protocol.md section 6):
    // ready (a PedalState at its sample time; a field's messages once its last active pixel is in and its last
    // blob has left the pipeline), then the soft core's encoding cost and the USB link, one frame after the other
    // in the order they became ready (eyesim/firmware/latency.hpp, the model the device core uses).
    // Sequence numbers follow the order the frames are sent, as on the device.
    struct Record {
        uint64_t ready_ns;
        uint32_t blobs;
        proto::Message message;
    };
    std::vector<Record> records;  // ready, not yet sent
    uint16_t sequence = 0;
    eyesim::firmware::LinkModel link;
    uint64_t core_free_ns = 0;
    // Sends every record ready before `horizon_ns` (no later field can produce an earlier one), in ready order.
    auto send_ready = [&](uint64_t horizon_ns) {
        std::stable_sort(records.begin(), records.end(),
                         [](const Record& a, const Record& b) { return a.ready_ns < b.ready_ns; });
        size_t k = 0;
        for (; k < records.size() && records[k].ready_ns < horizon_ns; ++k) {
            const Record& r = records[k];
            const size_t len = proto::encode_frame(r.message, sequence++, frame);
            if (len == 0) throw eyesim::app::Error("a message does not encode");
            const uint64_t queued_ns = std::max(r.ready_ns, core_free_ns) + eyesim::firmware::frame_cost_ns(len, r.blobs);
            core_free_ns = queued_ns;
            const uint64_t rx_us = (link.transmit(queued_ns, len) + 999) / 1000;  // whole µs, not before
            if (!capture.write(rx_us, std::span<const uint8_t>(frame.data(), len)))
                throw eyesim::app::Error(fmt::format("{}: write failed", opt.out));
        }
        records.erase(records.begin(), records.begin() + static_cast<std::ptrdiff_t>(k));
    };
    double refine_s = 0;
    // Refinement stage: a model fit on each blob's patch with the rig's marker colours (tracking/refine.hpp).
    std::unique_ptr<eyesim::app::BlobRefiner> refiner;
    const eyesim::tracking::SphereFitConfig refiner_config =
        opt.refine ? eyesim::app::recording_sphere_fit_config(rec) : eyesim::tracking::SphereFitConfig{};
    if (opt.refine) refiner = std::make_unique<eyesim::app::BlobRefiner>(refiner_config);
    // What hides part of a marker (its shaft, the eye) for the fits, as the host's live chain has it: a tracker runs
    // on the refined blobs, and each field's fits take the occluders of the newest poses it gave (earlier fields).
    std::unique_ptr<eyesim::tracking::Tracker> hint_tracker;
    std::unique_ptr<eyesim::app::HintMotion> hint_motion;  // the instruments' hints at each field's time
    eyesim::tracking::MarkerHintSource marker_hints;
    eyesim::tracking::TrackingFrame hint_frame;
    std::vector<std::pair<double, proto::FieldMarkers>> hint_msgs;
    if (opt.refine && !opt.no_hints) {
        try {
            const rig::Bodies bodies = rig::load_bodies(rig::default_bodies_path());
            std::vector<eyesim::tracking::SceneInstrument> scene;
            if (!truth.empty())
                for (const rig::InstrumentTruth& it : truth.front().instruments) scene.push_back({it.kind, it.trocar});
            else
                scene = eyesim::tracking::all_instruments(bodies);
            eyesim::tracking::TrackerConfig tcfg = eyesim::frame::tracker_config(rec.cameras(), bodies, scene);
            marker_hints = eyesim::tracking::MarkerHintSource(tcfg.cameras, tcfg.bodies);
            // The first fields' hints from the poses a look ahead finds (they have no earlier fields' poses).
            eyesim::app::prime_marker_hints(opt.recording, cams, maps, refiner_config, tcfg,
                                            std::min(eyesim::app::kMaxPrimingFields, n_fields), marker_hints);
            if (eyesim::app::hint_motion_for(refiner_config))
                hint_motion = std::make_unique<eyesim::app::HintMotion>(tcfg);
            hint_tracker = std::make_unique<eyesim::tracking::Tracker>(std::move(tcfg));
            refiner->set_hints(&marker_hints);
        } catch (const std::invalid_argument& e) {
            throw eyesim::app::Error(std::string("bodies: ") + e.what());
        }
    }
    const bool progress = eyesim::app::show_progress(opt.json);

    // The pedal, as eyesim-device sends it: one PedalState per field period from the truth (when there is one).
    const eyesim::firmware::pc::PedalTrack pedal(eyesim::firmware::pc::pedal_track_of(truth), nullptr);
    for (int64_t i = 0; i < n_fields; ++i) {
        if (capture_on && !truth.empty()) {
            const double t_us = std::max(0.0, rec.field_timing(cams.front(), i).start_us);
            const uint64_t device_us = static_cast<uint64_t>(std::llround(t_us));
            records.push_back({device_us * 1000u, 0, proto::Message{pedal.message_at(t_us, device_us)}});
        }
        size_t k = 0;
        model.run_field(i, [&](eyesim::app::ModelField& f) {
            const std::vector<fpga::Blob>& blobs = *f.blobs;
            const fpga::FieldStats& fs = *f.stats;
            CameraStats& st = stats[k++];
            if (opt.refine) {
                const auto r0 = std::chrono::steady_clock::now();
                if (hint_motion) hint_motion->move_to_field(hint_frame, f.camera, f.parity, f.start_us, marker_hints);
                st.refined += refiner->refine(f.uyvy, rig::kFieldHeight, *f.blobs, f.camera);
                refine_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - r0).count();
            }
            ++st.fields;
            st.blobs += static_cast<int64_t>(blobs.size());
            st.overflows += fs.table_overflows;
            for (const fpga::Blob& b : blobs) st.latency_us.push_back(b.latency_us());
            st.field_latency_us.push_back(fpga::cycles_to_us(fs.last_blob_latency_cycles));
            blob_truth.clear();
            if (i < static_cast<int64_t>(truth.size()))
                score(blobs, truth[static_cast<size_t>(i)], f.camera, f.parity, st, blob_truth);

            if (csv.is_open()) {
                // The refinement's outcome per blob (none without --refine).
                const auto& outcomes = refiner ? refiner->last_outcomes() : no_outcomes;
                for (size_t bi = 0; bi < blobs.size(); ++bi) {
                    const fpga::Blob& b = blobs[bi];
                    csv << fmt::format("{},{},{},{},{},{:.6f},{:.6f},{},{},{},{},{},{},{},{},{},{:.3f}", f.camera, i,
                                       f.parity, b.index, b.class_id, b.cx_px(), b.cy_px(), b.area_px, b.sum_w, b.x_min,
                                       b.y_min, b.x_max, b.y_max, b.flags, fpga::device_time_us(f.start_us, b.last_pixel_cycle),
                                       fpga::device_time_us(f.start_us, b.emit_cycle), b.latency_us());
                    csv << ',' << (bi < outcomes.size() ? outcomes[bi] : "");
                    // Truth columns: empty where the recording has no truth or the blob matched no marker.
                    if (bi < blob_truth.size() && blob_truth[bi].marker) {
                        const BlobTruth& t = blob_truth[bi];
                        csv << fmt::format(",{},{},{:.6f},{:.6f},{:.4f}", t.marker->body, t.marker->id,
                                           t.error_px.x(), t.error_px.y(), t.occluded_fraction);
                    } else {
                        csv << ",,,,,";
                    }
                    // With --refine: 1 where the poses gave the blob's fit a hint, 0 where not.
                    const auto& hints = refiner ? refiner->last_hinted() : no_hints;
                    csv << ',' << (bi < hints.size() ? (hints[bi] ? "1" : "0") : "") << '\n';
                }
            }
            if (!capture_on && !hint_tracker) return;
            // Ready once the last active pixel is in and the last blob has left the pipeline (as the device).
            const uint64_t ready_ns = eyesim::app::field_ready_ns(f);
            const std::vector<proto::FieldMarkers> msgs = eyesim::app::field_messages(f);
            if (hint_tracker)
                for (const proto::FieldMarkers& m : msgs) hint_msgs.push_back({1e-3 * static_cast<double>(ready_ns), m});
            if (capture_on) {
                for (size_t m = 0; m < msgs.size(); ++m) {
                    if (!proto::valid_message(proto::Message{msgs[m]}))
                        throw eyesim::app::Error(fmt::format("camera {} field {}: message {} does not encode", f.camera, i, m));
                    records.push_back({ready_ns, msgs[m].marker_count, proto::Message{msgs[m]}});
                }
            }
        });
        if (hint_tracker)
            eyesim::app::feed_hint_tracker(hint_msgs, *hint_tracker, hint_frame, marker_hints, hint_motion.get());
        if (capture_on) {
            // Everything of the next field is ready no earlier than its earliest camera's vertical sync.
            uint64_t horizon_ns = ~uint64_t{0};
            if (i + 1 < n_fields)
                for (int cam : cams)
                    horizon_ns = std::min(horizon_ns, static_cast<uint64_t>(std::llround(std::max(
                                                          0.0, rec.field_timing(cam, i + 1).start_us))) * 1000u);
            send_ready(horizon_ns);
        }
        print_warnings();
        if (progress && (i % 25 == 0 || i + 1 == n_fields))
            std::fprintf(stderr, "\rfpga: field %lld/%lld", static_cast<long long>(i + 1), static_cast<long long>(n_fields));
    }
    if (progress) std::fprintf(stderr, "\n");
    if (capture_on && !capture.flush()) throw eyesim::app::Error(fmt::format("{}: write failed", opt.out));
    capture.close();
    if (csv.is_open()) {
        csv.flush();
        if (!csv) throw eyesim::app::Error(fmt::format("{}: write failed", opt.csv));
    }

    int64_t total_fields = 0, total_blobs = 0, refined = 0, lost = 0;
    ErrorSums all;                      // over the cameras
    std::array<ErrorSums, 2> all_vis;
    for (int c : cams) lost += rec.lost_fields(c);
    std::vector<double> all_latency;
    nlohmann::json per_cam = nlohmann::json::array();
    for (const CameraStats& st : stats) {
        total_fields += st.fields;
        total_blobs += st.blobs;
        refined += st.refined;
        all_latency.insert(all_latency.end(), st.latency_us.begin(), st.latency_us.end());
        nlohmann::json j{{"camera", st.camera}, {"fields", st.fields}, {"blobs", st.blobs},
                         {"blob_table_overflows", st.overflows}, {"latency_us", latency_json(st.latency_us)},
                         {"field_last_blob_latency_us", latency_json(st.field_latency_us)}};
        if (opt.refine) j["refined"] = st.refined;
        if (!truth.empty()) {
            j["centroid_rms_px"] = rms(st.err);
            j["matched"] = st.err.n;
            j["missed"] = st.missed;
            j["extra"] = st.extra;
            j["centroid_bias_px"] = bias_json(st.err);
            j["centroid_by_visibility"] = visibility_json(st.vis);
            all.add(st.err);
            for (size_t h = 0; h < 2; ++h) all_vis[h].add(st.vis[h]);
        }
        j["lost_fields"] = rec.lost_fields(st.camera);
        per_cam.push_back(j);
    }
    const double model_s = model.model_seconds();
    const double fps = model_s > 0 ? total_fields / model_s : 0.0;
    if (opt.json) {
        nlohmann::json j{{"recording", opt.recording}, {"fields", total_fields}, {"fields_per_s", fps},
                         {"blobs", total_blobs}, {"latency_us", latency_json(all_latency)}, {"cameras", per_cam},
                         {"truth", !truth.empty()}, {"lost_fields", lost}, {"warnings", warnings}, {"errors", 0}};
        if (!truth.empty()) {
            j["centroid_rms_px"] = rms(all);
            j["centroid_bias_px"] = bias_json(all);
            j["centroid_by_visibility"] = visibility_json(all_vis);
        }
        if (opt.refine) {
            j["refined"] = refined;
            j["refine_fields_per_s"] = refine_s > 0 ? total_fields / refine_s : 0.0;
            j["refused"] = refiner->refusals_json();  // blobs whose fit was refused, by reason
            j["hinted_fits"] = refiner->hinted_fits();  // fits with an occluder (shaft, eye) left out
        }
        if (!opt.out.empty()) j["out"] = opt.out;
        if (!opt.csv.empty()) j["csv"] = opt.csv;
        std::printf("%s\n", j.dump().c_str());
    } else {
        std::printf("%s: %lld fields, %lld blobs, %.0f fields/s (model)\n", opt.recording.c_str(),
                    static_cast<long long>(total_fields), static_cast<long long>(total_blobs), fps);
        if (opt.refine) {
            std::printf("  refinement: %lld of %lld blobs refined by the sphere fit, %.0f fields/s; refused:",
                        static_cast<long long>(refined), static_cast<long long>(total_blobs),
                        refine_s > 0 ? total_fields / refine_s : 0.0);
            for (int r = 1; r < eyesim::tracking::kFitRefusalCount; ++r)
                std::printf(" %s %lld", eyesim::tracking::to_string(static_cast<eyesim::tracking::FitRefusal>(r)),
                            static_cast<long long>(refiner->refusals()[static_cast<size_t>(r)]));
            std::printf("\n");
        }
        for (const CameraStats& st : stats)
            if (!truth.empty())
                std::printf("  cam%d: centroid RMS %.4f px over %lld markers, %lld missed, %lld extra\n", st.camera,
                            rms(st.err), static_cast<long long>(st.err.n),
                            static_cast<long long>(st.missed), static_cast<long long>(st.extra));
    }
    return 0;
}

eyesim::app::Registrar reg{"fpga", "Run the FPGA pipeline model over a recording", [](CLI::App& sub) {
    auto opt = std::make_shared<FpgaOptions>();
    sub.add_option("--recording", opt->recording, "recording directory (rig.yaml + cam*.uyvy or video)")->required();
    sub.add_option("--cameras", opt->cameras, "comma-separated camera indices (default: all)");
    sub.add_option("--out", opt->out, "capture file of protocol FieldMarkers packets, and the pedal from the truth (device-time stamps)");
    sub.add_option("--csv", opt->csv, "CSV file with one row per blob");
    sub.add_option("--fields", opt->max_fields, "process at most this many fields per camera")
        ->check(CLI::Range(int64_t{1}, std::numeric_limits<int64_t>::max()));
    sub.add_option("--reg", opt->regs, "register write ADDRESS=VALUE before the first field (repeatable)");
    sub.add_flag("--json", opt->json, "print one JSON summary object on stdout");
    sub.add_flag("--refine", opt->refine,
                 "refine each blob's centroid by a shaded-sphere fit on its patch (refinement stage; the pipeline's "
                 "centroid stands where the fit is refused)");
    sub.add_flag("--no-hints", opt->no_hints,
                 "with --refine: fit every marker as a whole sphere (by default a marker's fit leaves out what hides "
                 "part of it, its instrument's shaft or the eye, placed from the newest poses of a tracker run on the "
                 "refined blobs)");
    return [opt]() -> int {
        try {
            if (opt->no_hints && !opt->refine) throw eyesim::app::Error("fpga: --no-hints needs --refine", 2);
            return run(*opt);
        } catch (const rig::RigError& e) {
            throw eyesim::app::Error(e.what());
        }
    };
}};

}  // namespace
