// Collision benchmark (paper Tables 1–2): the exact collision query, ZCOLL (CPU push at R = 32 … 256, optionally
// EGL) and the peers Bullet and FCL, on poses drawn at random around each scene's contact. Every query is scored
// on the membrane vertices it ran on, against a referee that shares no code with any method: brute-force
// double-precision triangle–triangle tests plus a winding-number inside test, computed once per pose, untimed.
//
// Usage: bench_collision [--poses N=1000] [--seed S=1] [--fcl-poses N=poses] [--egl] [--egl-poses N=50] [--json]
//                        [--scene TEXT] [--method NAME]   (only the scenes whose name holds TEXT / the methods
//                        whose name starts with NAME: a profiler's run; the published tables run them all)
//   Prints a Markdown table (or, with --json, one JSON object): per scene the colliding-count distribution over
//   poses; per method recall and precision over poses (min, p5, median) and thread-CPU time per query (p50, p99).

#include "bench_util.hpp"
#include "eyesim/render/zcoll_gles.hpp"
#include "eyesim/sim/collision/contact.hpp"
#include "eyesim/sim/collision/exact.hpp"
#include "eyesim/sim/collision/instrument.hpp"
#include "eyesim/sim/collision/tri_tri.hpp"
#include "eyesim/sim/collision/zcoll.hpp"

#include <BulletCollision/CollisionShapes/btTriangleIndexVertexArray.h>
#include <BulletCollision/Gimpact/btGImpactShape.h>
#include <fcl/geometry/bvh/BVH_model.h>
#include <fcl/narrowphase/collision.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <fstream>
#include <functional>
#include <memory>
#include <random>
#include <span>
#include <string>
#include <vector>

using namespace eyesim::sim;
using namespace eyesim::sim::collision;
using eyesim::sim::collision::bench::pose_at;
using eyesim::sim::collision::bench::thread_cpu_us;

namespace {

constexpr double kPi = 3.14159265358979323846;
using Vec3d = Eigen::Vector3d;

// ---------------------------------------------------------------------------------------------------------------
// Referee: brute force in double precision, written for this program only (no code shared with the methods).

struct Box3d {
    Vec3d lo = Vec3d::Constant(1e300), hi = Vec3d::Constant(-1e300);
    void add(const Vec3d& p) { lo = lo.cwiseMin(p); hi = hi.cwiseMax(p); }
    bool overlaps(const Box3d& o) const { return (lo.array() <= o.hi.array()).all() && (o.lo.array() <= hi.array()).all(); }
    bool contains(const Vec3d& p) const { return (lo.array() <= p.array()).all() && (p.array() <= hi.array()).all(); }
};

// Closed segments p0p1 and q0q1 in 2D share a point.
bool segments_meet_2d(const Eigen::Vector2d& p0, const Eigen::Vector2d& p1, const Eigen::Vector2d& q0,
                      const Eigen::Vector2d& q1) {
    auto orient = [](const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c) {
        const double d = (b - a).x() * (c - a).y() - (b - a).y() * (c - a).x();
        return (d > 0) - (d < 0);
    };
    auto on = [](const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c) {  // c on ab, collinear
        return std::min(a.x(), b.x()) <= c.x() && c.x() <= std::max(a.x(), b.x()) && std::min(a.y(), b.y()) <= c.y() &&
               c.y() <= std::max(a.y(), b.y());
    };
    const int o1 = orient(p0, p1, q0), o2 = orient(p0, p1, q1), o3 = orient(q0, q1, p0), o4 = orient(q0, q1, p1);
    if (o1 != o2 && o3 != o4) return true;
    return (o1 == 0 && on(p0, p1, q0)) || (o2 == 0 && on(p0, p1, q1)) || (o3 == 0 && on(q0, q1, p0)) ||
           (o4 == 0 && on(q0, q1, p1));
}

bool point_in_triangle_2d(const Eigen::Vector2d& p, const std::array<Eigen::Vector2d, 3>& t) {
    double s[3];
    for (int i = 0; i < 3; ++i) {
        const Eigen::Vector2d e = t[(i + 1) % 3] - t[i], w = p - t[i];
        s[i] = e.x() * w.y() - e.y() * w.x();
    }
    return (s[0] >= 0 && s[1] >= 0 && s[2] >= 0) || (s[0] <= 0 && s[1] <= 0 && s[2] <= 0);
}

// Where the closed triangle with vertex parameters p[] (along the planes' common line) and signed distances d[]
// (to the other triangle's plane) meets that plane: the interval [lo, hi]; false when it does not.
bool plane_interval(const double p[3], const double d[3], double& lo, double& hi) {
    lo = 1e300;
    hi = -1e300;
    for (int i = 0; i < 3; ++i) {
        if (d[i] == 0) {
            lo = std::min(lo, p[i]);
            hi = std::max(hi, p[i]);
        }
        const int j = (i + 1) % 3;
        if ((d[i] < 0 && d[j] > 0) || (d[i] > 0 && d[j] < 0)) {
            const double t = p[i] + (p[j] - p[i]) * d[i] / (d[i] - d[j]);
            lo = std::min(lo, t);
            hi = std::max(hi, t);
        }
    }
    return lo <= hi;
}

/// Closed triangles share a point (Möller's interval test on the planes' common line; coplanar pairs in 2D).
bool referee_tri_tri(const Vec3d a[3], const Vec3d b[3]) {
    const Vec3d na = (a[1] - a[0]).cross(a[2] - a[0]), nb = (b[1] - b[0]).cross(b[2] - b[0]);
    double da[3], db[3];
    for (int i = 0; i < 3; ++i) {
        da[i] = nb.dot(a[i] - b[0]);
        db[i] = na.dot(b[i] - a[0]);
    }
    auto one_side = [](const double d[3]) { return (d[0] > 0 && d[1] > 0 && d[2] > 0) || (d[0] < 0 && d[1] < 0 && d[2] < 0); };
    if (one_side(da) || one_side(db)) return false;
    if (da[0] == 0 && da[1] == 0 && da[2] == 0) {  // coplanar: drop the normal's largest axis
        int ax = 0;
        na.cwiseAbs().maxCoeff(&ax);
        const int u = (ax + 1) % 3, v = (ax + 2) % 3;
        std::array<Eigen::Vector2d, 3> a2, b2;
        for (int i = 0; i < 3; ++i) {
            a2[size_t(i)] = {a[i][u], a[i][v]};
            b2[size_t(i)] = {b[i][u], b[i][v]};
        }
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                if (segments_meet_2d(a2[size_t(i)], a2[size_t(i + 1) % 3], b2[size_t(j)], b2[size_t(j + 1) % 3])) return true;
        return point_in_triangle_2d(a2[0], b2) || point_in_triangle_2d(b2[0], a2);
    }
    const Vec3d dir = na.cross(nb);
    double pa[3], pb[3];
    for (int i = 0; i < 3; ++i) {
        pa[i] = dir.dot(a[i]);
        pb[i] = dir.dot(b[i]);
    }
    double alo, ahi, blo, bhi;
    if (!plane_interval(pa, da, alo, ahi) || !plane_interval(pb, db, blo, bhi)) return false;
    return std::max(alo, blo) <= std::min(ahi, bhi);
}

/// Generalised winding number of point p with respect to triangles (solid angles, Van Oosterom–Strackee):
/// ±1 inside a closed surface, 0 outside, whatever the orientation.
double winding_number(const Vec3d& p, std::span<const Vec3d> v, std::span<const std::array<uint32_t, 3>> tris) {
    double sum = 0;
    for (const auto& t : tris) {
        const Vec3d a = v[t[0]] - p, b = v[t[1]] - p, c = v[t[2]] - p;
        const double la = a.norm(), lb = b.norm(), lc = c.norm();
        const double num = a.dot(b.cross(c));
        const double den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
        sum += 2.0 * std::atan2(num, den);
    }
    return sum / (4.0 * kPi);
}

/// The referee's colliding set: membrane triangles that share a point with an instrument triangle, or lie inside
/// one of the instrument's closed parts. Ascending.
class Referee {
public:
    Referee(const TriangleMesh& membrane, const Instrument& instrument) : mem_(membrane), ins_(instrument) {}

