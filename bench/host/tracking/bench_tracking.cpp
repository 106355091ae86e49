// Tracking-stage benchmark: time per tracking frame (undistort → correspondence → triangulation + LM +
// covariance → eye and instrument fits) on synthetic frames of the default rig with ~10 and 14 markers, against
// 3D error; OpenCV's two-view pipeline (undistortPoints + triangulatePoints, correspondences given) measured in
// the same run on the same images as the peer. Median of repeated passes, thread CPU time (the machine is shared).
//
// The async chain's filters (one agile motion model per body, the mixture of three constant-velocity models, or the
// default: that mixture, the eye's steady model with an acceleration and an agile acceleration model beside) are
// timed per camera field on the unsynchronised stream, with their errors, in a second table.
//
// Usage: bench_tracking [--frames N] [--repeats R] [--sigma PX]

#include "eyesim/tracking/distortion.hpp"
#include "eyesim/tracking/rigid_fit.hpp"
#include "eyesim/tracking/tracker.hpp"

#include "synthetic_stream.hpp"

#include <opencv2/calib3d.hpp>

#include <algorithm>
#include <chrono>
#include <ctime>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <vector>

using namespace eyesim::tracking;
/// Thread CPU time: the machine is shared, so wall time would include other processes' time slices.
struct Clock {
    using duration = std::chrono::nanoseconds;
    using time_point = std::chrono::time_point<Clock, duration>;
    static time_point now() {
        timespec ts{};
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
        return time_point(duration(std::int64_t(ts.tv_sec) * 1000000000 + ts.tv_nsec));
    }
};

namespace {

struct Frame {
    std::array<CameraField, 3> fields{};
    test::SceneTruth truth;
    // Ground-truth correspondences for the peer: per scene marker, its image index in each camera (−1 unseen).
    std::vector<std::array<int, 3>> where;
};

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.empty() ? 0.0 : v[v.size() / 2];
}

/// Synchronised frames (every camera at the same instant): the benchmark isolates the tracking stage from time
/// alignment. `keep_eye` eye markers are kept (8 = all).
std::vector<Frame> make_frames(const test::SyntheticScene& scene, int n, double sigma_px, int keep_eye,
                               std::mt19937_64& rng) {
    std::vector<Frame> frames(static_cast<std::size_t>(n));
    std::normal_distribution<double> g(0.0, 1.0);
    for (int i = 0; i < n; ++i) {
        Frame& f = frames[std::size_t(i)];
        const double t = 20000.0 * i;
        test::SceneTruth s = scene.at(t);
        // Thin the eye markers (keep every other one first) to reach the marker count asked for.
        std::vector<std::size_t> keep;
        const int n_eye = int(scene.bodies().eye.markers.size());
        const int stride = std::max(1, n_eye / std::max(keep_eye, 1));
        for (int k = 0; k < n_eye; k += stride) keep.push_back(std::size_t(k));
        for (std::size_t k = std::size_t(n_eye); k < s.markers_rig_mm.size(); ++k) keep.push_back(k);
        test::SceneTruth kept = s;
        kept.markers_rig_mm.clear();
        kept.marker_class.clear();
        for (std::size_t k : keep) {
            kept.markers_rig_mm.push_back(s.markers_rig_mm[k]);
            kept.marker_class.push_back(s.marker_class[k]);
        }
        f.truth = kept;
        f.where.assign(kept.markers_rig_mm.size(), {-1, -1, -1});
        for (int c = 0; c < 3; ++c) {
            const auto& cm = scene.cameras()[std::size_t(c)];
            CameraField& cf = f.fields[std::size_t(c)];
            cf.camera = c;
            for (std::size_t k = 0; k < kept.markers_rig_mm.size(); ++k) {
                const auto px = cm.project_frame(kept.markers_rig_mm[k]);
                if (!px) continue;
                // Centroid noise is per field pixel: σ in x, 2σ in frame rows.
                const Eigen::Vector2d p = *px + Eigen::Vector2d(sigma_px * g(rng), 2.0 * sigma_px * g(rng));
                if (p.x() < 2 || p.x() > 717 || p.y() < 2 || p.y() > 573) continue;
                FieldImage& im = cf.images[std::size_t(cf.count)];
                im.colour_class = std::uint8_t(kept.marker_class[k]);
                im.frame_px = p;
                f.where[k][std::size_t(c)] = cf.count++;
            }
        }
    }
    return frames;
}

