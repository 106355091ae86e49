// Benchmark of the FPGA pipeline model: thread CPU time per field and centroid error against rendered truth,
// beside the fair OpenCV peer (opencv_peer.hpp), the naive OpenCV pipeline (opencv_baseline.hpp) and a plain
// read of the field's bytes (the memory-read limit), all on the same fields in the same run, timed in
// interleaved repeats (median). Fields: synthetic scenes (720×288, dark background with a white "eye" disc,
// 8–20 markers of 6–10 px (frame px; half as tall in a field), BT.601 studio swing, [1 2 1] co-sited chroma,
// Gaussian noise), or a rig recording with the rig's truth (--rig renders the `surgery` scenario in-process).
//
// Usage: bench_fpga_model [fields=64] [repeats=11] [noise_sigma=1.0] [--json] [--rig [--rig-seconds S] |
//                         --recording DIR] [--peer-variants] [--no-extended] [--huge-pages]
// --huge-pages: every contender reads the fields from one buffer the kernel is asked to back with 2 MB pages
// (transparent huge pages, madvise), as a capture driver's frame ring may be; the JSON says how much it got.
#include "field_gen.hpp"
#include "luma_estimate.hpp"
#include "opencv_baseline.hpp"
#include "opencv_peer.hpp"

#include "eyesim/tracking/refine.hpp"
#ifdef EYESIM_BENCH_HAVE_RIG
#include "eyesim/rig/match.hpp"
#include "eyesim/rig/pal.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/rig/truth.hpp"
#include "thread_cpu.hpp"
#endif

#include <nlohmann/json.hpp>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <string>
#include <ctime>
#include <sys/mman.h>
#include <unistd.h>

using namespace eyesim::fpga;
using namespace eyesim::fpga::test;
using eyesim::fpga::bench::Detection;
using eyesim::fpga::bench::OpenCvPeer;
using eyesim::fpga::bench::OpenCvPeerConfig;
using eyesim::fpga::bench::OpenCvPipeline;

namespace {

struct Scene {
    Field field;
    std::vector<Marker> markers;
    std::vector<std::array<double, 2>> truth;
};

// The white eye disc: centre and radius in frame pixels (field y doubled).
constexpr double kEyeX = 360, kEyeY = 144, kEyeR = 120;

// Dark background, white eye disc (markers on it and beside it).
Scene make_scene(uint32_t seed, double noise, double diam_min, double diam_max) {
    std::mt19937 rng(seed);
    std::uniform_int_distribution<int> count(8, 20), cls(1, 4);
    std::uniform_real_distribution<double> ux(12, 708), uy(6, 282), ud(diam_min, diam_max);
    Scene s;
    const int n = count(rng);
    while (static_cast<int>(s.markers.size()) < n) {
        const double d = ud(rng);
        Marker m{cls(rng), ux(rng), uy(rng), d / 2, d / 4};
        bool clear = true;  // keep markers apart (their rings must not touch) and off the eye's outline
        const double gap = std::max(16.0, diam_max + 6);  // 16 px apart up to 10-px markers
        for (const Marker& o : s.markers) clear = clear && std::hypot(o.cx - m.cx, 2 * (o.cy - m.cy)) > gap;
        clear = clear && std::fabs(std::hypot(m.cx - kEyeX, 2 * (m.cy - kEyeY)) - kEyeR) > 12;
        if (clear) s.markers.push_back(m);
    }
    s.field = render_markers(s.markers, noise, seed * 7 + 1, 288, 8, {14, 14, 18}, &s.truth);
    // Paint the eye (a white disc) under the markers: re-render with the eye as background inside the disc.
    std::vector<Marker> on_eye, off_eye;
    std::vector<std::array<double, 2>> t_on, t_off;
    const double ex = kEyeX, ey = kEyeY, er = kEyeR;
    for (size_t i = 0; i < s.markers.size(); ++i) {
        const Marker& m = s.markers[i];
        if (std::hypot(m.cx - ex, 2 * (m.cy - ey)) < er) on_eye.push_back(m);
    }
    if (!on_eye.empty()) {
        const Field eye = render_markers(on_eye, noise, seed * 7 + 2, 288, 8, {236, 234, 226}, &t_on);
        for (int y = 0; y < 288; ++y)
            for (int k = 0; k < 360; ++k) {
                const double x = 2 * k + 0.5;
                if (std::hypot(x - ex, 2 * (y - ey)) < er) std::memcpy(s.field.line(y) + 4 * k, eye.line(y) + 4 * k, 4);
            }
    }
    return s;
}

// Matches detections to truth markers by class and nearest centre (≤ 3 px); accumulates squared error.
struct ErrorStats {
    double se = 0, sdx = 0, sdy = 0;
    int matched = 0, missed = 0, extra = 0;
    double bias_x() const { return matched ? sdx / matched : 0.0; }
    double bias_y() const { return matched ? sdy / matched : 0.0; }
    double rms() const { return matched ? std::sqrt(se / matched) : 0.0; }
};

void score(const Scene& s, const std::vector<Detection>& det, ErrorStats& e) {
    std::vector<bool> used(det.size(), false);
    for (size_t i = 0; i < s.markers.size(); ++i) {
        int best = -1;
        double bd = 3.0;
        for (size_t j = 0; j < det.size(); ++j) {
            if (used[j] || det[j].cls != s.markers[i].cls) continue;
            const double d = std::hypot(det[j].x - s.truth[i][0], det[j].y - s.truth[i][1]);
            if (d < bd) {
                bd = d;
                best = static_cast<int>(j);
            }
        }
        if (best < 0) {
            ++e.missed;
            continue;
        }
        used[static_cast<size_t>(best)] = true;
        e.se += bd * bd;
        e.sdx += det[static_cast<size_t>(best)].x - s.truth[i][0];
        e.sdy += det[static_cast<size_t>(best)].y - s.truth[i][1];
        ++e.matched;
    }
    for (bool u : used) e.extra += !u;
}

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}