    std::vector<uint32_t> colliding(std::span<const Vec3f> mem_verts, const PosedInstrument& posed) {
        const Eigen::Isometry3d to_eye = posed.instrument_to_eye().cast<double>();
        const auto local = posed.vertices_local_mm();
        ins_eye_.resize(local.size());
        for (size_t i = 0; i < local.size(); ++i) ins_eye_[i] = to_eye * local[i].cast<double>();
        mem_eye_.resize(mem_verts.size());
        Box3d mem_box;
        for (size_t i = 0; i < mem_verts.size(); ++i) mem_box.add(mem_eye_[i] = mem_verts[i].cast<double>());
        const auto& itri = ins_.mesh.triangles;
        // Instrument triangles that can reach the membrane at all.
        near_.clear();
        ins_box_.resize(itri.size());
        Box3d near_box;
        for (uint32_t t = 0; t < itri.size(); ++t) {
            Box3d b;
            for (uint32_t k : itri[t]) b.add(ins_eye_[k]);
            ins_box_[t] = b;
            if (b.overlaps(mem_box)) {
                near_.push_back(t);
                near_box.add(b.lo);
                near_box.add(b.hi);
            }
        }
        hit_.assign(mem_.triangle_count(), 0);
        for (uint32_t m = 0; m < mem_.triangle_count(); ++m) {
            const auto& mt = mem_.triangles[m];
            const Vec3d a[3] = {mem_eye_[mt[0]], mem_eye_[mt[1]], mem_eye_[mt[2]]};
            Box3d mb;
            for (const Vec3d& p : a) mb.add(p);
            if (!mb.overlaps(near_box)) continue;
            for (uint32_t t : near_) {
                if (!mb.overlaps(ins_box_[t])) continue;
                const Vec3d b[3] = {ins_eye_[itri[t][0]], ins_eye_[itri[t][1]], ins_eye_[itri[t][2]]};
                if (referee_tri_tri(a, b)) {
                    hit_[m] = 1;
                    break;
                }
            }
        }
        // Containment: a triangle that meets no instrument triangle lies wholly on one side of every part's
        // surface, so one vertex decides; it must lie in the part's bounds with all three vertices.
        const auto& pb = ins_.part_triangle_begin;
        const size_t parts = pb.empty() ? 1 : pb.size() - 1;
        for (size_t k = 0; k < parts; ++k) {
            const uint32_t t0 = pb.empty() ? 0 : pb[k], t1 = pb.empty() ? uint32_t(itri.size()) : pb[k + 1];
            Box3d part_box;
            for (uint32_t t = t0; t < t1; ++t) {
                part_box.add(ins_box_[t].lo);
                part_box.add(ins_box_[t].hi);
            }
            const std::span<const std::array<uint32_t, 3>> part_tris(itri.data() + t0, t1 - t0);
            for (uint32_t m = 0; m < mem_.triangle_count(); ++m) {
                if (hit_[m]) continue;
                const auto& mt = mem_.triangles[m];
                if (!part_box.contains(mem_eye_[mt[0]]) || !part_box.contains(mem_eye_[mt[1]]) ||
                    !part_box.contains(mem_eye_[mt[2]]))
                    continue;
                if (std::fabs(winding_number(mem_eye_[mt[0]], ins_eye_, part_tris)) > 0.5) hit_[m] = 2;
            }
        }
        std::vector<uint32_t> out;
        for (uint32_t m = 0; m < mem_.triangle_count(); ++m)
            if (hit_[m]) out.push_back(m);
        return out;
    }

