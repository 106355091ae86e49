#include "eyesim/rig/board.hpp"

#include "eyesim/rig/error.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace eyesim::rig {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

/// splitmix64 (portable: std distributions differ between libraries).
struct Rng {
    uint64_t s;
    uint64_t next() {
        uint64_t z = (s += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    double uniform(double lo, double hi) { return lo + (hi - lo) * static_cast<double>(next() >> 11) * 0x1.0p-53; }
};

/// Minimum-jerk profile 0 → 1 on [0, 1].
double min_jerk(double u) {
    u = std::clamp(u, 0.0, 1.0);
    return u * u * u * (u * (u * 6 - 15) + 10);
}

/// Centre of the sheet in the board frame.
Eigen::Vector3d sheet_centre_board_mm(const BoardSpec& b) {
    return {0.5 * b.inner_cols() * b.square_mm - 0.5 * b.square_mm, 0.5 * b.inner_rows() * b.square_mm - 0.5 * b.square_mm,
            0.0};
}

/// Points along the outline of the squares and half a square of margin round them, board frame.
std::vector<Eigen::Vector3d> outline_samples(const BoardSpec& b) {
    auto c = b.outline_board_mm();
    const Eigen::Vector3d centre = 0.25 * (c[0] + c[1] + c[2] + c[3]);
    for (auto& p : c) p = centre + (p - centre).cwiseProduct(Eigen::Vector3d((b.squares_x + 1.0) / (b.squares_x + 2.0),
                                                                             (b.squares_y + 1.0) / (b.squares_y + 2.0), 0.0));
    std::vector<Eigen::Vector3d> out;
    constexpr int kPerEdge = 8;
    for (int e = 0; e < 4; ++e)
        for (int k = 0; k < kPerEdge; ++k) out.push_back(c[e] + (c[(e + 1) % 4] - c[e]) * (double(k) / kPerEdge));
    return out;
}

}  // namespace

std::vector<Eigen::Vector3d> BoardSpec::corners_board_mm() const {
    std::vector<Eigen::Vector3d> out;
    for (int r = 0; r < inner_rows(); ++r)
        for (int c = 0; c < inner_cols(); ++c) out.push_back(corner_board_mm(c, r));
    return out;
}

std::array<Eigen::Vector3d, 4> BoardSpec::outline_board_mm() const {
    // Checker squares span [-1, squares - 1) squares from the origin; the margin one more square each side.
    const double x0 = -2 * square_mm, x1 = squares_x * square_mm, y0 = -2 * square_mm, y1 = squares_y * square_mm;
    return {Eigen::Vector3d(x0, y0, 0), Eigen::Vector3d(x1, y0, 0), Eigen::Vector3d(x1, y1, 0), Eigen::Vector3d(x0, y1, 0)};
}

int BoardSpec::cell_class(int a, int b) const noexcept {
    if (a < -2 || a > squares_x - 1 || b < -2 || b > squares_y - 1) return -1;
    if (a == -2 || a == squares_x - 1 || b == -2 || b == squares_y - 1) return 1;  // margin
    return ((a + b) & 1) ? 1 : 0;  // cell (-1, -1), the top-left square, is black
}

BoardMotion BoardMotion::plan(const BoardSpec& spec, const std::vector<CameraModel>& cameras, uint64_t seed,
                              double duration_us) {
    if (cameras.empty()) throw RigError("checkerboard: cameras: none to hold the board in front of");
    if (spec.squares_x < 3 || spec.squares_y < 3 || !(spec.square_mm > 0))
        throw RigError(fmt::format("checkerboard: board: needs at least 3 × 3 squares of positive size, got {} × {} of {} mm",
                                   spec.squares_x, spec.squares_y, spec.square_mm));
    BoardMotion m;
    m.spec_ = spec;
    const int nc = static_cast<int>(cameras.size());
    const double period_s = kBoardHoldS + kBoardMoveS;
    const double dur_s = std::max(0.0, duration_us) * 1e-6;
    const int holds = std::max(nc, static_cast<int>(std::floor((dur_s - kBoardHoldS) / period_s + 1e-9)) + 1);
    Rng rng{seed * 0x9E3779B97F4A7C15ull ^ 0xB0A4DC4ECull};
    const Eigen::Vector3d centre_b = sheet_centre_board_mm(spec);
    const std::vector<Eigen::Vector3d> outline = outline_samples(spec);
    // Image positions of the board centre, as a fraction of the way from the image centre to the edge.
    static constexpr double kAnchors[9][2] = {{0, 0}, {-1, -1}, {1, 1}, {1, -1}, {-1, 1}, {0, -1}, {0, 1}, {-1, 0}, {1, 0}};

    for (int k = 0; k < holds; ++k) {
        const int cam_i = std::min(nc - 1, static_cast<int>(static_cast<int64_t>(k) * nc / holds));
        const int first = static_cast<int>((static_cast<int64_t>(cam_i) * holds + nc - 1) / nc);
        const int h = k - first;  // hold number within this camera's block
        const CameraModel& cam = cameras[static_cast<size_t>(cam_i)];
        const double ax = kAnchors[h % 9][0], ay = kAnchors[h % 9][1];
        const double tilt = rng.uniform(10, 40) * kDeg, tilt_dir = rng.uniform(0, 2 * kPi);
        const double roll = rng.uniform(-25, 25) * kDeg;
        // Nearer at the centre, further towards the edges and corners, where a smaller board reaches further out.
        const int ring = (ax != 0) + (ay != 0);
        double dist = ring == 0 ? rng.uniform(40, 50) : ring == 1 ? rng.uniform(46, 58) : rng.uniform(52, 64);
        const double jx = ax == 0 ? rng.uniform(-0.2, 0.2) : 0.0, jy = ay == 0 ? rng.uniform(-0.2, 0.2) : 0.0;
        // Board axes in the camera frame: facing the camera (board z along the optical axis), tilted and rolled.
        const Eigen::Matrix3d R_board_cam =
            (Eigen::AngleAxisd(tilt, Eigen::Vector3d(std::cos(tilt_dir), std::sin(tilt_dir), 0.0)) *
             Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()))
                .toRotationMatrix();
        // Board centre on the ray through an image point; the squares and half a square of margin round them must
        // stay inside the image (5 px), as a detector needs.
        auto place = [&](double lambda, double d, Eigen::Vector3d& centre_cam) {
            const Eigen::Vector2d px(cam.cx + lambda * (ax + jx) * 0.5 * kFrameWidth,
                                     cam.cy + lambda * (ay + jy) * 0.5 * kFrameHeight);
            const auto q = cam.undistort_to_normalized(px);
            if (!q || q->squaredNorm() > cam.max_r2) return false;
            centre_cam = d * Eigen::Vector3d(q->x(), q->y(), 1.0).normalized();
            for (const Eigen::Vector3d& pb : outline) {
                const Eigen::Vector3d pc = centre_cam + R_board_cam * (pb - centre_b);
                if (pc.z() <= 1.0) return false;
                const Eigen::Vector2d qn(pc.x() / pc.z(), pc.y() / pc.z());
                if (qn.squaredNorm() > cam.max_r2) return false;
                const Eigen::Vector2d u = cam.distort_normalized(qn);
                constexpr double kMarginPx = 5.0;
                if (u.x() < kMarginPx || u.x() > kFrameWidth - 1 - kMarginPx || u.y() < kMarginPx ||
                    u.y() > kFrameHeight - 1 - kMarginPx)
                    return false;
            }
            return true;
        };
        Eigen::Vector3d centre_cam = Eigen::Vector3d::Zero();
        while (!place(0.0, dist, centre_cam) && dist < 400) dist *= 1.1;
        double lo = 0.0, hi = 1.0;
        if (place(1.0, dist, centre_cam)) {
            lo = 1.0;
        } else {
            for (int it = 0; it < 30; ++it) {
                const double mid = 0.5 * (lo + hi);
                (place(mid, dist, centre_cam) ? lo : hi) = mid;
            }
        }
        place(lo, dist, centre_cam);
        // Camera frame → rig frame.
        const Eigen::Matrix3d R_rig_cam = cam.R_cam_rig.transpose();
        const Eigen::Matrix3d R_board_rig = R_rig_cam * R_board_cam;
        Hold hold;
        hold.camera = cam_i;
        hold.pose.q_board_to_rig = Eigen::Quaterniond(R_board_rig).normalized();
        hold.pose.origin_rig_mm = R_rig_cam * (centre_cam - cam.t_cam_rig_mm) - R_board_rig * centre_b;
        m.holds_.push_back(hold);
    }
    return m;
}