double load_average_1min() {
    std::ifstream f("/proc/loadavg");
    double l = -1;
    return (f >> l) ? l : -1;
}

// This process's anonymous memory in transparent huge pages, kB (-1 where the kernel does not say).
long anon_huge_kb() {
    std::ifstream f("/proc/self/smaps_rollup");
    std::string key;
    long kb = -1;
    while (f >> key) {
        if (key == "AnonHugePages:") {
            f >> kb;
            break;
        }
        f.ignore(4096, '\n');
    }
    return kb;
}

// The fields copied into one 2 MB-aligned buffer with MADV_HUGEPAGE (--huge-pages): without huge pages each
// field's 414 KB span 102 pages, each a TLB miss when every field is read from memory in turn.
struct HugeFieldBuffer {
    uint8_t* data = nullptr;
    size_t bytes = 0;
    HugeFieldBuffer() = default;
    HugeFieldBuffer(const HugeFieldBuffer&) = delete;
    HugeFieldBuffer& operator=(const HugeFieldBuffer&) = delete;
    ~HugeFieldBuffer() { std::free(data); }
    bool fill(std::vector<const uint8_t*>& fields, size_t field_bytes) {
        constexpr size_t kHuge = size_t{1} << 21;
        bytes = (fields.size() * field_bytes + kHuge - 1) / kHuge * kHuge;
        data = static_cast<uint8_t*>(std::aligned_alloc(kHuge, bytes));
        if (data == nullptr) return false;
        (void)madvise(data, bytes, MADV_HUGEPAGE);  // a hint: where refused, the figures say so (anon_huge_kb)
        for (size_t k = 0; k < fields.size(); ++k) {
            std::memcpy(data + k * field_bytes, fields[k], field_bytes);
            fields[k] = data + k * field_bytes;
        }
        return true;
    }
};

nlohmann::json maybe(bool ok, double v) { return ok ? nlohmann::json(v) : nlohmann::json(nullptr); }

nlohmann::json error_json(const ErrorStats& e) {
    return {{"centroid_rms_px", maybe(e.matched > 0, e.rms())},
            {"bias_x_px", maybe(e.matched > 0, e.bias_x())},
            {"bias_y_px", maybe(e.matched > 0, e.bias_y())},
            {"matched", e.matched},
            {"missed", e.missed},
            {"extra", e.extra}};
}

// One contender: what it detects on a field (for accuracy) and the work that is timed (the same call, without
// scoring). `scored` false: a memory pass with no detections.
struct Contender {
    std::string key, name;
    std::function<std::vector<Detection>(size_t)> detect;
    std::function<void(size_t)> work;
    bool scored = true;
    ErrorStats err;
    std::vector<double> us;  ///< µs per field, one sample per repeat
    double p50() const { return median(us); }
    double min() const { return *std::min_element(us.begin(), us.end()); }
    double max() const { return *std::max_element(us.begin(), us.end()); }
};

// Times the contenders in `repeats` interleaved rounds over all fields (each round starts at another contender,
// so a change of load or clock hits every contender alike).
void time_interleaved(std::vector<Contender*>& cs, size_t n_fields, int repeats) {
    for (int r = 0; r < repeats; ++r)
        for (size_t j = 0; j < cs.size(); ++j) {
            Contender& c = *cs[(j + static_cast<size_t>(r)) % cs.size()];
            const double t0 = eyesim::bench::thread_cpu_s();
            for (size_t f = 0; f < n_fields; ++f) c.work(f);
            c.us.push_back(1e6 * (eyesim::bench::thread_cpu_s() - t0) / static_cast<double>(n_fields));
        }
}

std::vector<Detection> blobs_to_detections(const std::vector<Blob>& blobs) {
    std::vector<Detection> det;
    det.reserve(blobs.size());
    for (const Blob& b : blobs) det.push_back({b.class_id, b.cx_px(), b.cy_px()});
    return det;
}

// A sink that appends to a vector.
void push_blob(void* c, const Blob& b) { static_cast<std::vector<Blob>*>(c)->push_back(b); }