    /// Of the last query's set, the triangles that meet the instrument's surface (what FCL and Bullet report).
    std::vector<uint32_t> last_surface_set() const {
        std::vector<uint32_t> out;
        for (uint32_t m = 0; m < hit_.size(); ++m)
            if (hit_[m] == 1) out.push_back(m);
        return out;
    }

private:
    const TriangleMesh& mem_;
    const Instrument& ins_;
    std::vector<Vec3d> ins_eye_, mem_eye_;
    std::vector<Box3d> ins_box_;
    std::vector<uint32_t> near_;
    std::vector<uint8_t> hit_;
};

// ---------------------------------------------------------------------------------------------------------------
// Scenes and poses.


Vec3f scene_tip(float depth_mm) { return {0.11f, 0.07f, -depth_mm}; }
Vec3f scene_forward(float tilt_deg) {
    const float a = tilt_deg * float(kPi) / 180.0f;
    return {std::sin(a), 0.0f, -std::cos(a)};
}

struct SceneSpec {
    std::string name;
    PatchSize patch;
    size_t target;          ///< colliding triangles at the nominal pose (0: as many as a grazing approach gives)
    float lateral_mm;       ///< largest tip offset across the membrane (per axis)
    float normal_mm;        ///< largest tip offset along the membrane normal
    float direction_deg;    ///< largest tilt of the instrument axis away from the nominal one
};

struct Scene {
    SceneSpec spec;
    TriangleMesh membrane;
    std::vector<Vec3f> copies[2];  ///< membrane vertices: pose k runs on copies[k & 1] (0.1 µm apart)
    float opening_deg = 30, tilt_deg = 0, depth_mm = 0;
    float half_width_mm = 1, ahead_mm = 0.5f;
    std::vector<Eigen::Isometry3f> poses;
    std::vector<std::vector<uint32_t>> referee;  ///< per pose, on that pose's copy
    std::vector<std::vector<uint32_t>> surface;  ///< per pose: the part of `referee` that meets the surface
    size_t redrawn = 0;                         ///< drawn poses without any contact, replaced
};

/// Nominal pose: the smallest approach angle (from the membrane normal) at which some push depth (≤ 1.5 mm,
/// 0.02 mm steps) reaches `target` colliding triangles, then the depth by bisection below that step; for
/// target 0 the grazing angle (75–88°) and depth (0.02 mm grid) with the most colliding triangles.
void calibrate(Scene& s, PosedInstrument& forceps, Referee& ref) {
    auto count = [&](float tilt, float d) {
        forceps.set_state(s.opening_deg, pose_at(scene_tip(d), scene_forward(tilt)));
        return ref.colliding(s.copies[0], forceps).size();
    };
    if (s.spec.target == 0) {  // dense contact: the grazing approach and depth with the most colliding triangles
        size_t best = 0;
        for (float tilt : {75.0f, 80.0f, 85.0f, 88.0f})
            for (float d = -0.1f; d <= 0.5f; d += 0.02f)
                if (const size_t c = count(tilt, d); c > best) {
                    best = c;
                    s.tilt_deg = tilt;
                    s.depth_mm = d;
                }
        return;
    }
    float found = -1;
    for (float tilt : {0.0f, 15.0f, 30.0f, 45.0f, 60.0f, 70.0f, 75.0f, 80.0f, 85.0f}) {
        s.tilt_deg = tilt;
        for (float d = 0.02f; d <= 1.5f && found < 0; d += 0.02f)
            if (count(tilt, d) >= s.spec.target) found = d;
        if (found >= 0) break;
    }
    if (found < 0) found = 1.5f;
    float lo = std::max(0.0f, found - 0.02f), hi = found;
    for (int it = 0; it < 20; ++it) {
        const float mid = 0.5f * (lo + hi);
        (count(s.tilt_deg, mid) < s.spec.target ? lo : hi) = mid;
    }
    s.depth_mm = hi;
}

/// Uniform double in [0, 1) from 53 random bits (the same on every platform, unlike std distributions).
double uniform01(std::mt19937_64& g) { return double(g() >> 11) * 0x1.0p-53; }
double uniform(std::mt19937_64& g, double a, double b) { return a + (b - a) * uniform01(g); }

/// Poses around the nominal one: tip offsets up to ±lateral_mm across and ±normal_mm along the normal, each
/// scaled by a factor drawn log-uniformly from [0.05, 1] (so offsets of a few µm to the full range occur alike);
/// the axis tilted by up to direction_deg about a random perpendicular axis. Poses without any contact are
/// redrawn. V's half width is then fitted to hold every pose's colliding set.
void draw_poses(Scene& s, PosedInstrument& forceps, Referee& ref, int n, uint64_t seed) {
    std::mt19937_64 g(seed);
    const Vec3f tip0 = scene_tip(s.depth_mm), fwd0 = scene_forward(s.tilt_deg);
    s.poses.clear();
    s.referee.clear();
    s.surface.clear();
    while (int(s.poses.size()) < n) {
        const double scale = std::exp(uniform(g, std::log(0.05), 0.0));
        const Vec3f offset(float(scale * uniform(g, -1, 1) * s.spec.lateral_mm),
                           float(scale * uniform(g, -1, 1) * s.spec.lateral_mm),
                           float(scale * uniform(g, -1, 1) * s.spec.normal_mm));
        const double phi = uniform(g, 0, 2 * kPi), tilt = uniform(g, 0, s.spec.direction_deg) * kPi / 180.0;
        const Vec3f u = fwd0.unitOrthogonal(), w = fwd0.cross(u);
        const Vec3f axis = float(std::cos(phi)) * u + float(std::sin(phi)) * w;
        const Vec3f fwd = Eigen::AngleAxisf(float(tilt), axis) * fwd0;
        const Eigen::Isometry3f pose = pose_at(tip0 + offset, fwd);
        forceps.set_state(s.opening_deg, pose);
        auto set = ref.colliding(s.copies[s.poses.size() & 1], forceps);
        if (set.empty()) {
            if (++s.redrawn > size_t(100 * n) + 1000) {  // the scene has no contact to speak of
                std::fprintf(stderr, "eyesim: error: bench_collision: %s: no contact in %zu drawn poses\n",
                             s.spec.name.c_str(), s.redrawn);
                std::exit(1);
            }
            continue;
        }
        s.poses.push_back(pose);
        s.referee.push_back(std::move(set));
        s.surface.push_back(ref.last_surface_set());
    }
    float reach = 0.3f;
    for (size_t k = 0; k < s.poses.size(); ++k) {
        const Vec3f tip = s.poses[k].translation();
        for (uint32_t t : s.referee[k])
            for (uint32_t v : s.membrane.triangles[t])
                reach = std::max({reach, std::fabs(s.copies[k & 1][v].x() - tip.x()),
                                  std::fabs(s.copies[k & 1][v].y() - tip.y())});
    }
    s.half_width_mm = std::ceil((reach + 0.05f) * 4.0f) / 4.0f;
}

/// ZCOLL's view for pose k: π = membrane normal (+z, camera below the membrane looking back at the instrument),
/// centred on the tip, from 0.5 mm beyond the tip to 0.5 mm above the undeformed membrane.
ZcollView scene_view(const Scene& s, size_t k, int r) {
    const Vec3f tip = s.poses[k].translation();
    return make_tip_view_along(tip, Vec3f(0, 0, 1), Vec3f(0, 1, 0), s.half_width_mm, s.ahead_mm,
                               std::max(0.5f, 0.5f - tip.z()), r);
}

// ---------------------------------------------------------------------------------------------------------------
// Timing and scoring.


/// Nearest-rank percentile (p in [0, 1]); NaN without samples.
double pct(std::vector<double> v, double p) {
    if (v.empty()) return std::nan("");
    std::sort(v.begin(), v.end());
    const double rank = std::ceil(p * double(v.size()));
    return v[size_t(std::clamp(rank - 1.0, 0.0, double(v.size() - 1)))];
}

struct MethodResult {
    std::string name, clock = "thread_cpu";
    std::vector<double> recall, precision, time_us;  ///< per scored pose (precision: where anything was found)
    size_t fallbacks = 0;                            ///< ZCOLL: poses answered by its exact fallback
    size_t equal = 0, equal_surface = 0;  ///< poses whose set equals the referee's / its surface part exactly
};

/// Runs `query(k)` on poses 0 … n-1 (3 unscored warm-up queries first); `prepare(k)` runs untimed before each.
/// Each answer is scored against the referee of its own pose.
MethodResult run_method(const std::string& name, const Scene& s, int n, bool wall,
                        const std::function<void(size_t)>& prepare,
                        const std::function<std::span<const uint32_t>(size_t)>& query) {
    MethodResult r;
    r.name = name;
    if (wall) r.clock = "wall";
    n = std::min<int>(n, int(s.poses.size()));
    for (int k = 0; k < std::min(3, n); ++k) {
        prepare(size_t(k));
        query(size_t(k));
    }
    std::vector<uint32_t> got;
    for (int k = 0; k < n; ++k) {
        prepare(size_t(k));
        const double c0 = thread_cpu_us();
        const auto t0 = std::chrono::steady_clock::now();
        const std::span<const uint32_t> res = query(size_t(k));
        const auto t1 = std::chrono::steady_clock::now();
        const double c1 = thread_cpu_us();
        r.time_us.push_back(wall ? std::chrono::duration<double, std::micro>(t1 - t0).count() : c1 - c0);
        got.assign(res.begin(), res.end());
        std::sort(got.begin(), got.end());
        got.erase(std::unique(got.begin(), got.end()), got.end());
        const auto& truth = s.referee[size_t(k)];
        size_t common = 0;
        for (uint32_t t : got) common += std::binary_search(truth.begin(), truth.end(), t);
        r.recall.push_back(double(common) / double(truth.size()));
        r.equal += got == truth;
        r.equal_surface += got == s.surface[size_t(k)];
        if (!got.empty()) r.precision.push_back(double(common) / double(got.size()));
    }
    return r;
}

/// "%.<digits>f", or "–" without samples.
std::string fixed(double v, int digits) {
    if (!std::isfinite(v)) return "–";
    char b[64];
    std::snprintf(b, sizeof b, "%.*f", digits, v);
    return b;
}

nlohmann::json num(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

std::string load_average() {
    std::ifstream f("/proc/loadavg");
    std::string a, b, c;
    if (!(f >> a >> b >> c)) return "unknown";
    return a + " " + b + " " + c;
}

}  // namespace

int main(int argc, char** argv) {
    int poses = 1000, fcl_poses = -1, egl_poses = 50;
    uint64_t seed = 1;
    bool json = false, egl = false;
    std::string only_scene, only_method;
    auto want = [&](const std::string& method) { return method.rfind(only_method, 0) == 0; };
    auto count_arg = [&](const char* opt, const char* v, int& out) {
        char* end = nullptr;
        const long x = std::strtol(v, &end, 10);
        if (!*v || *end || x < 1 || x > 1000000) {
            std::fprintf(stderr, "eyesim: error: bench_collision: %s needs a count in 1 … 1000000, got '%s'\n", opt, v);
            return false;
        }
        out = int(x);
        return true;
    };
    for (int i = 1; i < argc; ++i) {
        const bool has = i + 1 < argc;
        if (!std::strcmp(argv[i], "--json")) json = true;
        else if (!std::strcmp(argv[i], "--egl")) egl = true;
        else if (!std::strcmp(argv[i], "--poses") && has) {
            if (!count_arg("--poses", argv[++i], poses)) return 2;
        } else if (!std::strcmp(argv[i], "--fcl-poses") && has) {
            if (!count_arg("--fcl-poses", argv[++i], fcl_poses)) return 2;
        } else if (!std::strcmp(argv[i], "--egl-poses") && has) {
            if (!count_arg("--egl-poses", argv[++i], egl_poses)) return 2;
        } else if (!std::strcmp(argv[i], "--scene") && has) {
            only_scene = argv[++i];
        } else if (!std::strcmp(argv[i], "--method") && has) {
            only_method = argv[++i];
        } else if (!std::strcmp(argv[i], "--seed") && has) {
            char* end = nullptr;
            const char* v = argv[++i];
            seed = std::strtoull(v, &end, 10);
            if (!*v || *end || *v == '-') {
                std::fprintf(stderr, "eyesim: error: bench_collision: --seed needs a non-negative integer, got '%s'\n", v);
                return 2;
            }
        } else {
            std::fprintf(stderr, "eyesim: error: bench_collision: unknown or incomplete option %s (usage: "
                                 "bench_collision [--poses N] [--seed S] [--fcl-poses N] [--egl] [--egl-poses N] "
                                 "[--json] [--scene TEXT] [--method NAME])\n", argv[i]);
            return 2;
        }
    }
    if (fcl_poses < 0) fcl_poses = poses;
    const std::string load_start = load_average();

    PosedInstrument forceps(make_forceps());
    const Instrument& ins = forceps.instrument();
    std::string renderer = "not run (--egl)";
    if (egl) {
        std::string err;
        auto probe = eyesim::render::GlesZcollBackend::create(err);
        renderer = probe ? probe->context().renderer() : "unavailable: " + err;
        if (!probe) std::fprintf(stderr, "eyesim: warning: bench_collision: no EGL back-end (%s); EGL rows skipped\n",
                                 err.c_str());
    }

    // The paper's situations: 4 × 4 mm membranes of ≈400, 1k and 3k triangles and the 2k-triangle forceps (jaws
    // open 30°) pushed through until about 40 triangles collide; and a dense, grazing contact.
    const std::vector<SceneSpec> specs = {
        {"400 membrane, ~40 colliding", kPatch400, 40, 0.25f, 0.10f, 3.0f},
        {"1k membrane, ~40 colliding", kPatch1k, 40, 0.25f, 0.10f, 3.0f},
        {"3k membrane, ~40 colliding", kPatch3k, 40, 0.25f, 0.10f, 3.0f},
        {"3k membrane, dense contact", kPatch3k, 0, 0.20f, 0.03f, 1.5f},
    };

    nlohmann::json out;
    out["command"] = "bench_collision";
    out["seed"] = seed;
    out["poses"] = poses;
    out["fcl_poses"] = fcl_poses;
    out["forceps_triangles"] = ins.mesh.triangle_count();
    out["egl_renderer"] = renderer;
    out["scenes"] = nlohmann::json::array();
    std::string table;

    for (size_t si = 0; si < specs.size(); ++si) {
        if (specs[si].name.find(only_scene) == std::string::npos) continue;
        Scene s;
        s.spec = specs[si];
        s.membrane = make_membrane_patch(4.0f, 4.0f, s.spec.patch.nx, s.spec.patch.ny);
        if (s.membrane.vertex_triangle_begin.size() != s.membrane.vertex_count() + 1) s.membrane.build_adjacency();
        // The membrane "deforms" between queries: consecutive poses run on two vertex sets 0.1 µm apart, so every
        // refit does real work; each pose's referee is computed on its own set.
        s.copies[0] = s.copies[1] = s.membrane.vertices_mm;
        for (size_t v = 0; v < s.copies[1].size(); ++v) s.copies[1][v].z() += 1e-4f * std::sin(float(v));
        Referee ref(s.membrane, ins);
        calibrate(s, forceps, ref);
        draw_poses(s, forceps, ref, poses, seed * 1000003u + si);
        const TriangleMesh& mem = s.membrane;
        std::vector<Vec3f> verts = s.copies[0];  // the buffer every method reads (fixed address: Bullet keeps it)
        auto set_pose = [&](size_t k) {
            std::copy(s.copies[k & 1].begin(), s.copies[k & 1].end(), verts.begin());
            forceps.set_state(s.opening_deg, s.poses[k]);
        };
        std::vector<MethodResult> methods;

        // --- exact: the exact contact query (colliding set, ZI − ZM per colliding triangle along π = the
        // membrane normal, Eq. 1 node push vectors), as the frame loop runs it: within ZCOLL's V, along its π.
        if (want("exact")) {
            ExactContact contact(mem, ins.mesh.triangle_count());
            OrientedBox volume;
            ContactOptions opt;
            opt.within = &volume;
            Vec3f pi_eye(0, 0, 1);
            methods.push_back(run_method(
                "exact", s, poses, false,
                [&](size_t k) {
                    set_pose(k);
                    const ZcollView view = scene_view(s, k, 32);
                    volume = view_volume(view);
                    pi_eye = view.direction_eye();
                },
                [&](size_t) { return contact.query(verts, forceps, pi_eye, opt).colliding_triangles; }));
        }
        // --- exact_grid: the uniform-grid narrow phase ZCOLL falls back to (colliding set only).
        if (want("exact_grid")) {
            ExactNarrowPhase exact(mem.triangle_count(), ins.mesh.triangle_count());
            ExactOptions opt;
            opt.vertex_triangle_begin = mem.vertex_triangle_begin;
            opt.vertex_triangles = mem.vertex_triangles;
            methods.push_back(run_method("exact_grid", s, poses, false, set_pose, [&](size_t) {
                const MeshRef m{verts, mem.triangles, Eigen::Isometry3f::Identity()};
                const MeshRef t{forceps.vertices_local_mm(), ins.mesh.triangles, forceps.instrument_to_eye()};
                return exact.colliding_triangles(m, t, ins.part_triangle_begin, opt);
            }));
        }

        // --- ZCOLL push (features, Eq. 1 vectors, π-convexity check), CPU rasteriser.
        for (int r : {32, 64, 128, 256}) {
            if (!want("zcoll_r" + std::to_string(r))) continue;
            ZcollConfig cfg;
            cfg.resolution_px = r;
            ZcollEngine engine(mem, cfg);
            ZcollView view;
            size_t fallbacks = 0;
            auto m = run_method("zcoll_r" + std::to_string(r), s, poses, false,
                                [&](size_t k) {
                                    set_pose(k);
                                    view = scene_view(s, k, r);
                                },
                                [&](size_t) {
                                    const ZcollResult& res = engine.push(verts, forceps, view);
                                    fallbacks += res.fallback_used;
                                    return res.colliding_triangles;
                                });
            m.fallbacks = fallbacks;
            methods.push_back(std::move(m));
        }

        // --- Bullet: GImpact quantized BVH over the membrane refitted per query, pair search against the
        // forceps' tree, then the exact triangle test on the candidate pairs (surface intersections only).
        std::vector<Vec3f> ins_local(forceps.vertices_local_mm().begin(), forceps.vertices_local_mm().end());
        if (want("bullet")) {
            std::vector<int> mem_idx, ins_idx;
            for (const auto& t : mem.triangles) mem_idx.insert(mem_idx.end(), {int(t[0]), int(t[1]), int(t[2])});
            for (const auto& t : ins.mesh.triangles) ins_idx.insert(ins_idx.end(), {int(t[0]), int(t[1]), int(t[2])});
            btTriangleIndexVertexArray mem_array(int(mem.triangle_count()), mem_idx.data(), 3 * sizeof(int),
                                                 int(verts.size()), reinterpret_cast<btScalar*>(verts.data()),
                                                 sizeof(Vec3f));
            btTriangleIndexVertexArray ins_array(int(ins.mesh.triangle_count()), ins_idx.data(), 3 * sizeof(int),
                                                 int(ins_local.size()), reinterpret_cast<btScalar*>(ins_local.data()),
                                                 sizeof(Vec3f));
            btGImpactMeshShapePart mem_part(&mem_array, 0), ins_part(&ins_array, 0);
            mem_part.setMargin(0);
            ins_part.setMargin(0);
            mem_part.updateBound();
            ins_part.updateBound();
            btTransform ins_bt, ident;
            ident.setIdentity();
            btPairSet pairs;
            std::vector<Vec3f> ins_eye(ins_local.size());
            std::vector<uint32_t> stamp(mem.triangle_count(), 0), got;
            got.reserve(mem.triangle_count());
            uint32_t q = 0;
            Eigen::Isometry3f pose = Eigen::Isometry3f::Identity();
            methods.push_back(run_method(
                "bullet", s, poses, false,
                [&](size_t k) {
                    set_pose(k);
                    pose = s.poses[k];
                    const Eigen::Matrix3f rm = pose.linear();
                    ins_bt.setBasis(btMatrix3x3(rm(0, 0), rm(0, 1), rm(0, 2), rm(1, 0), rm(1, 1), rm(1, 2), rm(2, 0),
                                                rm(2, 1), rm(2, 2)));
                    ins_bt.setOrigin(btVector3(pose.translation().x(), pose.translation().y(), pose.translation().z()));
                },
                [&](size_t) {
                    mem_part.postUpdate();
                    mem_part.updateBound();  // refit
                    pairs.clear();
                    btGImpactQuantizedBvh::find_collision(mem_part.getBoxSet(), ident, ins_part.getBoxSet(), ins_bt,
                                                          pairs);
                    for (size_t i = 0; i < ins_local.size(); ++i) ins_eye[i] = pose * ins_local[i];
                    got.clear();
                    ++q;
                    for (int k = 0; k < pairs.size(); ++k) {
                        const uint32_t mt = uint32_t(pairs[k].m_index1);
                        if (stamp[mt] == q) continue;
                        const auto& a = mem.triangles[mt];
                        const auto& b = ins.mesh.triangles[size_t(pairs[k].m_index2)];
                        if (triangles_intersect(verts[a[0]], verts[a[1]], verts[a[2]], ins_eye[b[0]], ins_eye[b[1]],
                                                ins_eye[b[2]])) {
                            stamp[mt] = q;
                            got.push_back(mt);
                        }
                    }
                    return std::span<const uint32_t>(got);
                }));
        }

        // --- FCL: BVHModel<OBBRSS> of the membrane refitted per query (bottom-up), collide against the forceps'
        // model reporting every colliding triangle pair (surface intersections only). The float → double copy of
        // the vertices is untimed.
        if (want("fcl")) {
            using Model = fcl::BVHModel<fcl::OBBRSSd>;
            std::vector<fcl::Triangle> mem_tris, ins_tris;
            for (const auto& t : mem.triangles) mem_tris.emplace_back(t[0], t[1], t[2]);
            for (const auto& t : ins.mesh.triangles) ins_tris.emplace_back(t[0], t[1], t[2]);
            std::vector<fcl::Vector3d> ins_d(ins_local.size()), mem_d(verts.size());
            for (size_t i = 0; i < ins_local.size(); ++i) ins_d[i] = ins_local[i].cast<double>();
            for (size_t i = 0; i < verts.size(); ++i) mem_d[i] = verts[i].cast<double>();
            auto ins_model = std::make_shared<Model>(), mem_model = std::make_shared<Model>();
            ins_model->beginModel();
            ins_model->addSubModel(ins_d, ins_tris);
            ins_model->endModel();
            mem_model->beginModel();
            mem_model->addSubModel(mem_d, mem_tris);
            mem_model->endModel();
            fcl::Transform3d ins_tf = fcl::Transform3d::Identity();
            fcl::CollisionRequestd req(100000, false);
            fcl::CollisionResultd res;
            std::vector<uint32_t> got;
            got.reserve(100000);
            methods.push_back(run_method(
                "fcl", s, fcl_poses, false,
                [&](size_t k) {
                    set_pose(k);
                    for (size_t i = 0; i < verts.size(); ++i) mem_d[i] = verts[i].cast<double>();
                    ins_tf.linear() = s.poses[k].linear().cast<double>();
                    ins_tf.translation() = s.poses[k].translation().cast<double>();
                },
                [&](size_t) {
                    mem_model->beginUpdateModel();
                    mem_model->updateSubModel(mem_d);
                    mem_model->endUpdateModel(true, true);
                    fcl::CollisionObjectd a(mem_model, fcl::Transform3d::Identity()), b(ins_model, ins_tf);
                    res.clear();
                    fcl::collide(&a, &b, req, res);
                    got.clear();
                    for (size_t k = 0; k < res.numContacts(); ++k) got.push_back(uint32_t(res.getContact(k).b1));
                    return std::span<const uint32_t>(got);
                }));
        }

        // --- ZCOLL through EGL/GLES3 (optional; wall time: the driver may rasterise on other threads).
        if (egl && renderer.rfind("unavailable", 0) != 0) {
            for (int r : {32, 64, 128, 256}) {
                std::string err;
                auto be = eyesim::render::GlesZcollBackend::create(err);
                if (!be) continue;
                ZcollConfig cfg;
                cfg.resolution_px = r;
                ZcollEngine engine(mem, cfg, std::move(be));
                ZcollView view;
                methods.push_back(run_method("zcoll_egl_r" + std::to_string(r), s, egl_poses, true,
                                             [&](size_t k) {
                                                 set_pose(k);
                                                 view = scene_view(s, k, r);
                                             },
                                             [&](size_t) { return engine.push(verts, forceps, view).colliding_triangles; }));
            }
        }

        // --- Report.
        std::vector<double> counts;
        for (const auto& set : s.referee) counts.push_back(double(set.size()));
        nlohmann::json js;
        js["name"] = s.spec.name;
        js["membrane_triangles"] = mem.triangle_count();
        js["poses"] = s.poses.size();
        js["redrawn_without_contact"] = s.redrawn;
        js["nominal"] = {{"approach_deg", s.tilt_deg}, {"tip_below_membrane_mm", s.depth_mm}};
        js["perturbation"] = {{"lateral_mm", s.spec.lateral_mm}, {"normal_mm", s.spec.normal_mm},
                              {"direction_deg", s.spec.direction_deg}};
        js["view_half_width_mm"] = s.half_width_mm;
        auto count_at = [&](double p) { return int(pct(counts, p)); };
        js["colliding"] = {{"min", count_at(0)},   {"p5", count_at(0.05)}, {"median", count_at(0.5)},
                           {"p95", count_at(0.95)}, {"max", count_at(1)}};
        js["methods"] = nlohmann::json::array();
        double exact_p50 = std::nan("");
        for (const MethodResult& m : methods) {
            const double p50 = pct(m.time_us, 0.5), p99 = pct(m.time_us, 0.99);
            if (m.name == "exact") exact_p50 = p50;
            nlohmann::json jm = {
                {"name", m.name},
                {"poses", m.time_us.size()},
                {"clock", m.clock},
                {"recall", {{"min", num(pct(m.recall, 0))}, {"p5", num(pct(m.recall, 0.05))}, {"median", num(pct(m.recall, 0.5))}}},
                {"precision",
                 {{"min", num(pct(m.precision, 0))}, {"p5", num(pct(m.precision, 0.05))}, {"median", num(pct(m.precision, 0.5))}}},
                {"time_us", {{"p50", num(p50)}, {"p99", num(p99)}}}};
            jm["poses_equal_to_referee"] = m.equal;
            jm["poses_equal_to_referee_surface_part"] = m.equal_surface;
            if (m.name.rfind("zcoll", 0) == 0) jm["exact_fallback_poses"] = m.fallbacks;
            js["methods"].push_back(jm);
            const double ratio = m.clock == "wall" ? std::nan("") : p50 / exact_p50;
            table += "| " + s.spec.name + " | " + m.name + " | " + std::to_string(m.time_us.size()) + " | " +
                     fixed(pct(m.recall, 0), 3) + " | " + fixed(pct(m.recall, 0.05), 3) + " | " +
                     fixed(pct(m.recall, 0.5), 3) + " | " + fixed(pct(m.precision, 0), 3) + " | " +
                     fixed(pct(m.precision, 0.05), 3) + " | " + fixed(pct(m.precision, 0.5), 3) + " | " +
                     fixed(p50, 1) + " | " + fixed(p99, 1) + " | " + (m.clock == "wall" ? "– (wall)" : fixed(ratio, 2)) +
                     " | " + std::to_string(m.equal) + " | " + std::to_string(m.equal_surface) + " |\n";
        }
        out["scenes"].push_back(js);
        if (!json) {
            std::fprintf(stderr, "scene %zu of %zu done\n", si + 1, specs.size());
        }
    }
    const std::string load_end = load_average();
    out["load_average"] = {{"start", load_start}, {"end", load_end}};
    if (json) {
        std::printf("%s\n", out.dump(2).c_str());
        return 0;
    }
    std::printf("# eyesim collision benchmark\n\nforceps %zu triangles, jaws open 30°; %d poses per scene (FCL: %d), "
                "seed %llu; load average %s at the start, %s at the end; EGL renderer: %s\n\n",
                ins.mesh.triangle_count(), poses, fcl_poses, static_cast<unsigned long long>(seed), load_start.c_str(),
                load_end.c_str(), renderer.c_str());
    for (const auto& js : out["scenes"]) {
        const auto& c = js["colliding"];
        std::printf("- %s: %d triangles; nominal approach %.0f° from the normal, tip %.3f mm below the membrane; "
                    "poses: tip ±%.2f mm across, ±%.2f mm along the normal, axis ≤ %.0f°; %d redrawn without "
                    "contact; V ±%.2f mm; colliding triangles min %d, p5 %d, median %d, p95 %d, max %d\n",
                    js["name"].get<std::string>().c_str(), js["membrane_triangles"].get<int>(),
                    js["nominal"]["approach_deg"].get<double>(), js["nominal"]["tip_below_membrane_mm"].get<double>(),
                    js["perturbation"]["lateral_mm"].get<double>(), js["perturbation"]["normal_mm"].get<double>(),
                    js["perturbation"]["direction_deg"].get<double>(), js["redrawn_without_contact"].get<int>(),
                    js["view_half_width_mm"].get<double>(), c["min"].get<int>(), c["p5"].get<int>(), c["median"].get<int>(),
                    c["p95"].get<int>(), c["max"].get<int>());
    }
    std::printf("\n| scene | method | poses | recall min | recall p5 | recall median | precision min | precision p5 "
                "| precision median | time p50 µs | time p99 µs | p50 ÷ exact's | poses = referee | poses = surface part |\n"
                "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n%s",
                table.c_str());
    std::printf("\nrecall/precision: colliding membrane triangles of each query against the referee on that query's "
                "pose and vertices (brute-force double-precision triangle–triangle tests plus triangles inside a "
                "closed part of the instrument, by winding number); precision over poses where the method found "
                "anything. Time: thread CPU per query (wall for EGL rows). Last columns: poses on which the "
                "method's set equals the referee's exactly, and equals its surface part (the triangles meeting an "
                "instrument triangle; FCL and Bullet report only these).\n");
    return 0;
}
