// Benchmark of the FPGA pipeline model: fields/s on one core and centroid error against rendered truth, beside
// an OpenCV pipeline (cvtColor → inRange → connectedComponentsWithStats → moments) on the same fields in the
// same run. Fields: 720×288, dark background with a white "eye" disc, 8–20 markers of 6–10 px (frame px; half
// as tall in a field), BT.601 studio swing, [1 2 1] co-sited chroma, Gaussian noise.
//
// Usage: bench_fpga_model [fields=64] [repeats=7] [noise_sigma=1.0]
#include "field_gen.hpp"
#include "luma_estimate.hpp"
#include "opencv_baseline.hpp"

#include "eyesim/tracking/refine.hpp"

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <memory>
#include <string>
#include <ctime>

using namespace eyesim::fpga;
using namespace eyesim::fpga::test;
using eyesim::fpga::bench::Detection;
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
        for (const Marker& o : s.markers) clear = clear && std::hypot(o.cx - m.cx, 2 * (o.cy - m.cy)) > 16;
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

struct Row {
    std::string name;
    double fields_per_s;
    ErrorStats err;
};

}  // namespace

int main(int argc, char** argv) {
    const int n_fields = argc > 1 ? std::atoi(argv[1]) : 64;
    const int repeats = argc > 2 ? std::atoi(argv[2]) : 7;
    const double noise = argc > 3 ? std::atof(argv[3]) : 1.0;
    if (n_fields < 1 || repeats < 1 || !(noise >= 0)) {
        std::fprintf(stderr, "usage: bench_fpga_model [fields>=1] [repeats>=1] [noise_sigma>=0]\n");
        return 2;
    }
    cv::setNumThreads(1);  // per-core comparison

    std::vector<Scene> scenes;
    for (int i = 0; i < n_fields; ++i) scenes.push_back(make_scene(1000 + static_cast<uint32_t>(i), noise, 6.0, 10.0));
    int markers = 0;
    for (const Scene& s : scenes) markers += static_cast<int>(s.markers.size());

    // Fields per second of this thread's CPU time (CLOCK_THREAD_CPUTIME_ID): per core, and robust on a shared,
    // busy machine where wall time also counts time the thread waited for a core. Median of the repeats.
    auto cpu_s = [] {
        timespec ts{};
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
        return ts.tv_sec + 1e-9 * ts.tv_nsec;
    };
    auto time_it = [&](const std::function<void(const Scene&)>& fn) {
        std::vector<double> fps;
        for (int r = 0; r < repeats; ++r) {
            const double t0 = cpu_s();
            for (const Scene& s : scenes) fn(s);
            fps.push_back(n_fields / (cpu_s() - t0));
        }
        return median(fps);
    };

    std::vector<Row> rows;
    auto model_row = [&](const std::string& name, const std::function<void(RegisterMap&)>& setup, bool roi) {
        RegisterMap regs;
        setup(regs);
        Pipeline p(regs);
        std::vector<Blob> blobs;
        blobs.reserve(64);
        p.set_sink([](void* c, const Blob& b) { static_cast<std::vector<Blob>*>(c)->push_back(b); }, &blobs);
        // ROI: one window per marker around its true position (as a tracker predicting from the last field would).
        auto set_roi = [&](const Scene& s) {
            RegisterMap r2 = regs;
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
            p.set_registers(r2);
        };
        Row row{name, 0, {}};
        for (const Scene& s : scenes) {  // accuracy pass
            if (roi) set_roi(s);
            blobs.clear();
            p.process_field(s.field.bytes.data(), 288, 0, 0);
            std::vector<Detection> det;
            for (const Blob& b : blobs) det.push_back({b.class_id, b.cx_px(), b.cy_px()});
            if (roi) {  // only the first four markers were asked for
                Scene sub = s;
                sub.markers.resize(std::min<size_t>(4, s.markers.size()));
                sub.truth.resize(sub.markers.size());
                score(sub, det, row.err);
            } else {
                score(s, det, row.err);
            }
        }
        if (roi) {
            // Timing with a fixed 4-window ROI (register changes are outside the timed loop).
            set_roi(scenes[0]);
        }
        row.fields_per_s = time_it([&](const Scene& s) {
            blobs.clear();
            p.process_field(s.field.bytes.data(), 288, 0, 0);
        });
        rows.push_back(row);
    };

    model_row("model: chroma weight 8 bit, edge ring, BG_TRACK 4 (reset)", [](RegisterMap&) {}, false);
    model_row("model: BG_TRACK off, levels 3/3/3/5 (map 1.1 reset)", [](RegisterMap& r) {
        r.write(reg::kBgTrack, 0);
        r.write(reg::kWeightBg, 0x05030303u);
    }, false);
    model_row("model: chroma weight 4 bit, edge ring", [](RegisterMap& r) { r.write(reg::kWeightBits, 4); }, false);
    model_row("model: chroma weight 2 bit, edge ring", [](RegisterMap& r) { r.write(reg::kWeightBits, 2); }, false);
    model_row("model: chroma weight 8 bit, no ring", [](RegisterMap& r) { r.write(reg::kEdgeRing, 0); }, false);
    model_row("model: luma weight 8 bit (bg 30), edge ring", [](RegisterMap& r) {
        r.write(reg::kWeightMode, 2);
        r.write(reg::kWeightBg, 0x1E1E1E1Eu);  // 30 for every class
    }, false);
    model_row("model: binary centroid", [](RegisterMap& r) { r.write(reg::kWeightMode, 0); }, false);
    model_row("model: reset, fast path off", [](RegisterMap& r) { r.write(reg::kFastPath, 0); }, false);
    model_row("model: reset, ROI 4 windows 25x13 (first 4 markers)", [](RegisterMap&) {}, true);

    OpenCvPipeline cvp;
    for (bool weighted : {true, false}) {
        cvp.weighted = weighted;
        Row row{weighted ? "OpenCV: HSV inRange + CC + saturation-weighted moments"
                         : "OpenCV: HSV inRange + CC, binary centroid",
                0, {}};
        for (const Scene& s : scenes) score(s, cvp.run(s.field.bytes.data(), 288), row.err);
        row.fields_per_s = time_it([&](const Scene& s) { cvp.run(s.field.bytes.data(), 288); });
        rows.push_back(row);
    }

    const double ocv = rows[rows.size() - 2].fields_per_s;
    std::printf("fields: %d (720x288, %d markers, 6-10 px), noise sigma %.2f, repeats %d (median), 1 thread, "
                "fields per thread-CPU second\n\n",
                n_fields, markers, noise, repeats);
    std::printf("| pipeline | fields/s | x OpenCV (weighted) | centroid RMS px | bias x, y px | matched | missed | "
                "extra |\n");
    std::printf("|---|---:|---:|---:|---:|---:|---:|---:|\n");
    for (const Row& r : rows)
        std::printf("| %s | %.0f | %.1f | %.4f | %+.3f, %+.3f | %d | %d | %d |\n", r.name.c_str(), r.fields_per_s,
                    r.fields_per_s / ocv, r.err.rms(), r.err.bias_x(), r.err.bias_y(), r.err.matched, r.err.missed,
                    r.err.extra);

    // Accuracy per marker size (reset registers) beside the OpenCV baselines, and the offline luma estimator.
    std::printf("\nCentroid RMS (px) by marker diameter (frame px), noise sigma %.2f, %d fields each\n\n", noise,
                n_fields);
    std::printf("| diameter px | model (reset) | model + disc fit | model, map 1.1 | model binary | OpenCV weighted | "
                "OpenCV binary | luma, local bg (offline) | model + luma (offline) |\n"
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
                std::vector<Blob> blobs;
                p->set_sink([](void* c, const Blob& b) { static_cast<std::vector<Blob>*>(c)->push_back(b); }, &blobs);
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
            cvp.weighted = true;
            score(s, cvp.run(s.field.bytes.data(), 288), ew);
            cvp.weighted = false;
            score(s, cvp.run(s.field.bytes.data(), 288), ec);
        }
        std::printf("| %.0f | %.4f | %.4f | %.4f | %.4f | %.4f | %.4f | %.4f | %.4f |\n", d, em.rms(), efit.rms(),
                    e11.rms(), eb.rms(), ew.rms(), ec.rms(), el.rms(), emix.rms());
    }
    std::printf("\ndisc fit: %d of %d blobs refined, the rest keep the pipeline's centroid\n", fit_ok, fit_all);
    return 0;
}