// The fair peer's variants tried while tuning it (docs/bench/fpga-model.md, "The fair peer").
std::vector<std::pair<std::string, OpenCvPeerConfig>> peer_variants() {
    std::vector<std::pair<std::string, OpenCvPeerConfig>> v;
    v.push_back({"tuned (see opencv_peer.hpp)", {}});
    OpenCvPeerConfig c;
    auto add = [&](const std::string& name, const std::function<void(OpenCvPeerConfig&)>& f) {
        c = {};
        f(c);
        v.push_back({name, c});
    };
    add("blocks 16 px x 4 lines", [](OpenCvPeerConfig& k) { k.block_lines = 4; });
    add("blocks 16 px x 2 lines", [](OpenCvPeerConfig& k) { k.block_lines = 2; });
    add("grey box test only (no disc test of flagged blocks)", [](OpenCvPeerConfig& k) { k.disc_test = false; });
    add("findContours + boundingRect boxes", [](OpenCvPeerConfig& k) { k.contours = true; });
    add("CCL_WU (SAUF) labelling", [](OpenCvPeerConfig& k) { k.ccl = cv::CCL_WU; });
    add("CCL_GRANA (BBDT) labelling", [](OpenCvPeerConfig& k) { k.ccl = cv::CCL_GRANA; });
    add("background: band mean, no plane", [](OpenCvPeerConfig& k) { k.plane = false; });
    for (double l : {0.0, 1.0, 1.5, 2.0, 3.0}) {
        char name[64];
        std::snprintf(name, sizeof name, "fixed level %.1f", l);
        add(name, [l](OpenCvPeerConfig& k) {
            k.level = l;
            k.level_sigmas = 0;
        });
    }
    for (double n : {1.0, 1.5, 2.5, 3.0}) {
        char name[64];
        std::snprintf(name, sizeof name, "level %.1f sigma of the band", n);
        add(name, [n](OpenCvPeerConfig& k) { k.level_sigmas = n; });
    }
    add("ring 1 column", [](OpenCvPeerConfig& k) { k.ring_columns = 1; });
    add("ring 3 columns", [](OpenCvPeerConfig& k) { k.ring_columns = 3; });
    add("ring 2 lines", [](OpenCvPeerConfig& k) { k.ring_lines = 2; });
    add("band 3 columns", [](OpenCvPeerConfig& k) { k.band_columns = 3; });
    add("band 7 columns", [](OpenCvPeerConfig& k) { k.band_columns = 7; });
    add("band 1 line", [](OpenCvPeerConfig& k) { k.band_lines = 1; });
    add("band 3 lines", [](OpenCvPeerConfig& k) { k.band_lines = 3; });
    add("band 3 columns, 1 line", [](OpenCvPeerConfig& k) {
        k.band_columns = 3;
        k.band_lines = 1;
    });
    add("ring 3 columns, level 1.5 sigma", [](OpenCvPeerConfig& k) {
        k.ring_columns = 3;
        k.level_sigmas = 1.5;
    });
    return v;
}

}  // namespace

int main(int argc, char** argv) {
    int n_fields = 64, repeats = 11;
    double noise = 1.0, rig_seconds = 2.0;
    bool json = false, rig_mode = false, variants = false, extended = true, huge_pages = false;
    std::string recording_dir;
    std::vector<std::string> positional;
    auto usage = [](const std::string& why) {
        std::fprintf(stderr,
                     "eyesim: error: %s\nusage: bench_fpga_model [fields>=1] [repeats>=1] [noise_sigma>=0] [--json] "
                     "[--rig [--rig-seconds S] | --recording DIR] [--peer-variants] [--no-extended] [--huge-pages]\n",
                     why.c_str());
        return 2;
    };
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--json") {
            json = true;
        } else if (a == "--rig") {
            rig_mode = true;
        } else if (a == "--peer-variants") {
            variants = true;
        } else if (a == "--no-extended") {
            extended = false;
        } else if (a == "--huge-pages") {
            huge_pages = true;
        } else if (a == "--rig-seconds" || a == "--recording") {
            if (i + 1 >= argc) return usage(a + " needs a value");
            if (a == "--recording") {
                recording_dir = argv[++i];
            } else {
                char* end = nullptr;
                rig_seconds = std::strtod(argv[++i], &end);
                if (*end != '\0' || !(rig_seconds > 0 && rig_seconds <= 60)) return usage("--rig-seconds: 0 < S <= 60");
            }
            rig_mode = true;
        } else if (a.rfind("--", 0) == 0) {
            return usage("unknown option " + a);
        } else {
            positional.push_back(a);
        }
    }
    if (positional.size() > 3) return usage("too many arguments");
    auto number = [](const std::string& s, double& v) {
        char* end = nullptr;
        v = std::strtod(s.c_str(), &end);
        return !s.empty() && *end == '\0' && std::isfinite(v);
    };
    double v = 0;
    if (positional.size() > 0 && !(number(positional[0], v) && v >= 1 && v <= 100000 && v == std::floor(v)))
        return usage("fields: an integer >= 1");
    if (positional.size() > 0) n_fields = static_cast<int>(v);
    if (positional.size() > 1 && !(number(positional[1], v) && v >= 1 && v <= 1000 && v == std::floor(v)))
        return usage("repeats: an integer >= 1");
    if (positional.size() > 1) repeats = static_cast<int>(v);
    if (positional.size() > 2 && !(number(positional[2], v) && v >= 0 && v <= 50))
        return usage("noise_sigma: 0..50");
    if (positional.size() > 2) noise = v;
#ifndef EYESIM_BENCH_HAVE_RIG
    if (rig_mode) return usage("--rig/--recording: built without the rig library");
