#pragma once
// Test geometry: closed bodies for the paper's Fig. 7 situations, poses, a folded membrane, brute-force truth.

#include "eyesim/sim/collision/instrument.hpp"
#include "eyesim/sim/collision/tri_tri.hpp"
#include "eyesim/sim/mesh.hpp"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <vector>

namespace eyesim::sim::collision::testing {

inline constexpr float kPi = 3.14159265358979f;

/// Triangles of a closed body of revolution whose vertices from `base` on are: the bottom pole, rings 1 .. rings-1
/// of `segments` vertices each, the top pole (the last vertex); outward normals.
inline void close_rings(TriangleMesh& m, uint32_t base, int rings, int segments) {
    const uint32_t top = uint32_t(m.vertices_mm.size() - 1);
    auto id = [&](int ring, int s) { return base + 1 + uint32_t((ring - 1) * segments + (s % segments)); };
    for (int s = 0; s < segments; ++s) m.triangles.push_back({base, id(1, s + 1), id(1, s)});
    for (int i = 1; i < rings - 1; ++i)
        for (int s = 0; s < segments; ++s) {
            m.triangles.push_back({id(i, s), id(i, s + 1), id(i + 1, s + 1)});
            m.triangles.push_back({id(i, s), id(i + 1, s + 1), id(i + 1, s)});
        }
    for (int s = 0; s < segments; ++s) m.triangles.push_back({top, id(rings - 1, s), id(rings - 1, s + 1)});
}

/// Closed UV sphere (radius r, centre c), outward normals.
inline void append_uv_sphere(TriangleMesh& m, const Vec3f& c, float r, int rings, int segments,
                             const Vec3f& scale = Vec3f(1, 1, 1)) {
    const uint32_t base = uint32_t(m.vertices_mm.size());
    m.vertices_mm.push_back(c + Vec3f(0, 0, -r).cwiseProduct(scale));
    for (int i = 1; i < rings; ++i) {
        const float th = kPi * float(i) / float(rings);
        for (int s = 0; s < segments; ++s) {
            const float az = 2 * kPi * float(s) / float(segments);
            m.vertices_mm.push_back(
                c + Vec3f(r * std::sin(th) * std::cos(az), r * std::sin(th) * std::sin(az), -r * std::cos(th))
                        .cwiseProduct(scale));
        }
    }
    m.vertices_mm.push_back(c + Vec3f(0, 0, r).cwiseProduct(scale));
    close_rings(m, base, rings, segments);
}

/// Closed torus around the z axis through c (major R, minor r), rotated by `rot`.
inline void append_torus(TriangleMesh& m, const Vec3f& c, const Eigen::Matrix3f& rot, float big_r, float r, int n_major,
                         int n_minor) {
    const uint32_t base = uint32_t(m.vertices_mm.size());
    for (int i = 0; i < n_major; ++i) {
        const float u = 2 * kPi * float(i) / float(n_major);
        for (int j = 0; j < n_minor; ++j) {
            const float v = 2 * kPi * float(j) / float(n_minor);
            const Vec3f p((big_r + r * std::cos(v)) * std::cos(u), (big_r + r * std::cos(v)) * std::sin(u),
                          r * std::sin(v));
            m.vertices_mm.push_back(c + rot * p);
        }
    }
    auto id = [&](int i, int j) { return base + uint32_t((i % n_major) * n_minor + (j % n_minor)); };
    for (int i = 0; i < n_major; ++i)
        for (int j = 0; j < n_minor; ++j) {
            m.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
            m.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
        }
}

/// Sphere "instrument": the tip (origin) is the front-most point, the centre at (0, 0, −r).
inline Instrument sphere_body(float r, int rings = 48, int segments = 64) {
    TriangleMesh m;
    append_uv_sphere(m, Vec3f(0, 0, -r), r, rings, segments);
    return make_rigid_instrument(std::move(m));
}

/// Teapot-like non-convex body (squashed sphere body, torus handle, ellipsoidal spout, lid knob), three
/// overlapping closed parts; its front (+z) is the bottom of the pot.
inline Instrument teapot_body() {
    TriangleMesh m;
    std::vector<uint32_t> parts{0};
    append_uv_sphere(m, Vec3f(0, 0, -0.7f), 1.0f, 32, 48, Vec3f(1.0f, 1.0f, 0.7f));
    parts.push_back(uint32_t(m.triangle_count()));
    Eigen::Matrix3f rot = Eigen::AngleAxisf(0.5f * kPi, Vec3f::UnitX()).toRotationMatrix();
    append_torus(m, Vec3f(-1.05f, 0, -0.7f), rot, 0.4f, 0.09f, 40, 12);
    parts.push_back(uint32_t(m.triangle_count()));
    append_uv_sphere(m, Vec3f(1.1f, 0, -0.55f), 0.5f, 16, 24, Vec3f(0.9f, 0.25f, 0.3f));
    parts.push_back(uint32_t(m.triangle_count()));
    m.build_adjacency();
    return make_rigid_instrument(std::move(m), parts);
}

/// Rotation whose +z column is `forward` (unit), completed by a fixed up hint.
inline Eigen::Matrix3f frame_looking(const Vec3f& forward) {
    const Vec3f z = forward.normalized();
    const Vec3f hint = std::fabs(z.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY();
    const Vec3f y = z.cross(hint).normalized();
    const Vec3f x = y.cross(z);
    Eigen::Matrix3f r;
    r.col(0) = x;
    r.col(1) = y;
    r.col(2) = z;
    return r;
}

/// Pose instrument → eye with the tip at `tip` pointing along `forward`.
inline Eigen::Isometry3f pose_at(const Vec3f& tip, const Vec3f& forward) {
    Eigen::Isometry3f t = Eigen::Isometry3f::Identity();
    t.linear() = frame_looking(forward);
    t.translation() = tip;
    return t;
}

/// Brute force: membrane triangles that touch any instrument triangle or lie inside a closed part.
inline std::vector<uint32_t> brute_force_colliding(const std::vector<Vec3f>& mem_v,
                                                   const std::vector<std::array<uint32_t, 3>>& mem_t,
                                                   const Instrument& ins, std::span<const Vec3f> ins_local,
                                                   const Eigen::Isometry3f& to_eye) {
    std::vector<Vec3f> iv(ins_local.size());
    for (size_t i = 0; i < iv.size(); ++i) iv[i] = to_eye * ins_local[i];
    Vec3f lo = iv[0], hi = iv[0];
    for (const Vec3f& p : iv) {
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
    }
    std::vector<uint32_t> out;
    for (uint32_t t = 0; t < mem_t.size(); ++t) {
        const Vec3f &a = mem_v[mem_t[t][0]], &b = mem_v[mem_t[t][1]], &c = mem_v[mem_t[t][2]];
        const Vec3f tlo = a.cwiseMin(b).cwiseMin(c), thi = a.cwiseMax(b).cwiseMax(c);
        if ((thi.array() < lo.array()).any() || (tlo.array() > hi.array()).any()) continue;
        bool hit = false;
        for (const auto& q : ins.mesh.triangles)
            if (triangles_intersect(a, b, c, iv[q[0]], iv[q[1]], iv[q[2]])) {
                hit = true;
                break;
            }
        for (size_t p = 0; !hit && p + 1 < ins.part_triangle_begin.size(); ++p) {
            const auto tris = std::span(ins.mesh.triangles)
                                  .subspan(ins.part_triangle_begin[p], ins.part_triangle_begin[p + 1] - ins.part_triangle_begin[p]);
            hit = point_inside_closed_mesh(a, iv, tris);
        }
        if (hit) out.push_back(t);
    }
    return out;
}

/// |A ∩ B| for ascending sets.
inline size_t intersection_size(std::span<const uint32_t> a, std::span<const uint32_t> b) {
    size_t n = 0;
    for (size_t i = 0, j = 0; i < a.size() && j < b.size();) {
        if (a[i] == b[j]) {
            ++n;
            ++i;
            ++j;
        } else if (a[i] < b[j]) {
            ++i;
        } else {
            ++j;
        }
    }
    return n;
}

}  // namespace eyesim::sim::collision::testing
