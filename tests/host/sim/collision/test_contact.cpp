// ExactContact: deformation values against analytic shapes (sphere, capsule, box), the colliding set and the
// deformation values against an independent brute-force double-precision referee over random poses of the
// benchmark's forceps scenes (1k and 3k membranes, ~40 and ~200 colliding triangles),
// the grab rule, bad input and allocation-free queries.

#include "eyesim/sim/collision/contact.hpp"
#include "eyesim/sim/collision/exact.hpp"

#include "alloc_counter.hpp"
#include "shapes.hpp"

#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <random>

using namespace eyesim::sim;
using namespace eyesim::sim::collision;
using namespace eyesim::sim::collision::testing;

namespace {

using V3 = Eigen::Vector3d;
constexpr double kInfD = std::numeric_limits<double>::infinity();

// ---------------------------------------------------------------------------------------------------------------
// Closed test bodies (outward normals) and the analytic entry of a line into them.

/// Closed surface of revolution about +z: `profile` = (radius, z) from the bottom pole (radius 0) to the top pole
/// (radius 0); the same winding as shapes.hpp's UV sphere (outward normals).
void append_lathe(TriangleMesh& m, const std::vector<std::pair<float, float>>& profile, int segments) {
    const uint32_t base = uint32_t(m.vertices_mm.size());
    const int rings = int(profile.size()) - 1;  // ring indices 1 .. rings-1 are circles
    m.vertices_mm.push_back(Vec3f(0, 0, profile.front().second));
    for (int i = 1; i < rings; ++i)
        for (int s = 0; s < segments; ++s) {
            const float az = 2 * kPi * float(s) / float(segments);
            m.vertices_mm.push_back(
                Vec3f(profile[size_t(i)].first * std::cos(az), profile[size_t(i)].first * std::sin(az), profile[size_t(i)].second));
        }
    m.vertices_mm.push_back(Vec3f(0, 0, profile.back().second));
    close_rings(m, base, rings, segments);
}

/// Capsule along z: radius r, cylinder from z = −half to +half, hemispherical caps; `cap_rings` per cap.
TriangleMesh capsule_mesh(float r, float half, int cap_rings, int segments) {
    std::vector<std::pair<float, float>> p;
    for (int i = 0; i <= cap_rings; ++i) {  // bottom cap: pole → equator
        const float th = 0.5f * kPi * float(i) / float(cap_rings);
        p.emplace_back(r * std::sin(th), -half - r * std::cos(th));
    }
    for (int i = cap_rings; i >= 0; --i) {  // top cap: equator → pole
        const float th = 0.5f * kPi * float(i) / float(cap_rings);
        p.emplace_back(r * std::sin(th), half + r * std::cos(th));
    }
    TriangleMesh m;
    append_lathe(m, p, segments);
    return m;
}

/// Box of half extents h centred on the origin (12 triangles, outward normals).
TriangleMesh box_mesh(const Vec3f& h) {
    TriangleMesh m;
    for (int i = 0; i < 8; ++i)
        m.vertices_mm.push_back(Vec3f((i & 1) ? h.x() : -h.x(), (i & 2) ? h.y() : -h.y(), (i & 4) ? h.z() : -h.z()));
    // Faces as quads (counter-clockwise seen from outside).
    const uint32_t q[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
    for (const auto& f : q) {
        m.triangles.push_back({f[0], f[1], f[2]});
        m.triangles.push_back({f[0], f[2], f[3]});
    }
    return m;
}

/// Signed volume of a closed mesh (> 0 for outward normals).
double signed_volume(const TriangleMesh& m) {
    double v = 0;
    for (const auto& t : m.triangles)
        v += m.vertices_mm[t[0]].cast<double>().dot(m.vertices_mm[t[1]].cast<double>().cross(m.vertices_mm[t[2]].cast<double>()));
    return v / 6.0;
}

/// Entry parameter of the line p + t·d (d unit) into a sphere; +inf when it misses.
double sphere_entry(const V3& p, const V3& d, const V3& c, double r) {
    const V3 m = p - c;
    const double b = m.dot(d), cc = m.squaredNorm() - r * r, disc = b * b - cc;
    return disc < 0 ? kInfD : -b - std::sqrt(disc);
}

/// Entry into a capsule (segment a–b, radius r): the earliest entry into its cylinder (within the segment's
/// slab) or its two end spheres (each convex, so the union's entry is the smallest).
double capsule_entry(const V3& p, const V3& d, const V3& a, const V3& b, double r) {
    double best = std::min(sphere_entry(p, d, a, r), sphere_entry(p, d, b, r));
    const double len = (b - a).norm();
    const V3 ax = (b - a) / len, m = p - a;
    const V3 dp = d - d.dot(ax) * ax, mp = m - m.dot(ax) * ax;
    const double A = dp.squaredNorm(), B = mp.dot(dp), C = mp.squaredNorm() - r * r;
    if (A > 1e-14 && B * B - A * C >= 0) {
        const double t = (-B - std::sqrt(B * B - A * C)) / A;
        const double h = (m + t * d).dot(ax);
        if (h >= 0 && h <= len) best = std::min(best, t);
    }
    return best;
}

/// Entry into an oriented box (centre c, axes = columns of rot, half extents h): slabs.
double box_entry(const V3& p, const V3& d, const V3& c, const Eigen::Matrix3d& rot, const V3& h) {
    const V3 o = rot.transpose() * (p - c), dir = rot.transpose() * d;
    double t0 = -kInfD, t1 = kInfD;
    for (int k = 0; k < 3; ++k) {
        if (std::fabs(dir[k]) < 1e-15) {
            if (std::fabs(o[k]) > h[k]) return kInfD;
            continue;
        }
        double a = (-h[k] - o[k]) / dir[k], b = (h[k] - o[k]) / dir[k];
        if (a > b) std::swap(a, b);
        t0 = std::max(t0, a);
        t1 = std::min(t1, b);
    }
    return t0 <= t1 ? t0 : kInfD;
}

// ---------------------------------------------------------------------------------------------------------------
// Independent brute-force referee (double precision): separating axes for every pair + ray parity per part.

/// Closed triangles intersect (touching counts) iff no separating axis among the two normals, the nine edge
/// cross products and the six in-plane edge normals (coplanar pairs).
bool sat_intersect(const V3* a, const V3* b) {
    const V3 na = (a[1] - a[0]).cross(a[2] - a[0]), nb = (b[1] - b[0]).cross(b[2] - b[0]);
    V3 axes[17];
    int n = 0;
    axes[n++] = na;
    axes[n++] = nb;
    for (int i = 0; i < 3; ++i) {
        const V3 ea = a[(i + 1) % 3] - a[i];
        for (int j = 0; j < 3; ++j) axes[n++] = ea.cross(b[(j + 1) % 3] - b[j]);
        axes[n++] = na.cross(ea);
        axes[n++] = nb.cross(b[(i + 1) % 3] - b[i]);
    }
    for (int k = 0; k < n; ++k) {
        const V3& l = axes[k];
        if (l.squaredNorm() < 1e-24) continue;
        double alo = kInfD, ahi = -kInfD, blo = kInfD, bhi = -kInfD;
        for (int i = 0; i < 3; ++i) {
            const double pa = l.dot(a[i]), pb = l.dot(b[i]);
            alo = std::min(alo, pa);
            ahi = std::max(ahi, pa);
            blo = std::min(blo, pb);
            bhi = std::max(bhi, pb);
        }
        if (ahi < blo || bhi < alo) return false;
    }
    return true;
}

/// Ray parity along a fixed skew direction over one closed part (double).
bool inside_part_ref(const V3& p, const std::vector<V3>& iv, std::span<const std::array<uint32_t, 3>> tris) {
    const V3 d = V3(0.3717, 0.5571, 0.7425).normalized();
    int crossings = 0;
    for (const auto& t : tris) {
        const V3 e1 = iv[t[1]] - iv[t[0]], e2 = iv[t[2]] - iv[t[0]], h = d.cross(e2);
        const double det = e1.dot(h);
        if (std::fabs(det) < 1e-20) continue;
        const V3 s = p - iv[t[0]], q = s.cross(e1);
        const double u = s.dot(h) / det, v = d.dot(q) / det;
        if (u < 0 || v < 0 || u + v > 1) continue;
        if (e2.dot(q) / det > 0) ++crossings;
    }
    return (crossings & 1) != 0;
}

/// The exact colliding set by brute force: the membrane is moved into the instrument frame in double, every
/// membrane triangle whose bounds meet a part's bounds is tested against every triangle of that part whose
/// bounds it meets (separating axes), and a triangle touching none is inside iff its first vertex is.
std::vector<uint32_t> referee_set(const TriangleMesh& membrane, const std::vector<Vec3f>& verts_eye,
                                  const PosedInstrument& ins) {
    const Instrument& I = ins.instrument();
    std::vector<V3> iv(ins.vertices_local_mm().size());
    for (size_t i = 0; i < iv.size(); ++i) iv[i] = ins.vertices_local_mm()[i].cast<double>();
    const Eigen::Isometry3d to_eye = ins.instrument_to_eye().cast<double>();
    const Eigen::Isometry3d to_local = to_eye.inverse();
    std::vector<V3> mv(verts_eye.size());
    for (size_t i = 0; i < mv.size(); ++i) mv[i] = to_local * verts_eye[i].cast<double>();
    const size_t nit = I.mesh.triangles.size();
    std::vector<V3> tlo(nit), thi(nit);
    for (size_t t = 0; t < nit; ++t) {
        const auto& tr = I.mesh.triangles[t];
        tlo[t] = iv[tr[0]].cwiseMin(iv[tr[1]]).cwiseMin(iv[tr[2]]);
        thi[t] = iv[tr[0]].cwiseMax(iv[tr[1]]).cwiseMax(iv[tr[2]]);
    }
    std::vector<uint32_t> parts = I.part_triangle_begin;
    if (parts.size() < 2) parts = {0u, uint32_t(nit)};
    const size_t np = parts.size() - 1;
    std::vector<V3> plo(np, V3::Constant(kInfD)), phi(np, V3::Constant(-kInfD));
    for (size_t p = 0; p < np; ++p)
        for (uint32_t t = parts[p]; t < parts[p + 1]; ++t) {
            plo[p] = plo[p].cwiseMin(tlo[t]);
            phi[p] = phi[p].cwiseMax(thi[t]);
        }
    std::vector<uint32_t> out;
    for (uint32_t mt = 0; mt < membrane.triangles.size(); ++mt) {
        const auto& tr = membrane.triangles[mt];
        const V3 a[3] = {mv[tr[0]], mv[tr[1]], mv[tr[2]]};
        const V3 lo = a[0].cwiseMin(a[1]).cwiseMin(a[2]), hi = a[0].cwiseMax(a[1]).cwiseMax(a[2]);
        bool hit = false, near_part = false;
        for (size_t p = 0; p < np && !hit; ++p) {
            if ((hi.array() < plo[p].array()).any() || (lo.array() > phi[p].array()).any()) continue;
            near_part = true;
            for (uint32_t t = parts[p]; t < parts[p + 1] && !hit; ++t) {
                if ((hi.array() < tlo[t].array()).any() || (lo.array() > thi[t].array()).any()) continue;
                const auto& q = I.mesh.triangles[t];
                const V3 b[3] = {iv[q[0]], iv[q[1]], iv[q[2]]};
                hit = sat_intersect(a, b);
            }
        }
        for (size_t p = 0; p < np && !hit && near_part; ++p) {
            if ((lo.array() < plo[p].array()).any() || (hi.array() > phi[p].array()).any()) continue;
            hit = inside_part_ref(a[0], iv, std::span(I.mesh.triangles).subspan(parts[p], parts[p + 1] - parts[p]));
        }
        if (hit) out.push_back(mt);
    }
    return out;
}

/// Front-most instrument surface on the line p + t·π (brute force, double): the smallest t of any crossing.
double ray_front(const V3& p, const V3& pi, const PosedInstrument& ins) {
    const Eigen::Isometry3d to_eye = ins.instrument_to_eye().cast<double>();
    double best = kInfD;
    for (const auto& t : ins.instrument().mesh.triangles) {
        const V3 v0 = to_eye * ins.vertices_local_mm()[t[0]].cast<double>();
        const V3 e1 = to_eye * ins.vertices_local_mm()[t[1]].cast<double>() - v0;
        const V3 e2 = to_eye * ins.vertices_local_mm()[t[2]].cast<double>() - v0;
        const V3 h = pi.cross(e2);
        const double det = e1.dot(h);
        if (std::fabs(det) < 1e-20) continue;
        const V3 s = p - v0, q = s.cross(e1);
        const double u = s.dot(h) / det, v = pi.dot(q) / det;
        if (u < 0 || v < 0 || u + v > 1) continue;
        best = std::min(best, e2.dot(q) / det);
    }
    return best;
}

// ---------------------------------------------------------------------------------------------------------------
// The benchmark's scenes: bench_collision's pose search with the project's functions.

Eigen::Isometry3f bench_pose(float tilt_deg, float depth_mm) {
    const float a = tilt_deg * kPi / 180.0f;
    Eigen::Isometry3f t = Eigen::Isometry3f::Identity();
    const Vec3f z = Vec3f(std::sin(a), 0.0f, -std::cos(a)).normalized();
    const Vec3f y = z.cross(std::fabs(z.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY()).normalized();
    t.linear().col(0) = y.cross(z);
    t.linear().col(1) = y;
    t.linear().col(2) = z;
    t.translation() = Vec3f(0.11f, 0.07f, -depth_mm);
    return t;
}

size_t grid_count(const TriangleMesh& m, const PosedInstrument& ins) {
    ExactNarrowPhase exact(m.triangle_count(), ins.instrument().mesh.triangle_count());
    const MeshRef mr{m.vertices_mm, m.triangles, Eigen::Isometry3f::Identity()};
    const MeshRef tr{ins.vertices_local_mm(), ins.instrument().mesh.triangles, ins.instrument_to_eye()};
    ExactOptions opt;
    opt.vertex_triangle_begin = m.vertex_triangle_begin;
    opt.vertex_triangles = m.vertex_triangles;
    return exact.colliding_triangles(mr, tr, ins.instrument().part_triangle_begin, opt).size();
}

/// Smallest approach angle whose push (≤ 1.5 mm) reaches `target` colliding triangles, then the depth by
/// bisection (jaws open 30°), as bench_collision does.
Eigen::Isometry3f calibrate(const TriangleMesh& m, PosedInstrument& forceps, size_t target) {
    float found = -1.0f, tilt = 0.0f;
    for (float tl : {0.0f, 15.0f, 30.0f, 45.0f, 60.0f, 70.0f, 75.0f, 80.0f, 85.0f}) {
        tilt = tl;
        for (float d = 0.02f; d <= 1.5f && found < 0; d += 0.02f) {
            forceps.set_state(30.0f, bench_pose(tl, d));
            if (grid_count(m, forceps) >= target) found = d;
        }
        if (found >= 0) break;
    }
    if (found < 0) found = 1.5f;
    float lo = std::max(0.0f, found - 0.02f), hi = found;
    for (int it = 0; it < 16; ++it) {
        const float mid = 0.5f * (lo + hi);
        forceps.set_state(30.0f, bench_pose(tilt, mid));
        (grid_count(m, forceps) < target ? lo : hi) = mid;
    }
    return bench_pose(tilt, hi);
}

double percentile(std::vector<double> v, double q) {
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, size_t(q * double(v.size())))];
}

/// Random poses around each benchmark scene's contact, scored against the referee; `poses` per scene.
void referee_poses(int poses, uint32_t seed) {
    PosedInstrument forceps(make_forceps());
    struct Def {
        const char* name;
        PatchSize patch;
        size_t target;
    };
    for (const Def& d : {Def{"1k, ~40", kPatch1k, 40}, Def{"3k, ~40", kPatch3k, 40}, Def{"3k, dense", kPatch3k, 200}}) {
        const TriangleMesh m = make_membrane_patch(4.0f, 4.0f, d.patch.nx, d.patch.ny);
        const Eigen::Isometry3f base = calibrate(m, forceps, d.target);
        ExactContact contact(m);
        std::mt19937 rng(seed);
        std::uniform_real_distribution<float> lat(-0.05f, 0.05f), dep(-0.03f, 0.03f), ang(-3.0f, 3.0f), roll(-kPi, kPi),
            wave(0.0f, 0.02f);
        std::vector<double> recall, precision;
        size_t identical = 0, colliding_total = 0, depth_checked = 0;
        double worst_depth_um = 0;
        for (int i = 0; i < poses; ++i) {
            const float opening = 20.0f + 5.0f * float(i % 3);
            Eigen::Isometry3f pose = Eigen::Isometry3f::Identity();
            pose.linear() = (Eigen::AngleAxisf(ang(rng) * kPi / 180.0f, Vec3f::UnitX()) *
                             Eigen::AngleAxisf(ang(rng) * kPi / 180.0f, Vec3f::UnitY()))
                                .toRotationMatrix() *
                            base.linear() * Eigen::AngleAxisf(roll(rng), Vec3f::UnitZ()).toRotationMatrix();
            pose.translation() = base.translation() + Vec3f(lat(rng), lat(rng), dep(rng));
            forceps.set_state(opening, pose);
            // The membrane is not flat either: a gentle random wave (up to 20 µm).
            std::vector<Vec3f> verts = m.vertices_mm;
            const float amp = wave(rng), k = 2.0f + 4.0f * wave(rng) * 50.0f;
            for (Vec3f& v : verts) v.z() += amp * std::sin(k * v.x() + 0.7f * v.y());
            const ContactResult& r = contact.query(verts, forceps, Vec3f(0, 0, 1));
            const std::vector<uint32_t> got(r.colliding_triangles.begin(), r.colliding_triangles.end());
            const std::vector<uint32_t> ref = referee_set(m, verts, forceps);
            const size_t common = intersection_size(got, ref);
            recall.push_back(ref.empty() ? 1.0 : double(common) / double(ref.size()));
            precision.push_back(got.empty() ? 1.0 : double(common) / double(got.size()));
            identical += got == ref;
            colliding_total += ref.size();
            // Deformation values against a brute-force ray cast at the reported points (every 10th pose).
            if (i % 10 == 0) {
                REQUIRE(r.contacts.size() == got.size());
                for (const TriangleContact& c : r.contacts) {
                    const double front = ray_front(c.point_eye_mm.cast<double>(), V3(0, 0, 1), forceps);
                    const double expect = std::min(0.0, front);
                    worst_depth_um = std::max(worst_depth_um, 1e3 * std::fabs(double(c.depth_delta_mm) - expect));
                    ++depth_checked;
                }
            }
        }
        INFO(d.name << ": recall p5 " << percentile(recall, 0.05) << " min "
                    << *std::min_element(recall.begin(), recall.end()) << ", precision p5 "
                    << percentile(precision, 0.05) << " min " << *std::min_element(precision.begin(), precision.end())
                    << ", identical sets " << identical << " / " << poses << ", mean colliding "
                    << double(colliding_total) / poses << ", worst depth error " << worst_depth_um << " um over "
                    << depth_checked);
        CHECK(percentile(recall, 0.05) >= 0.99);
        CHECK(percentile(precision, 0.05) >= 0.99);
        CHECK(double(colliding_total) / poses >= 20.0);  // the poses are in contact
        CHECK(depth_checked > 0);
        CHECK(worst_depth_um <= 1.0);
        WARN(d.name << ": identical sets on " << identical << " of " << poses << " poses; worst depth error "
                    << worst_depth_um << " um");
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Analytic shapes pushed into flat and tilted membranes.

struct AnalyticCase {
    const char* name;
    Instrument body;
    std::function<double(const V3&, const V3&)> entry;  // entry of the line p + t·π into the posed shape
};

/// Checks every colliding triangle's deformation value against the analytic entry at its reported point.
void check_against_analytic(const AnalyticCase& c, const TriangleMesh& membrane, const Eigen::Isometry3f& pose,
                            const Vec3f& pi) {
    PosedInstrument body(c.body);
    body.set_state(0.0f, pose);
    ExactContact contact(membrane);
    const ContactResult& r = contact.query(membrane.vertices_mm, body, pi);
    REQUIRE_FALSE(r.invalid_input);
    REQUIRE(r.contacts.size() == r.colliding_triangles.size());
    INFO(c.name << ", pi " << pi.transpose() << ": " << r.contacts.size() << " colliding triangles");
    REQUIRE(r.contacts.size() >= 20);
    double worst_um = 0, deepest_mm = 0;
    for (const TriangleContact& t : r.contacts) {
        const double expect = std::min(0.0, c.entry(t.point_eye_mm.cast<double>(), pi.cast<double>()));
        worst_um = std::max(worst_um, 1e3 * std::fabs(double(t.depth_delta_mm) - expect));
        deepest_mm = std::min(deepest_mm, double(t.depth_delta_mm));
        // The point is one of the triangle's corners or its centroid.
        const auto& tr = membrane.triangles[t.triangle];
        const Vec3f centroid = (membrane.vertices_mm[tr[0]] + membrane.vertices_mm[tr[1]] + membrane.vertices_mm[tr[2]]) / 3.0f;
        bool on = (t.point_eye_mm - centroid).norm() < 1e-5f;
        for (uint32_t v : tr) on = on || (t.point_eye_mm - membrane.vertices_mm[v]).norm() < 1e-6f;
        CHECK(on);
    }
    INFO("worst |depth − analytic| " << worst_um << " um, deepest " << deepest_mm << " mm");
    CHECK(worst_um <= 5.0);
    WARN(c.name << ", pi " << pi.transpose() << ": " << r.contacts.size() << " colliding, worst |depth - analytic| " << worst_um << " um, deepest " << deepest_mm << " mm");
    CHECK(deepest_mm < -0.05);
    // Eq. 1: every node's push is π times the deepest value of its adjacent colliding triangles.
    std::vector<float> deepest(membrane.vertex_count(), 0.0f);
    for (const TriangleContact& t : r.contacts)
        for (uint32_t v : membrane.triangles[t.triangle]) deepest[v] = std::min(deepest[v], t.depth_delta_mm);
    size_t expected_nodes = 0;
    for (float d : deepest) expected_nodes += d < 0.0f;
    REQUIRE(r.pushed_nodes.size() == expected_nodes);
    for (size_t k = 0; k < r.pushed_nodes.size(); ++k)
        CHECK((r.node_push_eye_mm[k] - pi * deepest[r.pushed_nodes[k]]).norm() < 1e-5f);
}

}  // namespace

TEST_CASE("Exact contact: deformation values match a sphere, a capsule and a box within 5 um", "[collision][contact]") {
    // Bodies in their own frame (tip at the origin, +z forward); each a closed part with outward normals, fine
    // enough that the tessellation is < 0.5 µm from the analytic surface where the membrane meets it.
    const float rs = 0.8f;
    TriangleMesh sphere;
    append_uv_sphere(sphere, Vec3f(0, 0, -rs), rs, 120, 160);
    const float rc = 0.4f, hc = 0.6f;
    TriangleMesh capsule = capsule_mesh(rc, hc, 40, 160);
    const Vec3f hb(0.5f, 0.3f, 0.25f);
    TriangleMesh box = box_mesh(hb);
    for (const TriangleMesh* m : {&sphere, &capsule, &box}) REQUIRE(signed_volume(*m) > 0.0);
    CHECK(signed_volume(box) == Approx(8.0 * hb.x() * hb.y() * hb.z()).epsilon(1e-5));

    // Poses: the sphere straight down, the capsule lying slanted, the box on a corner; each 0.2–0.3 mm deep.
    const Eigen::Isometry3f sphere_pose = pose_at(Vec3f(0.031f, 0.017f, -0.3f), Vec3f(0, 0, -1));
    Eigen::Isometry3f capsule_pose = Eigen::Isometry3f::Identity();
    capsule_pose.linear() = (Eigen::AngleAxisf(0.35f, Vec3f::UnitZ()) * Eigen::AngleAxisf(0.5f * kPi - 0.17f, Vec3f::UnitY()))
                                .toRotationMatrix();
    Eigen::Isometry3f box_pose = Eigen::Isometry3f::Identity();
    box_pose.linear() = (Eigen::AngleAxisf(0.26f, Vec3f::UnitZ()) * Eigen::AngleAxisf(0.35f, Vec3f::UnitY()) *
                         Eigen::AngleAxisf(0.52f, Vec3f::UnitX()))
                            .toRotationMatrix();
    // Lowest points 0.25 mm (capsule) and 0.2 mm (box) below z = 0.
    {
        const Vec3f a = capsule_pose.linear() * Vec3f(0, 0, -hc), b = capsule_pose.linear() * Vec3f(0, 0, hc);
        capsule_pose.translation() = Vec3f(-0.04f, 0.06f, rc - 0.25f - std::min(a.z(), b.z()));
        float low = 1e9f;
        for (int i = 0; i < 8; ++i)
            low = std::min(low, (box_pose.linear() * Vec3f((i & 1) ? hb.x() : -hb.x(), (i & 2) ? hb.y() : -hb.y(),
                                                            (i & 4) ? hb.z() : -hb.z()))
                                    .z());
        box_pose.translation() = Vec3f(0.05f, -0.02f, -0.2f - low);
    }
    const Eigen::Isometry3d sp = sphere_pose.cast<double>(), cp = capsule_pose.cast<double>(), bp = box_pose.cast<double>();
    std::vector<AnalyticCase> cases;
    cases.push_back({"sphere", make_rigid_instrument(sphere), [&](const V3& p, const V3& d) {
                         return sphere_entry(p, d, sp * V3(0, 0, -rs), rs);
                     }});
    cases.push_back({"capsule", make_rigid_instrument(capsule), [&](const V3& p, const V3& d) {
                         return capsule_entry(p, d, cp * V3(0, 0, -hc), cp * V3(0, 0, hc), rc);
                     }});
    cases.push_back({"box", make_rigid_instrument(box), [&](const V3& p, const V3& d) {
                         return box_entry(p, d, bp.translation(), bp.linear(), hb.cast<double>());
                     }});
    const Eigen::Isometry3f poses[3] = {sphere_pose, capsule_pose, box_pose};

    SECTION("flat membrane, pi along its normal") {
        const TriangleMesh flat = make_membrane_patch(4.0f, 4.0f, kPatch3k.nx, kPatch3k.ny);
        for (size_t i = 0; i < cases.size(); ++i) check_against_analytic(cases[i], flat, poses[i], Vec3f(0, 0, 1));
    }
    SECTION("tilted membrane, pi along its normal and along the approach axis") {
        // The membrane turned 20° about (1, 1, 0) through the origin; the bodies stay where they are.
        TriangleMesh tilted = make_membrane_patch(4.0f, 4.0f, kPatch3k.nx, kPatch3k.ny);
        const Eigen::Matrix3f rot = Eigen::AngleAxisf(20.0f * kPi / 180.0f, Vec3f(1, 1, 0).normalized()).toRotationMatrix();
        for (Vec3f& v : tilted.vertices_mm) v = rot * v;
        const Vec3f normal = rot * Vec3f::UnitZ();
        for (size_t i = 0; i < cases.size(); ++i) {
            check_against_analytic(cases[i], tilted, poses[i], normal);
            check_against_analytic(cases[i], tilted, poses[i], Vec3f(0, 0, 1));
        }
    }
}

TEST_CASE("Exact contact: colliding sets and depths against a brute-force double referee, 1000 random forceps poses "
          "per scene", "[collision][contact]") {
    referee_poses(1000, 7);
}

TEST_CASE("Exact contact: 5000 further random forceps poses per scene against the referee",
          "[collision][contact][stress]") {
    referee_poses(5000, 11);
}

TEST_CASE("Exact contact: grab rule, bad input, a membrane out of reach", "[collision][contact]") {
    const TriangleMesh m = make_membrane_patch(4.0f, 4.0f, kPatch1k.nx, kPatch1k.ny);
    PosedInstrument forceps(make_forceps());
    ExactContact contact(m);
    const Eigen::Isometry3f pose = pose_at(Vec3f(0.1f, 0.05f, -0.4f), Vec3f(0.3f, 0.0f, -1.0f));

    SECTION("closed jaws bind the colliding nodes and the nodes near the tip, no pushes") {
        forceps.set_state(0.0f, pose);
        ContactOptions opt;
        opt.grab = true;
        opt.grab_tip_eye_mm = forceps.tip_eye_mm();
        opt.grab_radius_mm = 0.3f;
        const ContactResult& r = contact.query(m.vertices_mm, forceps, Vec3f(0, 0, 1), opt);
        REQUIRE(r.colliding);
        REQUIRE(r.grabbed);
        CHECK(r.pushed_nodes.empty());
        std::vector<uint32_t> expect;
        for (uint32_t t : r.colliding_triangles) expect.insert(expect.end(), m.triangles[t].begin(), m.triangles[t].end());
        for (uint32_t v = 0; v < m.vertex_count(); ++v)
            if ((m.vertices_mm[v] - forceps.tip_eye_mm()).norm() <= 0.3f) expect.push_back(v);
        std::sort(expect.begin(), expect.end());
        expect.erase(std::unique(expect.begin(), expect.end()), expect.end());
        CHECK(std::vector<uint32_t>(r.grabbed_nodes.begin(), r.grabbed_nodes.end()) == expect);
    }
    SECTION("a vertex span of another size is refused") {
        forceps.set_state(30.0f, pose);
        const std::vector<Vec3f> fewer(m.vertices_mm.begin(), m.vertices_mm.end() - 1);
        const ContactResult& r = contact.query(fewer, forceps, Vec3f(0, 0, 1));
        CHECK(r.invalid_input);
        CHECK_FALSE(r.colliding);
        CHECK(r.colliding_triangles.empty());
    }
    SECTION("an instrument 1 mm above the membrane touches nothing") {
        forceps.set_state(30.0f, pose_at(Vec3f(0.1f, 0.05f, 1.0f), Vec3f(0, 0, -1)));
        const ContactResult& r = contact.query(m.vertices_mm, forceps, Vec3f(0, 0, 1));
        CHECK_FALSE(r.invalid_input);
        CHECK_FALSE(r.colliding);
        CHECK(r.candidate_triangles == 0);
    }
}

TEST_CASE("Exact contact: queries on a known instrument allocate nothing", "[collision][contact]") {
    TriangleMesh m = make_membrane_patch(4.0f, 4.0f, kPatch3k.nx, kPatch3k.ny);
    PosedInstrument forceps(make_forceps());
    ExactContact contact(m);
    std::vector<Vec3f> verts = m.vertices_mm;
    long allocations = 0;
    size_t contacts = 0;
    // The same 60 queries twice: the first pass lets the buffers grow to this sequence's largest contact and both
    // openings' grids, the second must not allocate.
    for (int pass = 0; pass < 2; ++pass) {
        std::mt19937 rng(5);
        std::uniform_real_distribution<float> u(-0.2f, 0.2f);
        for (int i = 0; i < 60; ++i) {
            forceps.set_state((i & 1) ? 30.0f : 10.0f,
                              pose_at(Vec3f(u(rng), u(rng), -0.5f + u(rng)), Vec3f(u(rng), u(rng), -1.0f)));
            for (size_t v = 0; v < verts.size(); ++v)
                verts[v].z() = 0.05f * std::sin(float(i) * 0.3f + verts[v].x() * 3.0f);
            const long before = allocation_count();
            const ContactResult& r = contact.query(verts, forceps, Vec3f(0, 0, 1));
            if (pass == 1) {
                allocations += allocation_count() - before;
                contacts += r.contacts.size();
            }
        }
    }
    CHECK(contacts > 100);
    CHECK(allocations == 0);
}

TEST_CASE("Exact contact: a turning jaw keeps its grid, a part that deforms gets a new one, the sets stay the "
          "referee's", "[collision][contact]") {
    const TriangleMesh m = make_membrane_patch(4.0f, 4.0f, kPatch3k.nx, kPatch3k.ny);
    PosedInstrument forceps(make_forceps());
    const Eigen::Isometry3f base = calibrate(m, forceps, 200);
    ExactContact contact(m);
    forceps.set_state(30.0f, base);
    CHECK(contact.query(m.vertices_mm, forceps, Vec3f(0, 0, 1)).rebuilt);

    // The pedal moves the jaws between queries (0–60°, far from the opening the grids were built at), the pose
    // moves a little: the jaws are refitted, never rebuilt, and every set equals the brute-force referee's.
    std::mt19937 rng(23);
    std::uniform_real_distribution<float> open(0.0f, 60.0f), lat(-0.03f, 0.03f);
    size_t equal = 0, colliding = 0;
    const int poses = 40;
    for (int i = 0; i < poses; ++i) {
        Eigen::Isometry3f pose = base;
        pose.translation() += Vec3f(lat(rng), lat(rng), lat(rng));
        forceps.set_state(open(rng), pose);
        const ContactResult& r = contact.query(m.vertices_mm, forceps, Vec3f(0, 0, 1));
        CHECK_FALSE(r.rebuilt);
        CHECK(r.refit_parts == 2);  // the two jaws; the shaft did not move
        const std::vector<uint32_t> got(r.colliding_triangles.begin(), r.colliding_triangles.end());
        equal += got == referee_set(m, m.vertices_mm, forceps);
        colliding += got.size();
    }
    CHECK(equal == size_t(poses));
    CHECK(colliding >= 100u * poses);  // dense contact: the jaws are in it
    // The same opening again: nothing moved in the instrument frame.
    CHECK(contact.query(m.vertices_mm, forceps, Vec3f(0, 0, 1)).refit_parts == 0);

    // One jaw 40 % wider (not a rigid motion): its grid is rebuilt and the set follows the new shape.
    const std::span<const uint32_t> before = contact.query(m.vertices_mm, forceps, Vec3f(0, 0, 1)).colliding_triangles;
    const std::vector<uint32_t> plain(before.begin(), before.end());
    Instrument wide = make_forceps();
    for (size_t v = 0; v < wide.mesh.vertices_mm.size(); ++v)
        if (wide.vertex_part[v] == InstrumentPart::JawA) wide.mesh.vertices_mm[v].x() *= 1.4f;
    PosedInstrument wide_forceps(std::move(wide));
    wide_forceps.set_state(forceps.opening_deg(), forceps.instrument_to_eye());
    const ContactResult& r = contact.query(m.vertices_mm, wide_forceps, Vec3f(0, 0, 1));
    CHECK(r.rebuilt);
    CHECK(r.refit_parts == 0);
    const std::vector<uint32_t> got(r.colliding_triangles.begin(), r.colliding_triangles.end());
    CHECK(got == referee_set(m, m.vertices_mm, wide_forceps));
    CHECK(got != plain);
}