#endif
    cv::setNumThreads(1);  // per-core comparison
    const double load_start = load_average_1min();

    // The field set: synthetic scenes, or every camera's fields of a rig recording (in memory, read once).
    std::vector<Scene> scenes;
    std::vector<std::vector<uint8_t>> rig_fields;
    std::vector<const uint8_t*> fields;
    std::function<void(size_t, const std::vector<Detection>&, ErrorStats&)> score_field;
    int markers = 0;
    nlohmann::json source;
#ifdef EYESIM_BENCH_HAVE_RIG
    namespace rig = eyesim::rig;
    std::vector<rig::FieldTruth> truth;
    std::vector<std::pair<int, int64_t>> rig_ids;
#endif
    if (!rig_mode) {
        for (int i = 0; i < n_fields; ++i)
            scenes.push_back(make_scene(1000 + static_cast<uint32_t>(i), noise, 6.0, 10.0));
        for (const Scene& s : scenes) {
            markers += static_cast<int>(s.markers.size());
            fields.push_back(s.field.bytes.data());
        }
        score_field = [&](size_t i, const std::vector<Detection>& det, ErrorStats& e) { score(scenes[i], det, e); };
        source = {{"kind", "synthetic"}, {"fields", n_fields}, {"markers", markers}, {"noise_sigma", noise},
                  {"diameter_px", {6, 10}}};
    }
#ifdef EYESIM_BENCH_HAVE_RIG
    if (rig_mode) {
        try {
            std::string dir = recording_dir;
            bool made = false;
            if (dir.empty()) {  // render the surgery scenario in-process, removed after reading
                dir = (std::filesystem::temp_directory_path() /
                       ("eyesim_bench_fpga_model_surgery_" + std::to_string(::getpid())))
                          .string();
                std::filesystem::remove_all(dir);
                rig::SynthRequest req;
                req.out_dir = dir;
                req.scenario = "surgery";
                req.seconds = rig_seconds;
                req.render.noise_sigma = noise;
                rig::write_recording(req);
                made = true;
            }
            rig::Recording rec = rig::Recording::open(dir);
            if (rec.truth_path().empty()) {
                std::fprintf(stderr, "eyesim: error: %s: truth.jsonl missing\n", dir.c_str());
                return 1;
            }
            truth = rig::read_truth(rec.truth_path());
            const int64_t n = std::min<int64_t>(rec.common_field_count(), static_cast<int64_t>(truth.size()));
            for (int64_t i = 0; i < n; ++i)
                for (int c = 0; c < rec.camera_count(); ++c) {
                    rig_fields.emplace_back(static_cast<size_t>(rig::kFieldBytes));
                    rec.read_field(c, i, rig_fields.back().data());
                    rig_ids.emplace_back(c, i);
                }
            if (made) std::filesystem::remove_all(dir);
            for (const auto& f : rig_fields) fields.push_back(f.data());
            if (fields.empty()) {
                std::fprintf(stderr, "eyesim: error: %s: no fields\n", dir.c_str());
                return 1;
            }
            // Truth: the rig's centroid of every visible, unoccluded marker (area ≥ 2 px); class + nearest
            // within 3 px. Extra: detections within 3 px of no visible marker of their class (occluded ones
            // included, whose centroid the truth does not define).
            score_field = [&](size_t k, const std::vector<Detection>& det, ErrorStats& e) {
                const rig::FieldTruth& t = truth[static_cast<size_t>(rig_ids[k].second)];
                const int cam = rig_ids[k].first;
                std::vector<rig::DetectedMarker> found;
                for (const Detection& d : det) found.push_back({d.cls, Eigen::Vector2d(d.x, d.y)});
                std::vector<bool> used;
                rig::match_markers(
                    t, cam, found, 3.0,
                    [](const rig::MarkerTruth&, const rig::MarkerCameraTruth& view) {
                        return view.visible && !(view.area_px < 2.0) && !(view.occluded_fraction > 0.0);
                    },
                    [&](const rig::MarkerMatch& m) {
                        if (m.detection < 0) {
                            ++e.missed;
                            return;
                        }
                        const Detection& d = det[static_cast<size_t>(m.detection)];
                        e.se += m.distance_px * m.distance_px;
                        e.sdx += d.x - m.view->centroid_px.x();
                        e.sdy += d.y - m.view->centroid_px.y();
                        ++e.matched;
                    },
                    used);
                for (size_t j = 0; j < det.size(); ++j) {
                    if (used[j]) continue;
                    bool near = false;
                    for (const rig::MarkerTruth& m : t.markers) {
                        if (cam >= static_cast<int>(m.cams.size()) || m.colour_class != det[j].cls) continue;
                        const rig::MarkerCameraTruth& view = m.cams[static_cast<size_t>(cam)];
                        near = near || (view.visible && (view.centroid_px - Eigen::Vector2d(det[j].x, det[j].y)).norm() < 3.0);
                    }
                    e.extra += !near;
                }
            };
            for (size_t k = 0; k < fields.size(); ++k) {
                const rig::FieldTruth& t = truth[static_cast<size_t>(rig_ids[k].second)];
                for (const rig::MarkerTruth& m : t.markers) {
                    if (rig_ids[k].first >= static_cast<int>(m.cams.size())) continue;
                    const rig::MarkerCameraTruth& view = m.cams[static_cast<size_t>(rig_ids[k].first)];
                    markers += view.visible && !(view.area_px < 2.0) && !(view.occluded_fraction > 0.0);
                }
            }
            source = {{"kind", "rig"},
                      {"recording", recording_dir.empty() ? "surgery (rendered in-process)" : recording_dir},
                      {"fields", fields.size()},
                      {"cameras", rec.camera_count()},
                      {"unoccluded_markers", markers}};
            if (recording_dir.empty()) {
                source["seconds"] = rig_seconds;
                source["noise_sigma"] = noise;
            }
        } catch (const std::exception& e) {
            std::fprintf(stderr, "eyesim: error: %s\n", e.what());
            return 1;
        }
    }
