// The eye's filter in the asynchronous tracker starts from its first acquisition fit, at rest
// (tracking::AsyncOptions::eye_filter_from_one_fit), not from two fits in a row and their finite-difference rate. On
// the rig the acquisition fits are of the other cameras' fields held to the reference field's time (nothing to
// extrapolate at a stream's start) and of partly hidden markers: the rate of two such fits was off, and the first
// frames carried it. Both starts are fed the same FPGA model messages of `surgery` recordings and scored against the
// rig's truth.
#include "rig_fixture.hpp"

#include "eyesim/app/fpga_run.hpp"
#include "eyesim/frame/session.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/tracking/tracker.hpp"
#include "eyesim/tracking/validation.hpp"

#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

using namespace eyesim;

TEST_CASE("the eye's filter starts from one fit: its first frames nearer the truth", "[app][rig][tracking][async]") {
    const rig::Bodies bodies = rig::load_bodies(rig::default_bodies_path());
    double pooled_first[2] = {0, 0};
    int n_first = 0;
    for (const uint64_t seed : {61u, 62u, 63u}) {
        fpga::test::RigRecording written("eyesim_eye_start", "surgery", 1.0, 1.0, seed);
        rig::Recording& rec = written.rec;
        std::vector<tracking::SceneInstrument> scene;
        for (const rig::InstrumentTruth& it : written.truth.front().instruments) scene.push_back({it.kind, it.trocar});
        tracking::TrackerConfig cfg = frame::tracker_config(rec.cameras(), bodies, scene);
        cfg.sync.mode = tracking::SyncMode::Async;
        std::vector<std::pair<double, protocol::FieldMarkers>> msgs;
        app::FpgaModelRun model(rec, {0, 1, 2}, std::vector<fpga::RegisterMap>(3));
        const int64_t fields = std::min<int64_t>(rec.common_field_count(), static_cast<int64_t>(written.truth.size()));
        for (int64_t i = 0; i < fields; ++i)
            model.run_field(i, [&](app::ModelField& f) {
                for (const protocol::FieldMarkers& m : app::field_messages(f))
                    msgs.push_back({1e-3 * static_cast<double>(app::field_ready_ns(f)), m});
            });
        std::stable_sort(msgs.begin(), msgs.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
        std::vector<double> err[2];  // eye rotation error of each measured frame: two fits, one fit
        for (int k = 0; k < 2; ++k) {
            tracking::TrackerConfig c = cfg;
            c.async.eye_filter_from_one_fit = k == 1;
            tracking::Tracker tracker(c);
            tracking::TrackingFrame frame;
            const auto take = [&] {
                if (frame.reference_field >= written.truth.size()) return;
                const tracking::FrameScore s = tracking::score_frame(frame, c.bodies, written.truth[frame.reference_field]);
                if (s.eye_error_deg >= 0) err[k].push_back(s.eye_error_deg);
            };
            for (const auto& [t_us, m] : msgs) {
                tracker.push(m, t_us);
                while (tracker.pop(frame, t_us)) take();
            }
            tracker.finish();
            while (tracker.pop(frame, 1e15)) take();
        }
        REQUIRE(err[0].size() >= 40);
        REQUIRE(err[1].size() == err[0].size());  // the same frames measured
        const auto rms = [](const std::vector<double>& v, std::size_t a, std::size_t b) {
            double ss = 0;
            for (std::size_t i = a; i < b; ++i) ss += v[i] * v[i];
            return std::sqrt(ss / double(b - a));
        };
        // Frame 0 is the acquisition fit itself (the same in both); frames 1-5 follow the start.
        const double first2 = rms(err[0], 1, 6), first1 = rms(err[1], 1, 6);
        const double all2 = rms(err[0], 0, err[0].size()), all1 = rms(err[1], 0, err[1].size());
        const double late2 = rms(err[0], 10, err[0].size()), late1 = rms(err[1], 10, err[1].size());
        INFO("seed " << seed << ": eye RMS deg, two fits -> one fit: frames 1-5 " << first2 << " -> " << first1
                     << ", all " << all2 << " -> " << all1 << ", from frame 10 " << late2 << " -> " << late1);
        CHECK(err[1][0] == Approx(err[0][0]).margin(1e-12));
        // With the markers' image model (TrackerConfig::marker_image_model) the fits the two starts take are nearer
        // the truth, and the gain is less: seeds 61-63 all 0.0088 -> 0.0085, 0.0072 -> 0.0069, 0.00638 -> 0.00641 deg.
        CHECK(all1 < 1.01 * all2);
        CHECK(late1 < 1.05 * late2);
        for (int k = 0; k < 2; ++k) pooled_first[k] += std::pow(k == 0 ? first2 : first1, 2);
        ++n_first;
    }
    const double p2 = std::sqrt(pooled_first[0] / n_first), p1 = std::sqrt(pooled_first[1] / n_first);
    INFO("frames 1-5 pooled over the seeds: two fits " << p2 << " deg, one fit " << p1);
    CHECK(p1 < 0.9 * p2);  // measured 0.0101 -> 0.0087 deg (0.8x before the image model)
}