struct Result {
    double us_per_frame = 0, markers_per_frame = 0, rms_um = 0, tip_um = 0, eye_deg = 0;
};

Result run_ours(Tracker& tracker, const std::vector<Frame>& frames, int repeats, bool two_view) {
    Result r;
    std::array<bool, 3> present{true, true, !two_view};
    TrackingFrame out;
    std::vector<double> pass_us;
    double ss = 0, ss_tip = 0, ss_eye = 0;
    long n = 0, n_tip = 0, n_eye = 0, n_markers = 0;
    for (int rep = 0; rep < repeats; ++rep) {
        const auto t0 = Clock::now();
        for (const Frame& f : frames) tracker.track_images(f.fields, present, out);
        pass_us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count() / double(frames.size()));
    }
    for (const Frame& f : frames) {  // accuracy pass (not timed)
        tracker.track_images(f.fields, present, out);
        n_markers += out.markers.count;
        for (int m = 0; m < out.markers.count; ++m) {
            const auto& mk = out.markers.markers[std::size_t(m)];
            double best = 1e9;
            for (std::size_t k = 0; k < f.truth.markers_rig_mm.size(); ++k)
                if (f.truth.marker_class[k] == mk.colour_class)
                    best = std::min(best, (f.truth.markers_rig_mm[k] - mk.point.X_rig_mm).norm());
            ss += best * best;
            ++n;
        }
        for (int b = 0; b < out.instrument_count; ++b)
            if (out.instruments[std::size_t(b)].measured()) {
                ss_tip += (out.instruments[std::size_t(b)].tip_rig_mm - f.truth.tip_rig_mm[std::size_t(b)]).squaredNorm();
                ++n_tip;
            }
        if (out.eye.measured()) {
            ss_eye += std::pow(rotation_angle_deg(out.eye.rotation_eye_to_rig.toRotationMatrix(),
                                                  f.truth.q_eye_to_rig.toRotationMatrix()), 2);
            ++n_eye;
        }
    }
    r.us_per_frame = median(pass_us);
    r.markers_per_frame = double(n_markers) / double(frames.size());
    r.rms_um = 1e3 * std::sqrt(ss / double(std::max(n, 1L)));
    r.tip_um = 1e3 * std::sqrt(ss_tip / double(std::max(n_tip, 1L)));
    r.eye_deg = std::sqrt(ss_eye / double(std::max(n_eye, 1L)));
    return r;
}

/// OpenCV peer: cameras 0 and 1, correspondences given by the generator, undistortPoints (default criteria) +
/// triangulatePoints on normalised coordinates. No pose fitting.
Result run_opencv(const test::SyntheticScene& scene, const std::vector<Frame>& frames, int repeats) {
    const auto& c0 = scene.cameras()[0];
    const auto& c1 = scene.cameras()[1];
    cv::Mat K0(c0.camera_matrix()), K1(c1.camera_matrix()), D0(c0.dist_coeffs()), D1(c1.dist_coeffs());
    cv::Matx34d P0, P1;
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) {
            P0(r, c) = c0.R_cam_rig(r, c);
            P1(r, c) = c1.R_cam_rig(r, c);
        }
        P0(r, 3) = c0.t_cam_rig_mm(r);
        P1(r, 3) = c1.t_cam_rig_mm(r);
    }
    Result res;
    std::vector<double> pass_us;
    double ss = 0;
    long n = 0;
    std::vector<cv::Point2d> a, b, ua, ub;
    std::vector<std::size_t> idx;
    cv::Mat X;
    for (int rep = 0; rep <= repeats; ++rep) {
        const bool score = rep == repeats;
        const auto t0 = Clock::now();
        for (const Frame& f : frames) {
            a.clear();
            b.clear();
            idx.clear();
            for (std::size_t k = 0; k < f.where.size(); ++k) {
                if (f.where[k][0] < 0 || f.where[k][1] < 0) continue;
                const auto& p = f.fields[0].images[std::size_t(f.where[k][0])].frame_px;
                const auto& q = f.fields[1].images[std::size_t(f.where[k][1])].frame_px;
                a.emplace_back(p.x(), p.y());
                b.emplace_back(q.x(), q.y());
                idx.push_back(k);
            }
            if (a.empty()) continue;
            cv::undistortPoints(a, ua, K0, D0);
            cv::undistortPoints(b, ub, K1, D1);
            cv::triangulatePoints(P0, P1, ua, ub, X);
            if (score) {
                for (std::size_t j = 0; j < idx.size(); ++j) {
                    const double w = X.at<double>(3, int(j));
                    const Eigen::Vector3d Xe(X.at<double>(0, int(j)) / w, X.at<double>(1, int(j)) / w,
                                             X.at<double>(2, int(j)) / w);
                    ss += (Xe - f.truth.markers_rig_mm[idx[j]]).squaredNorm();
                    ++n;
                }
            }
        }
        if (!score) pass_us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count() / double(frames.size()));
    }
    res.us_per_frame = median(pass_us);
    res.markers_per_frame = double(n) / double(frames.size());
    res.rms_um = 1e3 * std::sqrt(ss / double(std::max(n, 1L)));
    return res;
}