BoardPose BoardMotion::pose_at(double t_us) const {
    const double period_s = kBoardHoldS + kBoardMoveS;
    const double t_s = t_us * 1e-6;
    const int n = static_cast<int>(holds_.size());
    const int k = std::clamp(static_cast<int>(std::floor(t_s / period_s)), 0, n - 1);
    const double u = t_s - k * period_s;
    if (k >= n - 1 || u <= kBoardHoldS) return holds_[static_cast<size_t>(k)].pose;
    // Move: the sheet's centre on a minimum-jerk straight line, the rotation by slerp with the same profile.
    const double s = min_jerk((u - kBoardHoldS) / kBoardMoveS);
    const BoardPose& a = holds_[static_cast<size_t>(k)].pose;
    const BoardPose& b = holds_[static_cast<size_t>(k) + 1].pose;
    const Eigen::Vector3d cb = sheet_centre_board_mm(spec_);
    const Eigen::Vector3d ca = a.to_rig(cb), cc = b.to_rig(cb);
    BoardPose p;
    p.q_board_to_rig = a.q_board_to_rig.slerp(s, b.q_board_to_rig).normalized();
    p.origin_rig_mm = ca + s * (cc - ca) - p.q_board_to_rig * cb;
    return p;
}

BoardTruth board_truth(const BoardMotion& motion, const std::vector<CameraModel>& cameras, int64_t index, double t_us) {
    const BoardSpec& spec = motion.spec();
    BoardTruth bt;
    bt.squares_x = spec.squares_x;
    bt.squares_y = spec.squares_y;
    bt.square_mm = spec.square_mm;
    const BoardPose p = motion.pose_at(t_us);
    bt.q_board_to_rig = p.q_board_to_rig;
    bt.origin_rig_mm = p.origin_rig_mm;
    const std::vector<Eigen::Vector3d> corners = spec.corners_board_mm();
    for (const CameraModel& cam : cameras) {
        const FieldTiming ft = cam.field_timing(index);
        const BoardPose pm = motion.pose_at(ft.exposure_mid_us);
        const BoardPose p0 = motion.pose_at(ft.exposure_start_us), p1 = motion.pose_at(ft.exposure_end_us);
        BoardCameraTruth ct;
        ct.q_board_to_rig = pm.q_board_to_rig;
        ct.origin_rig_mm = pm.origin_rig_mm;
        const Eigen::Vector3d n_cam = cam.R_cam_rig * (pm.q_board_to_rig * Eigen::Vector3d::UnitZ());
        ct.facing = n_cam.dot(cam.to_camera(pm.origin_rig_mm)) > 0;
        for (const Eigen::Vector3d& c : corners) {
            const auto u = cam.project_frame(pm.to_rig(c));
            if (u && u->x() >= -0.5 && u->x() <= kFrameWidth - 0.5 && u->y() >= -0.5 && u->y() <= kFrameHeight - 0.5)
                ++ct.corners_in_image;
            const auto u0 = cam.project_frame(p0.to_rig(c)), u1 = cam.project_frame(p1.to_rig(c));
            if (u0 && u1) ct.motion_px = std::max(ct.motion_px, (*u1 - *u0).norm());
        }
        bt.cams.push_back(ct);
    }
    return bt;
}

}  // namespace eyesim::rig
