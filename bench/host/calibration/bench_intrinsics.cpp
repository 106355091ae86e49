// Intrinsic calibration from a synthesised checkerboard recording against the true cameras, over seeds.
//
//   bench_intrinsics [--seeds "1 2 3 4 5"] [--seconds S] [--cameras N] [--field-step N] [--noise SIGMA]
//                    [--work DIR]
//
// Per seed: `checkerboard` recording of the default rig's first N cameras (S seconds; default 16 holds per
// camera), then calibrate_intrinsics on fields and on woven frames for every camera. Prints one Markdown row per
// seed, camera and mode (focal errors %, principal point errors px, whole-image model error max/RMS px,
// distortion error max px, reprojection RMS px, views, corner error against the true board pose px RMS over the
// views and for the worst view, wall seconds), then the median and worst of each column over all rows of a mode.
// Also the renderer's board edges: the largest luma difference between 2 × 2 and 16 × 16 sub-cells per edge
// pixel over the still fields of the first seed, and what that is as an edge shift (difference / the contrast).
#include "eyesim/calibration/intrinsics.hpp"
#include "eyesim/rig/board.hpp"
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/renderer.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/rig/truth.hpp"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

namespace rig = eyesim::rig;
namespace cal = eyesim::calibration;
namespace fs = std::filesystem;

namespace {

double now_s() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

/// RMS distance of a view's corners from the true board corners (either numbering of the board).
double corner_error_rms(const std::vector<cv::Point2f>& corners, const rig::BoardCameraTruth& bt, const rig::CameraModel& cam) {
    const rig::BoardPose pose{bt.q_board_to_rig, bt.origin_rig_mm};
    const auto board = rig::kCheckerboard.corners_board_mm();
    double best = HUGE_VAL;
    for (int rev = 0; rev < 2; ++rev) {
        double s = 0;
        for (size_t i = 0; i < corners.size(); ++i) {
            const auto p = cam.project_frame(pose.to_rig(board[i]));
            const cv::Point2f& c = corners[rev ? corners.size() - 1 - i : i];
            s += p ? (Eigen::Vector2d(c.x, c.y) - *p).squaredNorm() : 1e6;
        }
        best = std::min(best, std::sqrt(s / static_cast<double>(corners.size())));
    }
    return best;
}

struct Row {
    double fx, fy, cx, cy, img_max, img_rms, dist_max, rms, corner, corner_view_max, seconds;
    int views, holds;
};

/// Largest luma difference (DN) between board_subcells 2 and 16 over still fields of camera 0, and the contrast.
void edge_check(const rig::BoardMotion& motion, const rig::CameraModel& cam, double& max_dn, double& contrast) {
    max_dn = 0;
    contrast = HUGE_VAL;
    std::vector<rig::MarkerCameraTruth> truth;
    for (int h = 0; h < std::min(motion.hold_count(), 12); ++h) {
        if (motion.hold_camera(h) != 0) continue;
        const rig::BoardPose pose = motion.pose_at(motion.hold_start_us(h) + 1000.0);
        const rig::GeometryAt geo = [&](double, rig::SceneGeometry& g) {
            g.eye_radius_mm = 0;
            g.markers.clear();
            g.shafts.clear();
            g.board = pose;
        };
        std::vector<float> img[2];
        int k = 0;
        for (int ns : {2, 16}) {
            rig::RenderOptions o;
            o.noise_sigma = 0;
            o.board_subcells = ns;
            rig::CameraRenderer r(cam, 0, Eigen::Vector3d::Zero(), 0.0, o);
            std::vector<uint8_t> out(rig::kFieldBytes);
            r.render_field(geo, 0, out.data(), truth);
            img[k++] = r.last_rgb();
        }
        for (size_t i = 0; i < img[0].size(); i += 3) {
            const double y0 = 0.299 * img[0][i] + 0.587 * img[0][i + 1] + 0.114 * img[0][i + 2];
            const double y1 = 0.299 * img[1][i] + 0.587 * img[1][i + 1] + 0.114 * img[1][i + 2];
            max_dn = std::max(max_dn, std::abs(y0 - y1));
        }
    }
    // Darkest contrast of a square edge: black against white at the least shading (ambient only).
    const double lw = 0.299 * rig::kBoardWhiteRgb[0] + 0.587 * rig::kBoardWhiteRgb[1] + 0.114 * rig::kBoardWhiteRgb[2];
    const double lb = 0.299 * rig::kBoardBlackRgb[0] + 0.587 * rig::kBoardBlackRgb[1] + 0.114 * rig::kBoardBlackRgb[2];
    contrast = (lw - lb) * rig::kShadeAmbient;
}

void print_summary(const char* mode, const std::vector<Row>& rows) {
    if (rows.empty()) return;
    auto col = [&](auto get) {
        std::vector<double> v;
        for (const Row& r : rows) v.push_back(std::abs(get(r)));
        std::sort(v.begin(), v.end());
        return std::make_pair(v[v.size() / 2], v.back());
    };
    const auto fx = col([](const Row& r) { return r.fx; }), fy = col([](const Row& r) { return r.fy; });
    const auto cx = col([](const Row& r) { return r.cx; }), cy = col([](const Row& r) { return r.cy; });
    const auto im = col([](const Row& r) { return r.img_max; }), ir = col([](const Row& r) { return r.img_rms; });
    const auto dm = col([](const Row& r) { return r.dist_max; }), rm = col([](const Row& r) { return r.rms; });
    const auto ce = col([](const Row& r) { return r.corner; }), cv = col([](const Row& r) { return r.corner_view_max; });
    std::printf("| %s median (|x|) | | | %.4f | %.4f | %.3f | %.3f | %.3f | %.3f | %.3f | %.4f | | %.4f | %.4f | |\n", mode,
                fx.first, fy.first, cx.first, cy.first, im.first, ir.first, dm.first, rm.first, ce.first, cv.first);
    std::printf("| %s worst (|x|) | | | %.4f | %.4f | %.3f | %.3f | %.3f | %.3f | %.3f | %.4f | | %.4f | %.4f | |\n", mode,
                fx.second, fy.second, cx.second, cy.second, im.second, ir.second, dm.second, rm.second, ce.second, cv.second);
}

}  // namespace