/// Time of each stage of the tracking frame (same work as Tracker::track_images, split up).
void stage_breakdown(const Tracker& tracker, const std::vector<Frame>& frames, int repeats) {
    const auto cams = tracker.cameras();
    Correspondence corr(cams, tracker.config().correspondence);
    std::vector<std::array<CameraObservations, 3>> views(frames.size());
    std::vector<CorrespondenceResult> found(frames.size());
    std::vector<double> t_und, t_corr, t_pose;
    for (int rep = 0; rep < repeats; ++rep) {
        auto t0 = Clock::now();
        for (std::size_t i = 0; i < frames.size(); ++i)
            for (int c = 0; c < 3; ++c) {
                auto& v = views[i][std::size_t(c)];
                const auto& f = frames[i].fields[std::size_t(c)];
                v.present = true;
                v.count = 0;
                for (int k = 0; k < f.count; ++k) {
                    ImagePoint& p = v.points[std::size_t(v.count++)];
                    p.colour_class = f.images[std::size_t(k)].colour_class;
                    p.px = f.images[std::size_t(k)].frame_px;
                    p.xn = undistort_pixel(cams[std::size_t(c)], p.px).xn;
                }
            }
        auto t1 = Clock::now();
        for (std::size_t i = 0; i < frames.size(); ++i) corr.solve(views[i], found[i]);
        auto t2 = Clock::now();
        EyePose eye, prev_eye;
        std::array<InstrumentPose, kMaxInstruments> inst{}, prev{};
        MarkerAssignment asg;
        const int ni = tracker.config().bodies.instrument_count;
        for (std::size_t i = 0; i < frames.size(); ++i) {
            fit_poses(tracker.config().bodies, found[i], tracker.config().pose, prev_eye,
                      std::span<const InstrumentPose>(prev.data(), std::size_t(ni)), eye,
                      std::span<InstrumentPose>(inst.data(), std::size_t(ni)), asg);
            prev_eye = eye;
            prev = inst;
        }
        auto t3 = Clock::now();
        const double n = double(frames.size());
        t_und.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count() / n);
        t_corr.push_back(std::chrono::duration<double, std::micro>(t2 - t1).count() / n);
        t_pose.push_back(std::chrono::duration<double, std::micro>(t3 - t2).count() / n);
    }
    std::printf("stages (us/frame): undistort %.2f, correspondence + triangulation %.2f, pose fits %.2f\n",
                median(t_und), median(t_corr), median(t_pose));
}