#endif
    const size_t nf = fields.size();
    constexpr size_t kFieldBytes = kLineBytes * 288;  // every field of either source is 720 × 288 UYVY
    HugeFieldBuffer huge;
    if (huge_pages && !huge.fill(fields, kFieldBytes)) {
        std::fprintf(stderr, "eyesim: error: --huge-pages: cannot allocate %zu MB\n", nf * kFieldBytes >> 20);
        return 1;
    }
    const long huge_kb = huge_pages ? anon_huge_kb() : 0;

    // Contenders. The pipeline rows are the model under several register settings; the ROI row (synthetic only)
    // asks for windows around the first four markers of each scene.
    std::vector<std::unique_ptr<Pipeline>> pipes;
    std::vector<Blob> blobs;
    blobs.reserve(256);
    std::vector<std::unique_ptr<Contender>> owned;
    auto model = [&](const std::string& key, const std::string& name, const std::function<void(RegisterMap&)>& setup,
                     const PipelineConfig& cfg = PipelineConfig{}) {
        RegisterMap regs;
        setup(regs);
        pipes.push_back(std::make_unique<Pipeline>(regs, cfg));
        Pipeline* p = pipes.back().get();
        auto c = std::make_unique<Contender>();
        c->key = key;
        c->name = name;
        c->work = [&, p](size_t f) {
            blobs.clear();
            p->set_sink(push_blob, &blobs);
            p->process_field(fields[f], 288, 0, 0);
        };
        c->detect = [&, p](size_t f) {
            blobs.clear();
            p->set_sink(push_blob, &blobs);
            p->process_field(fields[f], 288, 0, 0);
            return blobs_to_detections(blobs);
        };
        owned.push_back(std::move(c));
    };
    model("pipeline", "pipeline: reset registers (chroma weight 8 bit, edge ring, BG_TRACK 4)", [](RegisterMap&) {});
    model("pipeline_bg_offset", "pipeline: reset + BG_OFFSET (x corrected by the band beside the runs)",
          [](RegisterMap& r) { r.write(reg::kBgOffset, 1); });
    model("pipeline_map11", "pipeline: BG_TRACK off, levels 3/3/3/5 (map 1.1 reset)", [](RegisterMap& r) {
        r.write(reg::kBgTrack, 0);
        r.write(reg::kWeightBg, 0x05030303u);
    });
    model("pipeline_weight4", "pipeline: chroma weight 4 bit", [](RegisterMap& r) { r.write(reg::kWeightBits, 4); });
    model("pipeline_weight2", "pipeline: chroma weight 2 bit", [](RegisterMap& r) { r.write(reg::kWeightBits, 2); });
    model("pipeline_no_ring", "pipeline: no edge ring", [](RegisterMap& r) { r.write(reg::kEdgeRing, 0); });
    model("pipeline_luma", "pipeline: luma weight 8 bit (bg 30)", [](RegisterMap& r) {
        r.write(reg::kWeightMode, 2);
        r.write(reg::kWeightBg, 0x1E1E1E1Eu);  // 30 for every class
    });
    model("pipeline_binary", "pipeline: binary centroid", [](RegisterMap& r) { r.write(reg::kWeightMode, 0); });
    model("pipeline_no_fast_path", "pipeline: reset, fast path off", [](RegisterMap& r) { r.write(reg::kFastPath, 0); });
    // The model's own options (same output): the line scan a CPU without AVX-512 gets, no software prefetch, and
    // the prefetch into L1 at 4 lines that was the default before 2026-12-07.
    PipelineConfig avx2;
    avx2.scan_isa = ScanIsa::kAvx2;
    model("pipeline_avx2", "pipeline: reset, AVX2 line scan (a CPU without AVX-512)", [](RegisterMap&) {}, avx2);
    PipelineConfig no_prefetch;
    no_prefetch.prefetch_lines = 0;
    model("pipeline_no_prefetch", "pipeline: reset, no software prefetch", [](RegisterMap&) {}, no_prefetch);
    PipelineConfig prefetch_l1;
    prefetch_l1.prefetch_lines = 4;
    prefetch_l1.prefetch_l1 = true;
    model("pipeline_prefetch_l1", "pipeline: reset, prefetch into L1, 4 lines ahead (before 2026-12-07)", [](RegisterMap&) {},
          prefetch_l1);
    if (!rig_mode) {
        // ROI: one window per marker around its true position (as a tracker predicting from the last field
        // would); scored on the first four markers; timed with scene 0's windows (no register writes timed).
        pipes.push_back(std::make_unique<Pipeline>(RegisterMap{}));
        Pipeline* p = pipes.back().get();
        auto set_roi = [&, p](const Scene& s) {
            RegisterMap r2;
            int w = 0;
            for (size_t i = 0; i < s.markers.size() && w < kNumRoiWindows; ++i, ++w) {
                const int x0 = std::max(0, static_cast<int>(s.markers[i].cx) - 12);
                const int x1 = std::min(719, static_cast<int>(s.markers[i].cx) + 12);
                const int y0 = std::max(0, static_cast<int>(s.markers[i].cy) - 6);
                const int y1 = std::min(287, static_cast<int>(s.markers[i].cy) + 6);
                r2.write(reg::roi_x(w), static_cast<uint32_t>(x1 << 16 | x0));
                r2.write(reg::roi_y(w), static_cast<uint32_t>(y1 << 16 | y0));
            }
            r2.write(reg::kRoiEnable, (1u << w) - 1);
            p->set_registers(r2);
        };
        auto c = std::make_unique<Contender>();
        c->key = "pipeline_roi4";
        c->name = "pipeline: reset, ROI 4 windows 25x13 (first 4 markers)";
        c->work = [&, p](size_t f) {
            blobs.clear();
            p->set_sink(push_blob, &blobs);
            p->process_field(fields[f], 288, 0, 0);
        };
        c->scored = false;  // scored below on the first four markers of each scene
        for (const Scene& s : scenes) {
            set_roi(s);
            blobs.clear();
            p->set_sink(push_blob, &blobs);
            p->process_field(s.field.bytes.data(), 288, 0, 0);
            Scene sub = s;
            sub.markers.resize(std::min<size_t>(4, s.markers.size()));
            sub.truth.resize(sub.markers.size());
            score(sub, blobs_to_detections(blobs), c->err);
        }
        set_roi(scenes[0]);
        owned.push_back(std::move(c));
    }
    OpenCvPeer peer;
    {
        auto c = std::make_unique<Contender>();
        c->key = "opencv_peer";
        c->name = "fair OpenCV peer (opencv_peer.hpp)";
        c->work = [&](size_t f) { peer.run(fields[f], 288); };
        c->detect = [&](size_t f) { return peer.run(fields[f], 288); };
        owned.push_back(std::move(c));
    }
    OpenCvPipeline naive;
    {
        auto c = std::make_unique<Contender>();
        c->key = "opencv_naive";
        c->name = "naive OpenCV (BGR, HSV, inRange, 32-bit CC, saturation moments)";
        c->work = [&](size_t f) { naive.run(fields[f], 288); };
        c->detect = [&](size_t f) { return naive.run(fields[f], 288); };
        owned.push_back(std::move(c));
    }
    // The memory-read limit: a pass that only reads the field's 414,720 bytes (a SIMD sum), and a memcpy.
    volatile double sink_sum = 0;
    std::vector<uint8_t> copy(static_cast<size_t>(720 * 288 * 2));
    {
        auto c = std::make_unique<Contender>();
        c->key = "memory_read";
        c->name = "memory read: SIMD sum of the field's bytes (cv::sum)";
        c->work = [&](size_t f) {
            const cv::Mat m(288, 360, CV_8UC4, const_cast<uint8_t*>(fields[f]));
            sink_sum = sink_sum + cv::sum(m)[0];
        };
        c->scored = false;
        owned.push_back(std::move(c));
        c = std::make_unique<Contender>();
        c->key = "memcpy";
        c->name = "memcpy of the field";
        c->work = [&](size_t f) {
            std::memcpy(copy.data(), fields[f], copy.size());
            sink_sum = sink_sum + copy[static_cast<size_t>(f) % copy.size()];
        };
        c->scored = false;
        owned.push_back(std::move(c));
    }
    for (auto& c : owned)
        if (c->scored)
            for (size_t f = 0; f < nf; ++f) score_field(f, c->detect(f), c->err);

    // Peer variants (tuning), timed in their own interleaved rounds beside the tuned peer.
    std::vector<std::unique_ptr<OpenCvPeer>> variant_peers;
    std::vector<std::unique_ptr<Contender>> variant_rows;
    if (variants) {
        for (const auto& [name, cfg] : peer_variants()) {
            variant_peers.push_back(std::make_unique<OpenCvPeer>(RegisterMap{}, cfg));
            OpenCvPeer* vp = variant_peers.back().get();
            auto c = std::make_unique<Contender>();
            c->key = name;
            c->name = name;
            c->work = [&, vp](size_t f) { vp->run(fields[f], 288); };
            c->detect = [&, vp](size_t f) { return vp->run(fields[f], 288); };
            for (size_t f = 0; f < nf; ++f) score_field(f, c->detect(f), c->err);
            variant_rows.push_back(std::move(c));
        }
    }

    std::vector<Contender*> timed;
    for (auto& c : owned) timed.push_back(c.get());
    time_interleaved(timed, nf, repeats);
    if (variants) {
        std::vector<Contender*> vt;
        for (auto& c : variant_rows) vt.push_back(c.get());
        time_interleaved(vt, nf, repeats);
    }
    const double load_end = load_average_1min();
    auto find = [&](const std::string& key) -> Contender& {
        for (auto& c : owned)
            if (c->key == key) return *c;
        return *owned.front();
    };
    const double peer_us = find("opencv_peer").p50();

    nlohmann::json out;
    out["fields"] = source;
    out["repeats"] = repeats;
    out["timing"] = "thread CPU time (CLOCK_THREAD_CPUTIME_ID) per field, median of interleaved repeats, 1 thread";
    out["load_average_1min"] = {{"start", load_start}, {"end", load_end}};
    out["field_memory"] = {{"huge_pages_requested", huge_pages},
                           {"bytes", huge_pages ? huge.bytes : nf * kFieldBytes},
                           {"anon_huge_kb", huge_kb}};
    {
        static const char* const kIsa[] = {"auto", "scalar", "sse2", "avx2", "avx512"};
        out["pipeline_line_scan"] = kIsa[static_cast<int>(Pipeline(RegisterMap{}).scan_isa())];
    }
    for (auto& c : owned) {
        nlohmann::json j = error_json(c->err);
        if (!c->scored && c->err.matched == 0 && c->err.missed == 0) j = nlohmann::json::object();
        j["name"] = c->name;
        j["us_per_field"] = {{"p50", c->p50()}, {"min", c->min()}, {"max", c->max()}};
        j["fields_per_s"] = 1e6 / c->p50();
        j["speed_vs_peer"] = peer_us / c->p50();
        if (!j.contains("centroid_rms_px")) j["centroid_rms_px"] = nullptr;
        out["contenders"][c->key] = j;
    }
    out["pipeline_speedup_vs_peer"] = peer_us / find("pipeline").p50();

    if (!json) {
        std::printf("fields: %s, %zu fields, %d markers, noise sigma %.2f; %d interleaved repeats (median), 1 thread, "
                    "thread CPU time; load average %.2f -> %.2f; pipeline line scan %s; fields in %s\n\n",
                    rig_mode ? "rig surgery recording" : "synthetic scenes (6-10 px)", nf, markers, noise, repeats,
                    load_start, load_end, out["pipeline_line_scan"].get<std::string>().c_str(),
                    huge_pages ? ("huge pages (" + std::to_string(huge_kb / 1024) + " MB granted)").c_str()
                               : "default pages");
        std::printf("| contender | us/field p50 | min-max | fields/s | x peer (speed) | centroid RMS px | bias x, y px | "
                    "matched | missed | extra |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
        for (auto& c : owned) {
            std::printf("| %s | %.1f | %.1f-%.1f | %.0f | %.2f |", c->name.c_str(), c->p50(), c->min(), c->max(),
                        1e6 / c->p50(), peer_us / c->p50());
            if (c->err.matched > 0 || c->err.missed > 0)
                std::printf(" %.4f | %+.4f, %+.4f | %d | %d | %d |\n", c->err.rms(), c->err.bias_x(), c->err.bias_y(),
                            c->err.matched, c->err.missed, c->err.extra);
            else
                std::printf(" - | - | - | - | - |\n");
        }
        if (variants) {
            std::printf("\nFair peer variants (own interleaved rounds)\n\n| variant | us/field p50 | min-max | "
                        "centroid RMS px | matched | missed | extra |\n|---|---:|---:|---:|---:|---:|---:|\n");
            for (auto& c : variant_rows)
                std::printf("| %s | %.1f | %.1f-%.1f | %.4f | %d | %d | %d |\n", c->name.c_str(), c->p50(), c->min(),
                            c->max(), c->err.rms(), c->err.matched, c->err.missed, c->err.extra);
        }
    }
    for (auto& c : variant_rows) {
        nlohmann::json j = error_json(c->err);
        j["name"] = c->name;
        j["us_per_field"] = {{"p50", c->p50()}, {"min", c->min()}, {"max", c->max()}};
        out["peer_variants"].push_back(j);
    }
    if (rig_mode) {
        if (json) std::printf("%s\n", out.dump(2).c_str());
        return 0;
    }

    // Accuracy by marker size and noise: pipeline (reset) beside the fair peer, same fields.
    if (!json)
        std::printf("\nCentroid RMS (px) by marker diameter (frame px) and noise, %d fields each: pipeline (reset), "
                    "pipeline with BG_OFFSET, fair OpenCV peer\n\n| diameter px | noise sigma | markers | pipeline px | "
                    "BG_OFFSET px | peer px | pipeline missed / extra | peer missed / extra |\n"
                    "|---:|---:|---:|---:|---:|---:|---:|---:|\n",
                    n_fields);
    {
        Pipeline pm{RegisterMap{}};
        RegisterMap with_offset;
        with_offset.write(reg::kBgOffset, 1);
        Pipeline po{with_offset};
        OpenCvPeer ps;
        for (double sigma : {1.0, 2.0})
            for (double d : {4.0, 6.0, 8.0, 10.0, 12.0, 16.0}) {
                ErrorStats em, eo, ep;
                int nm = 0;
                for (int i = 0; i < n_fields; ++i) {
                    const Scene s = make_scene(5000 + static_cast<uint32_t>(i), sigma, d, d);
                    nm += static_cast<int>(s.markers.size());
                    blobs.clear();
                    pm.set_sink(push_blob, &blobs);
                    pm.process_field(s.field.bytes.data(), 288, 0, 0);
                    score(s, blobs_to_detections(blobs), em);
                    blobs.clear();
                    po.set_sink(push_blob, &blobs);
                    po.process_field(s.field.bytes.data(), 288, 0, 0);
                    score(s, blobs_to_detections(blobs), eo);
                    score(s, ps.run(s.field.bytes.data(), 288), ep);
                }
                if (!json)
                    std::printf("| %.0f | %.0f | %d | %.4f | %.4f | %.4f | %d / %d | %d / %d |\n", d, sigma, nm, em.rms(),
                                eo.rms(), ep.rms(), em.missed, em.extra, ep.missed, ep.extra);
                out["by_size"].push_back({{"diameter_px", d},
                                          {"noise_sigma", sigma},
                                          {"markers", nm},
                                          {"pipeline", error_json(em)},
                                          {"pipeline_bg_offset", error_json(eo)},
                                          {"opencv_peer", error_json(ep)}});
            }
    }
    if (json) {
        std::printf("%s\n", out.dump(2).c_str());
        return 0;
    }
    if (!extended) return 0;

    // The extended table: accuracy per marker size (reset registers) beside other register settings, the
    // refinement stage with a disc model, the naive OpenCV pipeline, and the offline luma estimator.
    std::printf("\nCentroid RMS (px) by marker diameter (frame px), noise sigma %.2f, %d fields each\n\n", noise,
                n_fields);
    std::printf("| diameter px | model (reset) | model + disc fit | model, map 1.1 | model binary | naive OpenCV weighted | "
                "naive OpenCV binary | luma, local bg (offline) | model + luma (offline) |\n"
                "|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    // The refinement stage with a flat-disc marker model: these markers are unshaded, their colours mixed
    // linearly with the background, and a field pixel integrates a whole field line (two frame rows).
    eyesim::tracking::SphereFitConfig disc_cfg;
    for (int c = 1; c <= 4; ++c) {
        const auto& rgb = kColours[static_cast<size_t>(c)];
        disc_cfg.colour[static_cast<size_t>(c)] = eyesim::tracking::MarkerColour::from_rgb(rgb[0], rgb[1], rgb[2]);
    }
    disc_cfg.shade_ambient = 1.0;
    disc_cfg.shade_diffuse = 0.0;
    disc_cfg.shot_gain = 0.0;
    disc_cfg.noise_dn = noise;
    disc_cfg.aperture_lines_px = 2.0;
    auto fit_work = std::make_unique<eyesim::tracking::SphereFitWorkspace>();
    int fit_ok = 0, fit_all = 0;
    for (double d : {4.0, 6.0, 8.0, 10.0, 14.0}) {
        ErrorStats em, efit, e11, eb, ew, ec, el, emix;
        RegisterMap reset, map11, bin;
        map11.write(reg::kBgTrack, 0);
        map11.write(reg::kWeightBg, 0x05030303u);
        bin.write(reg::kWeightMode, 0);
        Pipeline pm(reset), p11(map11), pb(bin);
        for (int i = 0; i < n_fields; ++i) {
            const Scene s = make_scene(5000 + static_cast<uint32_t>(i), noise, d, d);
            for (Pipeline* p : {&pm, &p11, &pb}) {
                blobs.clear();
                p->set_sink(push_blob, &blobs);
                p->process_field(s.field.bytes.data(), 288, 0, 0);
                std::vector<Detection> det, det_luma, det_mix, det_fit;
                for (const Blob& b : blobs) {
                    det.push_back({b.class_id, b.cx_px(), b.cy_px()});
                    if (p == &pm) {
                        const eyesim::tracking::SphereFitResult r =
                            eyesim::tracking::fit_sphere(s.field.bytes.data(), 288, eyesim::tracking::blob_box(b), disc_cfg, *fit_work);
                        ++fit_all;
                        fit_ok += r.ok;
                        det_fit.push_back({b.class_id, r.ok ? r.cx_px : b.cx_px(), r.ok ? r.cy_px : b.cy_px()});
                    }
                    eyesim::fpga::bench::LumaEstimate l;
                    if (p != &pm || !eyesim::fpga::bench::luma_centroid(s.field.bytes.data(), 288, b, l)) continue;
                    det_luma.push_back({b.class_id, l.x_px, l.y_px});
                    double mx, my;
                    eyesim::fpga::bench::mix_centroids(b, l, mx, my);
                    det_mix.push_back({b.class_id, mx, my});
                }
                score(s, det, p == &pm ? em : p == &p11 ? e11 : eb);
                if (p == &pm) {
                    score(s, det_fit, efit);
                    score(s, det_luma, el);
                    score(s, det_mix, emix);
                }
            }
            naive.weighted = true;
            score(s, naive.run(s.field.bytes.data(), 288), ew);
            naive.weighted = false;
            score(s, naive.run(s.field.bytes.data(), 288), ec);
        }
        std::printf("| %.0f | %.4f | %.4f | %.4f | %.4f | %.4f | %.4f | %.4f | %.4f |\n", d, em.rms(), efit.rms(),
                    e11.rms(), eb.rms(), ew.rms(), ec.rms(), el.rms(), emix.rms());
    }
    std::printf("\ndisc fit: %d of %d blobs refined, the rest keep the pipeline's centroid\n", fit_ok, fit_all);
    return 0;
}