int main(int argc, char** argv) {
    std::vector<uint64_t> seeds = {1, 2, 3, 4, 5};
    int ncam = 3, field_step = cal::IntrinsicsOptions{}.field_step;
    double seconds = -1, noise = 1.0;
    std::string work;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        const bool has = i + 1 < argc;
        if (a == "--seeds" && has) {
            seeds.clear();
            std::istringstream in(argv[++i]);
            uint64_t s;
            while (in >> s) seeds.push_back(s);
        } else if (a == "--seconds" && has) {
            seconds = std::atof(argv[++i]);
        } else if (a == "--cameras" && has) {
            ncam = std::atoi(argv[++i]);
        } else if (a == "--field-step" && has) {
            field_step = std::atoi(argv[++i]);
        } else if (a == "--noise" && has) {
            noise = std::atof(argv[++i]);
        } else if (a == "--work" && has) {
            work = argv[++i];
        } else {
            std::fprintf(stderr,
                         "usage: bench_intrinsics [--seeds \"1 2 3\"] [--seconds S] [--cameras N] [--field-step N] "
                         "[--noise SIGMA] [--work DIR]\n");
            return 2;
        }
    }
    const std::vector<rig::CameraModel> all = rig::default_rig();
    if (ncam < 1 || ncam > static_cast<int>(all.size()) || seeds.empty() || field_step < 1 || !(noise >= 0)) {
        std::fprintf(stderr, "bench_intrinsics: bad --cameras, --seeds, --field-step or --noise\n");
        return 2;
    }
    if (seconds <= 0) seconds = ncam * 16 * (rig::kBoardHoldS + rig::kBoardMoveS);
    const bool temp = work.empty();
    if (temp) work = (fs::temp_directory_path() / ("bench_intrinsics_" + std::to_string(::getpid()))).string();
    try {
        std::printf("checkerboard %d × %d squares of %.1f mm, %d cameras, %.1f s (%d holds), noise %.1f, field step %d\n\n",
                    rig::kCheckerboard.squares_x, rig::kCheckerboard.squares_y, rig::kCheckerboard.square_mm, ncam,
                    seconds, static_cast<int>(std::floor((seconds - rig::kBoardHoldS) / (rig::kBoardHoldS + rig::kBoardMoveS))) + 1,
                    noise, field_step);
        std::printf("| seed | cam | mode | fx err %% | fy err %% | cx err px | cy err px | image max px | image RMS px | "
                    "distortion max px | reproj RMS px | views | corner err px | worst view px | s |\n");
        std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
        std::vector<Row> rows[2];
        double edge_dn = -1, contrast = 0;
        for (uint64_t seed : seeds) {
            rig::SynthRequest req;
            req.out_dir = (fs::path(work) / ("board_" + std::to_string(seed))).string();
            req.scenario = "checkerboard";
            req.seconds = seconds;
            req.seed = seed;
            req.render.noise_sigma = noise;
            req.cameras.assign(all.begin(), all.begin() + ncam);
            rig::write_recording(req);
            const std::vector<rig::FieldTruth> truth = rig::read_truth(req.out_dir + "/truth.jsonl");
            if (edge_dn < 0) {
                const rig::BoardMotion motion = rig::BoardMotion::plan(rig::kCheckerboard, req.cameras, seed,
                                                                       static_cast<double>(truth.size()) * rig::kFieldPeriodUs);
                edge_check(motion, req.cameras[0], edge_dn, contrast);
            }
            rig::Recording rec = rig::Recording::open(req.out_dir);
            for (int c = 0; c < ncam; ++c)
                for (int woven = 0; woven < 2; ++woven) {
                    cal::IntrinsicsOptions opt;
                    opt.woven_frames = woven != 0;
                    opt.field_step = field_step;
                    const double t0 = now_s();
                    const cal::IntrinsicsResult r = cal::calibrate_intrinsics(rec, c, opt);
                    const double dt = now_s() - t0;
                    const rig::CameraModel& cam = req.cameras[static_cast<size_t>(c)];
                    const cal::IntrinsicsError e = cal::compare_intrinsics(r.camera, cam);
                    double s2 = 0, view_max = 0;
                    int k = 0;
                    for (const auto& v : r.views) {
                        if (!v.used) continue;
                        const double ce = corner_error_rms(r.corners_frame_px[static_cast<size_t>(k++)],
                                                           truth.at(static_cast<size_t>(v.first_field)).board->cams.at(static_cast<size_t>(c)), cam);
                        s2 += ce * ce;
                        view_max = std::max(view_max, ce);
                    }
                    const Row row{e.fx_error_pct, e.fy_error_pct, e.cx_error_px, e.cy_error_px, e.max_image_error_px,
                                  e.rms_image_error_px, e.max_distortion_error_px, r.rms_px,
                                  k ? std::sqrt(s2 / k) : 0.0, view_max, dt, r.views_used, r.holds};
                    rows[woven].push_back(row);
                    std::printf("| %llu | cam%d | %s | %+.4f | %+.4f | %+.3f | %+.3f | %.3f | %.3f | %.3f | %.4f | %d/%d | %.4f | %.4f | %.1f |\n",
                                static_cast<unsigned long long>(seed), c, woven ? "woven" : "fields", row.fx, row.fy,
                                row.cx, row.cy, row.img_max, row.img_rms, row.dist_max, row.rms, row.views, row.holds,
                                row.corner, row.corner_view_max, row.seconds);
                    std::fflush(stdout);
                }
            if (temp) fs::remove_all(req.out_dir);
        }
        print_summary("fields", rows[0]);
        print_summary("woven", rows[1]);
        std::printf("\nboard edges: largest luma difference between 2 × 2 and 16 × 16 sub-cells %.4f DN; as an edge shift "
                    "at the least contrast (%.0f DN): %.5f px\n",
                    edge_dn, contrast, edge_dn / contrast);
    } catch (const rig::RigError& e) {
        std::fprintf(stderr, "bench_intrinsics: %s\n", e.what());
        return 1;
    } catch (const cal::CalibrationError& e) {
        std::fprintf(stderr, "bench_intrinsics: %s\n", e.what());
        return 1;
    }
    if (temp) fs::remove_all(work);
    return 0;
}