/// The async chain (`--sync async`): the unsynchronised cameras' fields pushed one at a time into a Tracker, a
/// frame per reference field. Time per camera field (push + pop: association and the filters' updates), and the
/// frames' errors against the scene's truth at each frame's time.
Result run_async(const test::SyntheticScene& scene, int fields, double sigma_px, int motion_models, bool eye_accel,
                 bool pivot, int repeats) {
    std::mt19937_64 rng(7);
    const auto stream = scene.stream(fields, sigma_px, rng, [](int, int) { return false; });
    TrackerConfig cfg = scene.tracker_config();
    cfg.sync.mode = SyncMode::Async;
    cfg.async.motion_models = motion_models;
    cfg.async.eye_acceleration_model = eye_accel;
    cfg.async.pivot_model = pivot;
    if (!eye_accel) {  // the eye's steady model without its acceleration too, as it was (constant velocity, 1e-3)
        cfg.async.eye_steady_ang_jerk_psd_rad2_s5 = 0.0;
        cfg.async.eye_steady_ang_accel_psd_rad2_s3 = 1.0e-3;
    }
    std::vector<double> pass_us;
    Result r;
    for (int rep = 0; rep <= repeats; ++rep) {
        const bool score = rep == repeats;
        Tracker tracker(cfg);
        tracker.set_clock_offset_us(1e6);
        TrackingFrame f;
        double ss = 0, ss_tip = 0, ss_eye = 0;
        long n = 0, n_tip = 0, n_eye = 0, frames = 0;
        double busy_us = 0.0;
        for (const auto& msg : stream) {
            const double received = double(msg.field_end_us) - 1e6 + 2000.0;
            const auto t0 = Clock::now();
            tracker.push(msg, received);
            bool got = tracker.pop(f, received);
            busy_us += std::chrono::duration<double, std::micro>(Clock::now() - t0).count();
            while (got) {
                ++frames;
                if (score && frames > 50) {  // settled (acquisition and the first second)
                    const auto truth = scene.at(f.timing.sample_host_us);
                    for (int m = 0; m < f.markers.count; ++m) {
                        const auto& mk = f.markers.markers[std::size_t(m)];
                        const double best = test::nearest_marker_error_mm(truth, mk.colour_class, mk.point.X_rig_mm);
                        ss += best * best;
                        ++n;
                    }
                    for (int b = 0; b < f.instrument_count; ++b)
                        if (f.instruments[std::size_t(b)].measured()) {
                            ss_tip += (f.instruments[std::size_t(b)].tip_rig_mm - truth.tip_rig_mm[std::size_t(b)])
                                          .squaredNorm();
                            ++n_tip;
                        }
                    if (f.eye.measured()) {
                        ss_eye += std::pow(rotation_angle_deg(f.eye.rotation_eye_to_rig.toRotationMatrix(),
                                                              truth.q_eye_to_rig.toRotationMatrix()), 2);
                        ++n_eye;
                    }
                }
                const auto t1 = Clock::now();
                got = tracker.pop(f, received);
                busy_us += std::chrono::duration<double, std::micro>(Clock::now() - t1).count();
            }
        }
        if (!score) {
            pass_us.push_back(busy_us / double(stream.size()));
            continue;
        }
        r.markers_per_frame = double(n) / double(std::max(frames - 50, 1L));
        r.rms_um = 1e3 * std::sqrt(ss / double(std::max(n, 1L)));
        r.tip_um = 1e3 * std::sqrt(ss_tip / double(std::max(n_tip, 1L)));
        r.eye_deg = std::sqrt(ss_eye / double(std::max(n_eye, 1L)));
    }
    r.us_per_frame = median(pass_us);
    return r;
}

}  // namespace

