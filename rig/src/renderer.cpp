#include "eyesim/rig/renderer.hpp"

#include "eyesim/rig/board.hpp"

#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <limits>

namespace eyesim::rig {

namespace {

constexpr int W = kFieldWidth;
constexpr int H = kFieldHeight;
constexpr float kInf = std::numeric_limits<float>::infinity();

struct Rect {
    int x0, y0, x1, y1;  // inclusive field-pixel bounds
};

/// splitmix64 step (seeding) and xorshift64* (streams).
uint64_t splitmix(uint64_t& s) {
    uint64_t z = (s += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/// Area fraction of a square cell of side h (centred at the origin) on the inner side of a straight edge
/// with unit outward normal (nx, ny) at signed distance `dist` (positive: cell centre outside).
inline double cell_coverage(double dist, double nx, double ny, double h) {
    double a = std::abs(nx) * h, b = std::abs(ny) * h;
    if (a > b) std::swap(a, b);
    const double u = -dist + 0.5 * (a + b);  // distance of the edge from the cell's innermost corner
    if (u <= 0) return 0.0;
    if (u >= a + b) return 1.0;
    if (a < 1e-12) return u / b;
    if (u < a) return u * u / (2 * a * b);
    if (u <= b) return (u - 0.5 * a) / b;
    const double v = a + b - u;
    return 1.0 - v * v / (2 * a * b);
}

/// Nearest hit (distance along unit ray dir from the origin) of a sphere, or +inf.
inline double ray_sphere(const Eigen::Vector3d& dir, const Eigen::Vector3d& c, double r2) {
    const double tca = dir.dot(c);
    const double d2 = c.squaredNorm() - tca * tca;
    const double disc = r2 - d2;
    if (disc <= 0) return kInf;
    const double t = tca - std::sqrt(disc);
    return t > 0 ? t : kInf;
}

/// Nearest hit of a capless finite cylinder (axis from a, unit w, length len, radius r), or +inf.
inline double ray_cylinder(const Eigen::Vector3d& dir, const Eigen::Vector3d& a, const Eigen::Vector3d& w, double len,
                           double r, Eigen::Vector3d* normal = nullptr) {
    const Eigen::Vector3d m = dir - dir.dot(w) * w;
    const Eigen::Vector3d n0 = -a + a.dot(w) * w;
    const double A = m.squaredNorm();
    if (A < 1e-18) return kInf;
    const double B = 2 * m.dot(n0), C = n0.squaredNorm() - r * r;
    const double disc = B * B - 4 * A * C;
    if (disc <= 0) return kInf;
    const double t = (-B - std::sqrt(disc)) / (2 * A);
    if (t <= 0) return kInf;
    const double s = (t * dir - a).dot(w);
    if (s < 0 || s > len) return kInf;
    if (normal) {
        const Eigen::Vector3d p = t * dir - a;
        *normal = (p - p.dot(w) * w).normalized();
    }
    return t;
}

/// Squared distance between segments [p0,p1] and [q0,q1].
double segment_distance2(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1, const Eigen::Vector3d& q0,
                         const Eigen::Vector3d& q1) {
    const Eigen::Vector3d d1 = p1 - p0, d2 = q1 - q0, r = p0 - q0;
    const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
    double s = 0, t = 0;
    if (a <= 1e-12 && e <= 1e-12) return r.squaredNorm();
    if (a <= 1e-12) {
        t = std::clamp(f / e, 0.0, 1.0);
    } else {
        const double c = d1.dot(r);
        if (e <= 1e-12) {
            s = std::clamp(-c / a, 0.0, 1.0);
        } else {
            const double b = d1.dot(d2), denom = a * e - b * b;
            s = denom > 1e-12 ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
            t = (b * s + f) / e;
            if (t < 0) {
                t = 0;
                s = std::clamp(-c / a, 0.0, 1.0);
            } else if (t > 1) {
                t = 1;
                s = std::clamp((b - c) / a, 0.0, 1.0);
            }
        }
    }
    return (p0 + s * d1 - (q0 + t * d2)).squaredNorm();
}

/// The calibration board in the camera frame: origin, axes (ex, ey in the sheet, n = ex × ey) and outline.
struct CamBoard {
    Eigen::Vector3d o, ex, ey, n;
    double x0, x1, y0, y1;  // outline in board coordinates, mm
    bool facing;            // printed face towards the camera

    CamBoard(const BoardPose& pose, const CameraModel& cam) {
        const Eigen::Matrix3d R = cam.R_cam_rig * pose.q_board_to_rig.toRotationMatrix();
        o = cam.to_camera(pose.origin_rig_mm);
        ex = R.col(0);
        ey = R.col(1);
        n = R.col(2);
        const auto c = kCheckerboard.outline_board_mm();
        x0 = c[0].x(), y0 = c[0].y(), x1 = c[2].x(), y1 = c[2].y();
        facing = n.dot(o) > 0;
    }
    /// Distance along `dir` (any length) to the sheet, or +inf when the ray misses it.
    double hit(const Eigen::Vector3d& dir) const {
        const double nd = n.dot(dir);
        if (std::abs(nd) < 1e-15) return kInf;
        const double t = n.dot(o) / nd;
        if (!(t > 0)) return kInf;
        const Eigen::Vector3d rel = t * dir - o;
        const double s = ex.dot(rel), u = ey.dot(rel);
        return s >= x0 && s <= x1 && u >= y0 && u <= y1 ? t : kInf;
    }
};

/// Area of the convex polygon `poly` (n ≤ 4 vertices) inside the rectangle [x0, x1] × [y0, y1] (Sutherland–Hodgman).
double clipped_area(const Eigen::Vector2d* poly, int n, double x0, double x1, double y0, double y1) {
    Eigen::Vector2d a[12], b[12];
    for (int i = 0; i < n; ++i) a[i] = poly[i];
    // Keeps the part with sign * (p[axis] - v) >= 0.
    auto clip = [&](int axis, double v, double sign) {
        int m = 0;
        for (int i = 0; i < n; ++i) {
            const Eigen::Vector2d& p = a[i];
            const Eigen::Vector2d& q = a[(i + 1) % n];
            const double dp = sign * (p[axis] - v), dq = sign * (q[axis] - v);
            if (dp >= 0) b[m++] = p;
            if ((dp >= 0) != (dq >= 0)) b[m++] = p + (q - p) * (dp / (dp - dq));
        }
        n = m;
        for (int i = 0; i < n; ++i) a[i] = b[i];
    };
    clip(0, x0, 1.0);
    if (n) clip(0, x1, -1.0);
    if (n) clip(1, y0, 1.0);
    if (n) clip(1, y1, -1.0);
    double area2 = 0;
    for (int i = 0; i < n; ++i) {
        const Eigen::Vector2d& p = a[i];
        const Eigen::Vector2d& q = a[(i + 1) % n];
        area2 += p.x() * q.y() - q.x() * p.y();
    }
    return 0.5 * std::abs(area2);
}

/// Camera-frame occluders of one marker at one time sample.
struct Occluders {
    struct Sph { Eigen::Vector3d c; double r2; };
    struct Cyl { Eigen::Vector3d a, w; double len, r; };
    std::vector<Sph> spheres;
    std::vector<Cyl> cylinders;
    std::vector<CamBoard> boards;
    bool hit_before(const Eigen::Vector3d& dir, double t_max) const {
        for (const Sph& s : spheres)
            if (ray_sphere(dir, s.c, s.r2) < t_max) return true;
        for (const Cyl& c : cylinders)
            if (ray_cylinder(dir, c.a, c.w, c.len, c.r) < t_max) return true;
        for (const CamBoard& b : boards)
            if (b.hit(dir) < t_max) return true;
        return false;
    }
};

}  // namespace

struct CameraRenderer::Impl {
    CameraModel cam;
    int cam_index = 0;
    RenderOptions opt;
    Eigen::Vector3d eye_c_rig = Eigen::Vector3d::Zero();
    double eye_r = 0;

    std::vector<float> ray[2];        // (qx, qy) per field pixel; NaN where the model is invalid
    std::vector<float> base[2];       // static RGB per field pixel
    std::vector<float> eye_depth[2];  // distance along the unit ray to the eye at the pixel centre
    std::vector<float> img[2];        // working RGB per parity
    std::vector<Rect> dirty[2];       // regions of img[p] that differ from base[p]
    int last_parity = 0;

    std::vector<float> cov, contrib;  // marker layer: visible coverage, RGB contribution
    std::vector<uint32_t> stamp;
    std::vector<float> shaft_depth;   // valid where stamp == stamp_no during draw_shafts
    uint32_t stamp_no = 0;

    std::vector<float> noise;         // N(0,1) table
    float sigma_y[256];

    // Per-field scratch (reused: no allocation once warm).
    SceneGeometry geo_mid, geo_start, geo_end;
    std::vector<SceneGeometry> geo_t;
    std::vector<SceneGeometry> geo_b;  // the checkerboard's time samples
    std::vector<double> times_b;
    std::vector<double> times;
    std::vector<double> tile_I, tile_cv, tile_ca;
    Occluders occ;
    std::vector<Rect> marker_rect;

    Eigen::Vector3d to_cam(const Eigen::Vector3d& x) const { return cam.to_camera(x); }

    void precompute();
    void draw_shafts(int parity, const SceneGeometry& g);
    void draw_board(int parity, int T);
    void draw_markers(int parity, const std::vector<double>& sample_times_us, std::vector<MarkerCameraTruth>& truth);
    void composite(int parity);
    void to_uyvy(int parity, int64_t index, uint8_t* out) const;
};

CameraRenderer::CameraRenderer(const CameraModel& cam, int cam_index, const Eigen::Vector3d& eye_center_rig_mm,
                               double eye_radius_mm, const RenderOptions& opt)
    : impl_(std::make_unique<Impl>()) {
    impl_->cam = cam;
    impl_->cam_index = cam_index;
    impl_->opt = opt;
    impl_->eye_c_rig = eye_center_rig_mm;
    impl_->eye_r = eye_radius_mm;
    impl_->precompute();
}
CameraRenderer::~CameraRenderer() = default;
CameraRenderer::CameraRenderer(CameraRenderer&&) noexcept = default;
CameraRenderer& CameraRenderer::operator=(CameraRenderer&&) noexcept = default;

const std::vector<float>& CameraRenderer::last_rgb() const { return impl_->img[impl_->last_parity]; }
const CameraModel& CameraRenderer::camera() const { return impl_->cam; }

void CameraRenderer::Impl::precompute() {
    const Eigen::Vector3d ec = to_cam(eye_c_rig);
    const double er2 = eye_r * eye_r;
    for (int p = 0; p < 2; ++p) {
        ray[p].assign(static_cast<size_t>(W) * H * 2, 0.f);
        base[p].assign(static_cast<size_t>(W) * H * 3, 0.f);
        eye_depth[p].assign(static_cast<size_t>(W) * H, kInf);
        for (int y = 0; y < H; ++y) {
            const double v = 2.0 * y + p;
            Eigen::Vector2d q((0 - cam.cx) / cam.fx, (v - cam.cy) / cam.fy);
            bool warm = false;
            for (int x = 0; x < W; ++x) {
                const size_t i = static_cast<size_t>(y) * W + x;
                const Eigen::Vector2d px(x, v);
                // Newton from the previous pixel's solution (warm start along the row).
                bool ok = false;
                if (!warm) q = Eigen::Vector2d((x - cam.cx) / cam.fx, (v - cam.cy) / cam.fy);
                for (int it = 0; it < 30; ++it) {
                    const Eigen::Vector2d r = cam.distort_normalized(q) - px;
                    const Eigen::Vector2d step = cam.distort_jacobian(q).inverse() * r;
                    q -= step;
                    if (!q.allFinite() || q.squaredNorm() > 4.0) break;
                    if (step.squaredNorm() < 1e-26) {
                        ok = true;
                        break;
                    }
                }
                ok = ok && q.squaredNorm() <= cam.max_r2;
                warm = ok;
                float* rgb = &base[p][i * 3];
                rgb[0] = kBackgroundRgb[0];
                rgb[1] = kBackgroundRgb[1];
                rgb[2] = kBackgroundRgb[2];
                if (!ok) {
                    ray[p][i * 2] = ray[p][i * 2 + 1] = std::numeric_limits<float>::quiet_NaN();
                    q = Eigen::Vector2d((x + 1 - cam.cx) / cam.fx, (v - cam.cy) / cam.fy);
                    continue;
                }
                ray[p][i * 2] = static_cast<float>(q.x());
                ray[p][i * 2 + 1] = static_cast<float>(q.y());
                if (eye_r <= 0) continue;
                const Eigen::Vector3d d = Eigen::Vector3d(q.x(), q.y(), 1.0).normalized();
                const double tc = ray_sphere(d, ec, er2);
                eye_depth[p][i] = static_cast<float>(tc);
                // Eye coverage and shading: 4×4 samples near the outline, else the centre only.
                const double cosb = d.dot(ec.normalized());
                const double beta = std::acos(std::clamp(cosb, -1.0, 1.0));
                const double alpha = std::asin(std::min(1.0, eye_r / ec.norm()));
                const double near_px = std::abs(beta - alpha) * cam.fx;
                int n = near_px < 3.0 ? 4 : 1;
                const Eigen::Matrix2d A = cam.distort_jacobian(q).inverse();
                double acc = 0;
                for (int sy = 0; sy < n; ++sy)
                    for (int sx = 0; sx < n; ++sx) {
                        const Eigen::Vector2d dp = n == 1 ? Eigen::Vector2d::Zero()
                                                          : Eigen::Vector2d((sx + 0.5) / n - 0.5, (sy + 0.5) / n - 0.5);
                        const Eigen::Vector2d qs = q + A * dp;
                        const Eigen::Vector3d ds = Eigen::Vector3d(qs.x(), qs.y(), 1.0).normalized();
                        const double t = ray_sphere(ds, ec, er2);
                        if (t == kInf) continue;
                        const Eigen::Vector3d nrm = (t * ds - ec) / eye_r;
                        acc += kShadeAmbient + kShadeDiffuse * std::max(0.0, -nrm.dot(ds));
                    }
                acc /= n * n;
                const double cover = [&] {
                    int hits = 0;
                    for (int sy = 0; sy < n; ++sy)
                        for (int sx = 0; sx < n; ++sx) {
                            const Eigen::Vector2d dp = n == 1 ? Eigen::Vector2d::Zero()
                                                              : Eigen::Vector2d((sx + 0.5) / n - 0.5, (sy + 0.5) / n - 0.5);
                            const Eigen::Vector2d qs = q + A * dp;
                            hits += ray_sphere(Eigen::Vector3d(qs.x(), qs.y(), 1.0).normalized(), ec, er2) < kInf;
                        }
                    return static_cast<double>(hits) / (n * n);
                }();
                for (int c = 0; c < 3; ++c)
                    rgb[c] = static_cast<float>(kEyeRgb[c] * acc + kBackgroundRgb[c] * (1.0 - cover));
            }
        }
        img[p] = base[p];
        dirty[p].clear();
    }
    cov.assign(static_cast<size_t>(W) * H, 0.f);
    contrib.assign(static_cast<size_t>(W) * H * 3, 0.f);
    stamp.assign(static_cast<size_t>(W) * H, 0u);
    shaft_depth.assign(static_cast<size_t>(W) * H, kInf);

    // Noise table: 2^16 standard normal values (Box–Muller), deterministic.
    uint64_t s = 0x5EEDull ^ (opt.seed * 0x9E3779B97F4A7C15ull);
    noise.resize(1u << 16);
    for (size_t i = 0; i < noise.size(); i += 2) {
        const double u1 = (static_cast<double>(splitmix(s) >> 11) + 1.0) * 0x1.0p-53;
        const double u2 = static_cast<double>(splitmix(s) >> 11) * 0x1.0p-53;
        const double r = std::sqrt(-2.0 * std::log(u1));
        noise[i] = static_cast<float>(r * std::cos(2 * M_PI * u2));
        noise[i + 1] = static_cast<float>(r * std::sin(2 * M_PI * u2));
    }
    for (int yv = 0; yv < 256; ++yv)
        sigma_y[yv] = static_cast<float>(
            std::sqrt(opt.noise_sigma * opt.noise_sigma + opt.shot_gain * std::max(0, yv - 16)));
}

void CameraRenderer::Impl::draw_shafts(int parity, const SceneGeometry& g) {
    ++stamp_no;
    for (const auto& sh : g.shafts) {
        const Eigen::Vector3d a = to_cam(sh.a_rig_mm), b = to_cam(sh.b_rig_mm);
        const double len = (b - a).norm();
        if (len <= 0) continue;
        const Eigen::Vector3d w = (b - a) / len;
        const int n = std::max(2, static_cast<int>(len / 1.5) + 1);
        Eigen::Vector2d prev;
        bool prev_ok = false;
        double prev_z = 0;
        for (int k = 0; k <= n; ++k) {
            const Eigen::Vector3d pc = a + (len * k / n) * w;
            bool ok = pc.z() > 1.0;
            Eigen::Vector2d pp;
            if (ok) {
                const Eigen::Vector2d q(pc.x() / pc.z(), pc.y() / pc.z());
                ok = q.squaredNorm() <= cam.max_r2;
                if (ok) pp = cam.distort_normalized(q);
            }
            if (ok && prev_ok) {
                const double rpx = sh.radius_mm * std::max(cam.fx, cam.fy) / std::min(pc.z(), prev_z) * 1.3 + 2.0;
                const int x0 = std::max(0, static_cast<int>(std::floor(std::min(pp.x(), prev.x()) - rpx)));
                const int x1 = std::min(W - 1, static_cast<int>(std::ceil(std::max(pp.x(), prev.x()) + rpx)));
                const double v0 = std::min(pp.y(), prev.y()) - rpx, v1 = std::max(pp.y(), prev.y()) + rpx;
                const int y0 = std::max(0, static_cast<int>(std::ceil((v0 - parity) / 2)));
                const int y1 = std::min(H - 1, static_cast<int>(std::floor((v1 - parity) / 2)));
                if (x0 <= x1 && y0 <= y1) {
                    dirty[parity].push_back({x0, y0, x1, y1});
                    for (int y = y0; y <= y1; ++y)
                        for (int x = x0; x <= x1; ++x) {
                            const size_t i = static_cast<size_t>(y) * W + x;
                            const float qx = ray[parity][i * 2], qy = ray[parity][i * 2 + 1];
                            if (std::isnan(qx)) continue;
                            const Eigen::Vector3d d = Eigen::Vector3d(qx, qy, 1.0).normalized();
                            Eigen::Vector3d nrm;
                            const double t = ray_cylinder(d, a, w, len, sh.radius_mm, &nrm);
                            if (t == kInf || t >= eye_depth[parity][i]) continue;
                            if (stamp[i] == stamp_no && t >= shaft_depth[i]) continue;  // a nearer shaft is there
                            stamp[i] = stamp_no;
                            shaft_depth[i] = static_cast<float>(t);
                            const double shade = kShadeAmbient + kShadeDiffuse * std::abs(nrm.dot(d));
                            float* rgb = &img[parity][i * 3];
                            for (int c = 0; c < 3; ++c) rgb[c] = static_cast<float>(kShaftRgb[c] * shade);
                        }
                }
            }
            prev = pp;
            prev_ok = ok;
            prev_z = pc.z();
        }
    }
}

void CameraRenderer::Impl::draw_board(int parity, int T) {
    for (int k = 0; k < T; ++k)
        if (!geo_b[k].board) return;
    const BoardSpec& spec = kCheckerboard;
    const double sq = spec.square_mm;
    // Sub-cells per edge pixel side: exact polygon areas on each sub-cell's affine footprint, so the only
    // error left is the map's curvature inside a sub-cell. Blurred fields average T samples: 2 are ample there.
    const int ns = std::max(1, T == 1 ? opt.board_subcells : std::min(2, opt.board_subcells));
    const double h = 1.0 / ns;
    // Pixels the sheet may touch at any time sample (outline projected densely; the whole image if it does
    // not project).
    Rect box{W, H, -1, -1};
    std::vector<CamBoard> boards;
    for (int k = 0; k < T; ++k) {
        boards.emplace_back(*geo_b[k].board, cam);
        const auto c = spec.outline_board_mm();
        bool all = true;
        double u0 = 1e30, u1 = -1e30, v0 = 1e30, v1 = -1e30;
        for (int e = 0; e < 4 && all; ++e)
            for (int j = 0; j < 32; ++j) {
                const auto px = cam.project_frame(geo_b[k].board->to_rig(c[e] + (c[(e + 1) % 4] - c[e]) * (j / 32.0)));
                if (!px) {
                    all = false;
                    break;
                }
                u0 = std::min(u0, px->x()), u1 = std::max(u1, px->x());
                v0 = std::min(v0, px->y()), v1 = std::max(v1, px->y());
            }
        if (!all) {
            box = {0, 0, W - 1, H - 1};
            continue;
        }
        box.x0 = std::min(box.x0, std::max(0, static_cast<int>(std::floor(u0 - 2))));
        box.x1 = std::max(box.x1, std::min(W - 1, static_cast<int>(std::ceil(u1 + 2))));
        box.y0 = std::min(box.y0, std::max(0, static_cast<int>(std::floor((v0 - 2 - parity) / 2))));
        box.y1 = std::max(box.y1, std::min(H - 1, static_cast<int>(std::ceil((v1 + 2 - parity) / 2))));
    }
    if (box.x0 > box.x1 || box.y0 > box.y1) return;
    const int bw = box.x1 - box.x0 + 1, bh = box.y1 - box.y0 + 1;
    tile_ca.assign(static_cast<size_t>(bw) * bh, 0.0);         // coverage
    tile_I.assign(static_cast<size_t>(bw) * bh * 3, 0.0);      // RGB contribution
    const double wt = 1.0 / T;

    for (const CamBoard& b : boards) {
        const double no = b.n.dot(b.o);
        // Board coordinates (mm) of the sheet point on the ray through normalised point q; z-depth in `tz`.
        auto board_at = [&](const Eigen::Vector2d& q, double& tz) {
            const Eigen::Vector3d dvec(q.x(), q.y(), 1.0);
            const double nd = b.n.dot(dvec);
            tz = std::abs(nd) > 1e-15 ? no / nd : -1.0;
            const Eigen::Vector3d rel = tz * dvec - b.o;
            return Eigen::Vector2d(b.ex.dot(rel), b.ey.dot(rel));
        };
        auto colour = [&](int cls) -> const std::array<float, 3>& {
            return !b.facing ? kBoardBackRgb : cls == 1 ? kBoardWhiteRgb : kBoardBlackRgb;
        };
        Eigen::Matrix2d J, A;
        int j_x = -1000, j_y = -1;
        for (int y = box.y0; y <= box.y1; ++y) {
            for (int x = box.x0; x <= box.x1; ++x) {
                const size_t i = static_cast<size_t>(y) * W + x;
                const float qx = ray[parity][i * 2], qy = ray[parity][i * 2 + 1];
                if (std::isnan(qx)) continue;
                const Eigen::Vector2d q(qx, qy);
                double tz;
                const Eigen::Vector2d st = board_at(q, tz);
                if (!(tz > 0)) continue;
                const Eigen::Vector3d dvec(q.x(), q.y(), 1.0);
                const double dn = dvec.norm();
                // Hidden behind the eye or a shaft at the pixel centre (the board is held in front of both).
                const double depth = tz * dn;
                if (depth >= eye_depth[parity][i] || (stamp[i] == stamp_no && depth >= shaft_depth[i])) continue;
                // Jacobian of board coordinates per frame pixel: plane map d(s,t)/dq, then dq/dpx = A. It varies
                // slowly (~1 % over 8 px), so the footprint test uses the one of up to 7 pixels back with a 25 %
                // margin; edge pixels get their own.
                auto jacobian = [&](Eigen::Matrix2d& A_out) {
                    const double nd = b.n.dot(dvec);
                    Eigen::Matrix2d B;
                    for (int j = 0; j < 2; ++j) {
                        Eigen::Vector3d dX = -(j == 0 ? b.n.x() : b.n.y()) / nd * dvec;
                        dX[j] += 1.0;
                        dX *= tz;
                        B(0, j) = b.ex.dot(dX);
                        B(1, j) = b.ey.dot(dX);
                    }
                    A_out = cam.distort_jacobian(q).inverse();
                    return Eigen::Matrix2d(B * A_out);
                };
                if (x - j_x >= 8 || j_y != y) {
                    J = jacobian(A);
                    j_x = x;
                    j_y = y;
                }
                const double es = 0.5 * (std::abs(J(0, 0)) + std::abs(J(0, 1))) * (j_x == x ? 1.001 : 1.25);
                const double et = 0.5 * (std::abs(J(1, 0)) + std::abs(J(1, 1))) * (j_x == x ? 1.001 : 1.25);
                const int a0 = static_cast<int>(std::floor(std::clamp((st.x() - es) / sq, -1e6, 1e6)));
                const int a1 = static_cast<int>(std::floor(std::clamp((st.x() + es) / sq, -1e6, 1e6)));
                const int b0 = static_cast<int>(std::floor(std::clamp((st.y() - et) / sq, -1e6, 1e6)));
                const int b1 = static_cast<int>(std::floor(std::clamp((st.y() + et) / sq, -1e6, 1e6)));
                const double shade = kShadeAmbient + kShadeDiffuse * std::abs(b.n.dot(dvec)) / dn;
                double covered = 0, rgb[3] = {0, 0, 0};
                if (a0 == a1 && b0 == b1) {
                    // Inside one square (or wholly off the sheet).
                    const int cls = spec.cell_class(a0, b0);
                    if (cls < 0) continue;
                    const auto& c = colour(cls);
                    covered = 1.0;
                    for (int ch = 0; ch < 3; ++ch) rgb[ch] = c[ch];
                } else {
                    // Outline pixel: ns × ns sub-cells, each an affine footprint (parallelogram) on the sheet,
                    // clipped exactly against every square it overlaps.
                    if (j_x != x) {
                        J = jacobian(A);
                        j_x = x;
                    }
                    const double cell_area = std::abs(J.determinant()) * h * h;
                    if (!(cell_area > 0)) continue;
                    const Eigen::Vector2d hx = J.col(0) * (0.5 * h), hy = J.col(1) * (0.5 * h);
                    for (int sy = 0; sy < ns; ++sy)
                        for (int sx = 0; sx < ns; ++sx) {
                            const Eigen::Vector2d dp((sx + 0.5) * h - 0.5, (sy + 0.5) * h - 0.5);
                            // Locally inverted distortion (its curvature over a quarter pixel: ~1e-4 px).
                            const Eigen::Vector2d qs = q + A * dp;
                            double tzs;
                            const Eigen::Vector2d c = board_at(qs, tzs);
                            if (!(tzs > 0)) continue;
                            const Eigen::Vector2d poly[4] = {c - hx - hy, c + hx - hy, c + hx + hy, c - hx + hy};
                            double s0 = 1e30, s1 = -1e30, t0 = 1e30, t1 = -1e30;
                            for (const auto& pt : poly) {
                                s0 = std::min(s0, pt.x()), s1 = std::max(s1, pt.x());
                                t0 = std::min(t0, pt.y()), t1 = std::max(t1, pt.y());
                            }
                            // Squares the footprint overlaps, only those of the sheet (a board seen edge-on has
                            // footprints across all of it).
                            const int ca0 = static_cast<int>(std::floor(std::max(s0 / sq, -3.0)));
                            const int ca1 = static_cast<int>(std::floor(std::min(s1 / sq, spec.squares_x + 1.0)));
                            const int cb0 = static_cast<int>(std::floor(std::max(t0 / sq, -3.0)));
                            const int cb1 = static_cast<int>(std::floor(std::min(t1 / sq, spec.squares_y + 1.0)));
                            for (int cb = cb0; cb <= cb1; ++cb)
                                for (int ca = ca0; ca <= ca1; ++ca) {
                                    const int cls = spec.cell_class(ca, cb);
                                    if (cls < 0) continue;
                                    const double area = ca0 == ca1 && cb0 == cb1
                                                            ? cell_area
                                                            : clipped_area(poly, 4, ca * sq, (ca + 1) * sq, cb * sq, (cb + 1) * sq);
                                    const double f = area / cell_area * h * h;
                                    const auto& col = colour(cls);
                                    covered += f;
                                    for (int ch = 0; ch < 3; ++ch) rgb[ch] += f * col[ch];
                                }
                        }
                }
                const size_t ti = static_cast<size_t>(y - box.y0) * bw + (x - box.x0);
                tile_ca[ti] += wt * covered;
                for (int ch = 0; ch < 3; ++ch) tile_I[ti * 3 + ch] += wt * shade * rgb[ch];
            }
        }
    }
    // Over whatever is behind the sheet (eye, background, shafts) in proportion to the uncovered area.
    dirty[parity].push_back(box);
    for (int y = box.y0; y <= box.y1; ++y)
        for (int x = box.x0; x <= box.x1; ++x) {
            const size_t ti = static_cast<size_t>(y - box.y0) * bw + (x - box.x0);
            const double c = std::min(1.0, tile_ca[ti]);
            if (c <= 0) continue;
            float* px = &img[parity][(static_cast<size_t>(y) * W + x) * 3];
            for (int ch = 0; ch < 3; ++ch) px[ch] = static_cast<float>(px[ch] * (1.0 - c) + tile_I[ti * 3 + ch]);
        }
}

void CameraRenderer::Impl::draw_markers(int parity, const std::vector<double>& sample_times_us,
                                        std::vector<MarkerCameraTruth>& truth) {
    const int T = static_cast<int>(sample_times_us.size());
    const size_t nm = geo_mid.markers.size();
    marker_rect.assign(nm, Rect{0, 0, -1, -1});
    const int ne = std::max(1, opt.edge_subcells);
    const double h = 1.0 / ne;
    const double gl = 0.5 / std::sqrt(3.0);  // 2-point Gauss–Legendre offsets on a unit interval
    const double kPi = 3.14159265358979323846;

    for (size_t m = 0; m < nm; ++m) {
        MarkerCameraTruth& tr = truth[m];
        tr = MarkerCameraTruth{};
        tr.center_rig_mm = geo_mid.markers[m].center_rig_mm;
        const double rho = geo_mid.markers[m].radius_mm;
        if (auto pp = cam.project_field(tr.center_rig_mm, parity)) {
            tr.projectable = true;
            tr.projected_px = *pp;
            tr.centroid_px = *pp;
        }
        {
            const double L = to_cam(tr.center_rig_mm).norm();
            tr.radius_px = L > rho ? std::asin(rho / L) * cam.fx : 0.0;
        }

        // Bounding boxes per time sample, union = tile.
        Rect tile{W, H, -1, -1};
        struct Sample {
            bool ok;
            Eigen::Vector3d C;
            Eigen::Vector2d pc;
            Eigen::Matrix2d A;
            Rect r;
        };
        Sample smp[64];
        for (int k = 0; k < T; ++k) {
            Sample& s = smp[k];
            s.ok = false;
            s.C = to_cam(geo_t[k].markers[m].center_rig_mm);
            const double L = s.C.norm();
            if (s.C.z() <= rho + 1e-3 || L <= rho * 1.001) continue;
            const Eigen::Vector2d qc(s.C.x() / s.C.z(), s.C.y() / s.C.z());
            if (qc.squaredNorm() > cam.max_r2 * 0.98) continue;
            s.pc = cam.distort_normalized(qc);
            const Eigen::Matrix2d J = cam.distort_jacobian(qc);
            s.A = J.inverse();
            const double alpha = std::asin(rho / L);
            const double rq = std::tan(alpha) * (1.0 + qc.squaredNorm()) * 1.1;
            const double rpx = rq * J.norm() + 1.5;
            Rect r;
            // Not clipped to the image: the parts outside count as hidden in occluded_fraction.
            constexpr int kOut = 64;
            r.x0 = std::max(-kOut, static_cast<int>(std::floor(s.pc.x() - rpx)));
            r.x1 = std::min(W - 1 + kOut, static_cast<int>(std::ceil(s.pc.x() + rpx)));
            r.y0 = std::max(-kOut / 2, static_cast<int>(std::ceil((s.pc.y() - rpx - parity) / 2)));
            r.y1 = std::min(H - 1 + kOut / 2, static_cast<int>(std::floor((s.pc.y() + rpx - parity) / 2)));
            if (r.x0 > r.x1 || r.y0 > r.y1) continue;
            if (r.x1 < 0 || r.x0 > W - 1 || r.y1 < 0 || r.y0 > H - 1) continue;  // wholly outside the image
            s.r = r;
            s.ok = true;
            tile.x0 = std::min(tile.x0, r.x0);
            tile.y0 = std::min(tile.y0, r.y0);
            tile.x1 = std::max(tile.x1, r.x1);
            tile.y1 = std::max(tile.y1, r.y1);
        }
        if (tile.x0 > tile.x1) continue;
        const int tw = tile.x1 - tile.x0 + 1, th = tile.y1 - tile.y0 + 1;
        tile_I.assign(static_cast<size_t>(tw) * th, 0.0);
        tile_cv.assign(static_cast<size_t>(tw) * th, 0.0);
        tile_ca.assign(static_cast<size_t>(tw) * th, 0.0);
        const double wt = 1.0 / T;

        for (int k = 0; k < T; ++k) {
            const Sample& s = smp[k];
            if (!s.ok) continue;
            const SceneGeometry& g = geo_t[k];
            const Eigen::Vector3d C = s.C;
            const double L = C.norm();
            const Eigen::Vector3d ch = C / L;
            const double cos_a = std::sqrt(1.0 - (rho / L) * (rho / L));
            const Eigen::Matrix2d& A = s.A;

            // Occluders near this marker's line of sight.
            occ.spheres.clear();
            occ.cylinders.clear();
            occ.boards.clear();
            if (g.board) occ.boards.emplace_back(*g.board, cam);
            const double alpha = std::asin(rho / L);
            if (g.eye_radius_mm > 0) {
                const Eigen::Vector3d E = to_cam(g.eye_center_rig_mm);
                const double LE = E.norm();
                const double ae = LE > g.eye_radius_mm ? std::asin(g.eye_radius_mm / LE) : kPi;
                const double ang = std::acos(std::clamp(ch.dot(E / LE), -1.0, 1.0));
                if (ang < ae + alpha + 0.01 && LE - g.eye_radius_mm < L + rho)
                    occ.spheres.push_back({E, g.eye_radius_mm * g.eye_radius_mm});
            }
            for (size_t o = 0; o < g.markers.size(); ++o) {
                if (o == m) continue;
                const Eigen::Vector3d S = to_cam(g.markers[o].center_rig_mm);
                const double LS = S.norm(), rs = g.markers[o].radius_mm;
                if (LS <= rs || LS - rs > L + rho) continue;
                const double ang = std::acos(std::clamp(ch.dot(S / LS), -1.0, 1.0));
                if (ang < std::asin(rs / LS) + alpha + 0.01) occ.spheres.push_back({S, rs * rs});
            }
            for (const auto& sh : g.shafts) {
                const Eigen::Vector3d a = to_cam(sh.a_rig_mm), b = to_cam(sh.b_rig_mm);
                const double len = (b - a).norm();
                if (len <= 0) continue;
                const double d2 = segment_distance2(a, b, Eigen::Vector3d::Zero(), C * (1.0 + rho / L));
                const double lim = sh.radius_mm + 2.0 * rho + 0.5;
                if (d2 < lim * lim) occ.cylinders.push_back({a, (b - a) / len, len, sh.radius_mm});
            }
            const bool any_occ = !occ.spheres.empty() || !occ.cylinders.empty() || !occ.boards.empty();

            // Evaluates the silhouette function at normalised point q: g = cos(alpha) - cos(beta), its frame-px
            // gradient, the marker depth and shading along that ray.
            struct Eval {
                double g, gx, gy, depth, shade;
                Eigen::Vector3d dir;
            };
            auto eval = [&](const Eigen::Vector2d& q, bool want_grad) {
                Eval e;
                const Eigen::Vector3d d(q.x(), q.y(), 1.0);
                const double dn = d.norm();
                e.dir = d / dn;
                const double cb = e.dir.dot(ch);
                e.g = cos_a - cb;
                if (want_grad) {
                    // d cos(beta) / dq, then chain through dq/dpx = A.
                    const double gqx = (ch.x() - cb * e.dir.x()) / dn, gqy = (ch.y() - cb * e.dir.y()) / dn;
                    e.gx = -(gqx * A(0, 0) + gqy * A(1, 0));
                    e.gy = -(gqx * A(0, 1) + gqy * A(1, 1));
                }
                const double disc = rho * rho - L * L * (1.0 - cb * cb);
                const double sd = disc > 0 ? std::sqrt(disc) : 0.0;
                e.depth = L * cb - sd;
                e.shade = kShadeAmbient + kShadeDiffuse * (sd / rho);
                return e;
            };

            for (int y = s.r.y0; y <= s.r.y1; ++y) {
                const double v = 2.0 * y + parity;
                for (int x = s.r.x0; x <= s.r.x1; ++x) {
                    const Eigen::Vector2d px(x, v);
                    // Locally inverted distortion: affine guess, two fixed-Jacobian Newton steps.
                    Eigen::Vector2d q = Eigen::Vector2d(C.x() / C.z(), C.y() / C.z()) + A * (px - s.pc);
                    for (int it = 0; it < 2; ++it) q -= A * (cam.distort_normalized(q) - px);
                    const Eval ec = eval(q, true);
                    const double gn = std::sqrt(ec.gx * ec.gx + ec.gy * ec.gy);
                    const double dist = ec.g / gn;
                    if (dist > 0.85) continue;
                    const size_t ti = static_cast<size_t>(y - tile.y0) * tw + (x - tile.x0);
                    double sum_ca = 0, sum_cv = 0, sum_i = 0;
                    if (dist < -1.2) {
                        // Interior: full coverage, 2×2 Gauss points for the shading.
                        for (int sy = 0; sy < 2; ++sy)
                            for (int sx = 0; sx < 2; ++sx) {
                                const Eigen::Vector2d dp(sx ? gl : -gl, sy ? gl : -gl);
                                const Eval es = eval(q + A * dp, false);
                                const double vis = any_occ && occ.hit_before(es.dir, es.depth) ? 0.0 : 1.0;
                                sum_ca += 0.25;
                                sum_cv += 0.25 * vis;
                                sum_i += 0.25 * vis * es.shade;
                            }
                    } else {
                        // Outline: n×n sub-cells with exact straight-edge coverage each, visited as 2×2 quads
                        // so that quads wholly inside (Gauss points) or outside (skipped) cost little.
                        const double cell_w = h * h;
                        auto subcell = [&](const Eigen::Vector2d& dp) {
                            const Eval es = eval(q + A * dp, true);
                            const double gsn = std::sqrt(es.gx * es.gx + es.gy * es.gy);
                            const double c = cell_coverage(es.g / gsn, es.gx / gsn, es.gy / gsn, h);
                            if (c <= 0) return;
                            const double vis = any_occ && occ.hit_before(es.dir, es.depth) ? 0.0 : 1.0;
                            sum_ca += cell_w * c;
                            sum_cv += cell_w * c * vis;
                            sum_i += cell_w * c * vis * es.shade;
                        };
                        if (ne % 2 != 0 || ne < 4) {
                            for (int sy = 0; sy < ne; ++sy)
                                for (int sx = 0; sx < ne; ++sx) subcell({(sx + 0.5) * h - 0.5, (sy + 0.5) * h - 0.5});
                        } else {
                            const int nh = ne / 2;
                            for (int qy = 0; qy < 2; ++qy)
                                for (int qx = 0; qx < 2; ++qx) {
                                    const Eigen::Vector2d qc(qx ? 0.25 : -0.25, qy ? 0.25 : -0.25);
                                    const Eval eq = eval(q + A * qc, true);
                                    const double dq = eq.g / std::sqrt(eq.gx * eq.gx + eq.gy * eq.gy);
                                    if (dq > 0.45) continue;  // quad (half-diagonal 0.354 px) wholly outside
                                    if (dq < -0.55) {
                                        // Wholly inside (margin for the inside over-estimate): 2×2 Gauss points.
                                        for (int sy = 0; sy < 2; ++sy)
                                            for (int sx = 0; sx < 2; ++sx) {
                                                const Eigen::Vector2d dp = qc + 0.5 * Eigen::Vector2d(sx ? gl : -gl, sy ? gl : -gl);
                                                const Eval es = eval(q + A * dp, false);
                                                const double vis = any_occ && occ.hit_before(es.dir, es.depth) ? 0.0 : 1.0;
                                                sum_ca += 0.0625;
                                                sum_cv += 0.0625 * vis;
                                                sum_i += 0.0625 * vis * es.shade;
                                            }
                                        continue;
                                    }
                                    for (int sy = 0; sy < nh; ++sy)
                                        for (int sx = 0; sx < nh; ++sx)
                                            subcell({qx * 0.5 + (sx + 0.5) * h - 0.5, qy * 0.5 + (sy + 0.5) * h - 0.5});
                                }
                        }
                    }
                    tile_ca[ti] += wt * sum_ca;
                    tile_cv[ti] += wt * sum_cv;
                    tile_I[ti] += wt * sum_i;
                }
            }
        }

        // Truth: centroid of the luma contribution (coverage × shading), frame coordinates → field.
        double si = 0, sx = 0, sv = 0, scv = 0, sca = 0;
        for (int y = tile.y0; y <= tile.y1; ++y)
            for (int x = tile.x0; x <= tile.x1; ++x) {
                const size_t ti = static_cast<size_t>(y - tile.y0) * tw + (x - tile.x0);
                sca += tile_ca[ti];
                if (x < 0 || x >= W || y < 0 || y >= H) continue;  // outside the image: not rendered
                const double I = tile_I[ti];
                si += I;
                sx += I * x;
                sv += I * (2.0 * y + parity);
                scv += tile_cv[ti];
            }
        tr.area_px = scv;
        tr.occluded_fraction = sca > 0 ? 1.0 - scv / sca : 0.0;
        tr.visible = si > 0;
        if (si > 0) {
            tr.centroid_px = Eigen::Vector2d(sx / si, 0.5 * (sv / si - parity));
            if (!tr.projectable) tr.projected_px = tr.centroid_px;
            tr.projectable = true;
        }
        // Marker layer (inside the image only).
        const auto rgb = marker_class_rgb(geo_mid.markers[m].colour_class);
        const Rect in{std::max(0, tile.x0), std::max(0, tile.y0), std::min(W - 1, tile.x1), std::min(H - 1, tile.y1)};
        for (int y = in.y0; y <= in.y1; ++y)
            for (int x = in.x0; x <= in.x1; ++x) {
                const size_t ti = static_cast<size_t>(y - tile.y0) * tw + (x - tile.x0);
                if (tile_cv[ti] <= 0) continue;
                const size_t i = static_cast<size_t>(y) * W + x;
                cov[i] += static_cast<float>(tile_cv[ti]);
                for (int c = 0; c < 3; ++c) contrib[i * 3 + c] += static_cast<float>(tile_I[ti] * rgb[c]);
            }
        marker_rect[m] = in;
    }
}

void CameraRenderer::Impl::composite(int parity) {
    ++stamp_no;
    for (const Rect& r : marker_rect) {
        if (r.x0 > r.x1) continue;
        dirty[parity].push_back(r);
        for (int y = r.y0; y <= r.y1; ++y)
            for (int x = r.x0; x <= r.x1; ++x) {
                const size_t i = static_cast<size_t>(y) * W + x;
                if (stamp[i] == stamp_no) continue;
                stamp[i] = stamp_no;
                const float c = std::min(1.f, cov[i]);
                float* rgb = &img[parity][i * 3];
                for (int k = 0; k < 3; ++k) rgb[k] = rgb[k] * (1.f - c) + contrib[i * 3 + k];
                cov[i] = 0.f;
                contrib[i * 3] = contrib[i * 3 + 1] = contrib[i * 3 + 2] = 0.f;
            }
    }
}

void CameraRenderer::Impl::to_uyvy(int parity, int64_t index, uint8_t* out) const {
    const bool noisy = opt.noise_sigma > 0;
    uint64_t s = opt.seed * 0xD1B54A32D192ED03ull ^ (static_cast<uint64_t>(cam_index) << 56) ^
                 static_cast<uint64_t>(index) * 0x9E3779B97F4A7C15ull;
    uint64_t x = splitmix(s) | 1u;
    auto gauss = [&]() {
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        return noise[(x * 0x2545F4914F6CDD1Dull) >> 48];
    };
    const float ky = 219.f / 255.f, kc = 224.f / 255.f;
    const float sigma_c = static_cast<float>(opt.noise_sigma);
    const float* imgp = img[parity].data();
    for (int y = 0; y < H; ++y) {
        const float* row = imgp + static_cast<size_t>(y) * W * 3;
        uint8_t* o = out + static_cast<size_t>(y) * W * 2;
        for (int xx = 0; xx < W; xx += 2) {
            const float* p0 = row + xx * 3;
            const float* p1 = p0 + 3;
            const float* pm = xx > 0 ? p0 - 3 : p0;
            const float l0 = 0.299f * p0[0] + 0.587f * p0[1] + 0.114f * p0[2];
            const float l1 = 0.299f * p1[0] + 0.587f * p1[1] + 0.114f * p1[2];
            const float fr = 0.25f * (pm[0] + 2 * p0[0] + p1[0]);
            const float fg = 0.25f * (pm[1] + 2 * p0[1] + p1[1]);
            const float fb = 0.25f * (pm[2] + 2 * p0[2] + p1[2]);
            const float lf = 0.299f * fr + 0.587f * fg + 0.114f * fb;
            float Y0 = 16.f + ky * l0, Y1 = 16.f + ky * l1;
            float Cb = 128.f + kc * (fb - lf) / 1.772f, Cr = 128.f + kc * (fr - lf) / 1.402f;
            if (noisy) {
                Y0 += sigma_y[std::clamp(static_cast<int>(Y0), 0, 255)] * gauss();
                Y1 += sigma_y[std::clamp(static_cast<int>(Y1), 0, 255)] * gauss();
                Cb += sigma_c * gauss();
                Cr += sigma_c * gauss();
            }
            // Round half up after clamping to the legal range (values are positive there).
            o[xx * 2 + 0] = static_cast<uint8_t>(std::clamp(Cb, 16.f, 240.f) + 0.5f);
            o[xx * 2 + 1] = static_cast<uint8_t>(std::clamp(Y0, 16.f, 235.f) + 0.5f);
            o[xx * 2 + 2] = static_cast<uint8_t>(std::clamp(Cr, 16.f, 240.f) + 0.5f);
            o[xx * 2 + 3] = static_cast<uint8_t>(std::clamp(Y1, 16.f, 235.f) + 0.5f);
        }
    }
}

void CameraRenderer::render_field(const GeometryAt& geometry, int64_t index, uint8_t* uyvy_out,
                                  std::vector<MarkerCameraTruth>& truth) {
    Impl& d = *impl_;
    const FieldTiming ft = d.cam.field_timing(index);
    const int p = ft.parity;
    d.last_parity = p;
    // Restore the working image of this parity to the static base.
    for (const Rect& r : d.dirty[p])
        for (int y = r.y0; y <= r.y1; ++y) {
            const size_t i0 = (static_cast<size_t>(y) * W + r.x0) * 3;
            std::copy(d.base[p].begin() + i0, d.base[p].begin() + i0 + (r.x1 - r.x0 + 1) * 3, d.img[p].begin() + i0);
        }
    d.dirty[p].clear();

    geometry(ft.exposure_mid_us, d.geo_mid);
    geometry(ft.exposure_start_us, d.geo_start);
    geometry(ft.exposure_end_us, d.geo_end);
    // Time samples: enough that no marker moves more than blur_step_px between samples.
    double motion_px = 0;
    for (size_t m = 0; m < d.geo_mid.markers.size(); ++m) {
        auto a = d.cam.project_frame(d.geo_start.markers[m].center_rig_mm);
        auto b = d.cam.project_frame(d.geo_end.markers[m].center_rig_mm);
        if (a && b) motion_px = std::max(motion_px, (*a - *b).norm());
    }
    // The checkerboard's own time samples (it alone may move in its scene): the same rule, at most
    // board_time_samples (a moving board is only ever rejected by calibration).
    double board_px = 0;
    if (d.geo_start.board && d.geo_end.board)
        for (const Eigen::Vector3d& c : kCheckerboard.outline_board_mm()) {
            auto a = d.cam.project_frame(d.geo_start.board->to_rig(c));
            auto b = d.cam.project_frame(d.geo_end.board->to_rig(c));
            if (a && b) board_px = std::max(board_px, (*a - *b).norm());
        }
    auto samples = [&](double px, int cap, std::vector<double>& times, std::vector<SceneGeometry>& geo) {
        const int T = std::clamp(static_cast<int>(std::ceil(px / d.opt.blur_step_px)), 1, std::min(64, std::max(1, cap)));
        times.resize(static_cast<size_t>(T));
        if (geo.size() < static_cast<size_t>(T)) geo.resize(static_cast<size_t>(T));
        for (int k = 0; k < T; ++k) {
            times[k] = ft.exposure_start_us + (k + 0.5) / T * (ft.exposure_end_us - ft.exposure_start_us);
            geometry(times[k], geo[k]);
        }
        return T;
    };
    samples(motion_px, d.opt.max_time_samples, d.times, d.geo_t);
    truth.resize(d.geo_mid.markers.size());
    if (uyvy_out) d.draw_shafts(p, d.geo_mid);
    if (uyvy_out && d.geo_mid.board)
        d.draw_board(p, samples(board_px, std::min(d.opt.board_time_samples, d.opt.max_time_samples), d.times_b, d.geo_b));
    d.draw_markers(p, d.times, truth);
    d.composite(p);
    if (uyvy_out) d.to_uyvy(p, index, uyvy_out);
}

}  // namespace eyesim::rig