int main(int argc, char** argv) {
    int n_frames = 1000, repeats = 7;
    double sigma = 0.03;
    for (int i = 1; i + 1 < argc; i += 2) {
        if (!std::strcmp(argv[i], "--frames")) n_frames = std::max(10, std::atoi(argv[i + 1]));
        else if (!std::strcmp(argv[i], "--repeats")) repeats = std::max(1, std::atoi(argv[i + 1]));
        else if (!std::strcmp(argv[i], "--sigma")) sigma = std::atof(argv[i + 1]);
    }
    const test::SyntheticScene scene(1.0);
    std::printf("tracking stage: %d frames, centroid noise %.3f field px, median of %d passes (thread CPU time)\n\n", n_frames, sigma,
                repeats);
    std::printf("| markers | pipeline | views | us/frame | markers/frame | 3D RMS um | tip RMS um | eye RMS deg |\n");
    std::printf("|---|---|---|---|---|---|---|---|\n");
    for (int keep_eye : {4, 8}) {
        std::mt19937_64 rng(42);
        const auto frames = make_frames(scene, n_frames, sigma, keep_eye, rng);
        const int markers = keep_eye + 6;
        TrackerConfig cfg = scene.tracker_config();
        cfg.centroid_sigma_px = std::max(sigma, 0.02);
        Tracker tracker(cfg);
        const Result ours3 = run_ours(tracker, frames, repeats, false);
        Tracker tracker2(cfg);
        const Result ours2 = run_ours(tracker2, frames, repeats, true);
        const Result peer = run_opencv(scene, frames, repeats);
        stage_breakdown(tracker, frames, repeats);
        TrackerConfig cfg_corr = cfg;
        cfg_corr.shaft_occlusion_correction = true;
        Tracker tracker3(cfg_corr);
        const Result corr3 = run_ours(tracker3, frames, repeats, false);
        TrackerConfig cfg_eye = cfg_corr;
        cfg_eye.eye_occlusion_correction = true;
        Tracker tracker4(cfg_eye);
        const Result eye3 = run_ours(tracker4, frames, repeats, false);
        std::printf("| %d | eyesim (correspondence + LM + poses) | 3 | %.2f | %.1f | %.2f | %.2f | %.4f |\n", markers,
                    ours3.us_per_frame, ours3.markers_per_frame, ours3.rms_um, ours3.tip_um, ours3.eye_deg);
        std::printf("| %d | eyesim + shaft-occlusion correction (inputs here are unbiased) | 3 | %.2f | %.1f | %.2f | %.2f | %.4f |\n",
                    markers, corr3.us_per_frame, corr3.markers_per_frame, corr3.rms_um, corr3.tip_um, corr3.eye_deg);
        std::printf("| %d | eyesim + shaft- and eye-occlusion corrections (validate's default; inputs here are unbiased) | 3 | %.2f | %.1f | %.2f | %.2f | %.4f |\n",
                    markers, eye3.us_per_frame, eye3.markers_per_frame, eye3.rms_um, eye3.tip_um, eye3.eye_deg);
        std::printf("| %d | eyesim (correspondence + LM + poses) | 2 | %.2f | %.1f | %.2f | %.2f | %.4f |\n", markers,
                    ours2.us_per_frame, ours2.markers_per_frame, ours2.rms_um, ours2.tip_um, ours2.eye_deg);
        std::printf("| %d | OpenCV undistortPoints + triangulatePoints (given matches) | 2 | %.2f | %.1f | %.2f | - | - |\n",
                    markers, peer.us_per_frame, peer.markers_per_frame, peer.rms_um);
        std::printf("| %d | ratio eyesim 2-view / OpenCV: time %.2fx, 3D error %.3fx | | | | | | |\n", markers,
                    ours2.us_per_frame / peer.us_per_frame, ours2.rms_um / peer.rms_um);
    }
    // The async filters: one agile motion model per body, the mixture of three constant-velocity models, the
    // default (that mixture, the eye's steady model with an acceleration and an agile acceleration model beside,
    // the instruments' agile model about the trocar; AsyncOptions) and the default without that pivot, on the
    // unsynchronised
    // stream (every camera field on its own, the eye turning at up to 0.3 Hz, instruments tilting).
    const int async_fields = std::max(100, n_frames / 2);
    std::printf("\nasync filters (--sync async): %d fields per camera, unsynchronised, time per camera field (push +"
                " pop), frames after the first 50\n\n",
                async_fields);
    std::printf("| centroid σ px | filters | us/camera field | markers/frame | 3D RMS um | tip RMS um | eye RMS deg |\n");
    std::printf("|---|---|---|---|---|---|---|\n");
    for (double sg : {sigma, 2.0 * sigma}) {
        for (int row = 0; row < 4; ++row) {
            const Result a = run_async(scene, async_fields, sg, row == 0 ? 1 : 3, row >= 2, row != 3, repeats);
            static const char* const kNames[4] = {"one agile model", "mixture of three constant-velocity models",
                                                  "mixture, the eye's steady and agile models with accelerations (default)",
                                                  "the default, the instruments' agile model without its trocar pivot"};
            std::printf("| %.3f | %s | %.2f | %.1f | %.2f | %.2f | %.4f |\n", sg, kNames[row], a.us_per_frame,
                        a.markers_per_frame, a.rms_um, a.tip_um, a.eye_deg);
        }
    }
    return 0;
}
