#include "eyesim/sim/collision/tri_tri.hpp"

#include <Eigen/Geometry>

#include <cmath>

namespace eyesim::sim::collision {
namespace {

using V3 = Eigen::Vector3d;

double orient3d(const V3& a, const V3& b, const V3& c, const V3& d) { return (b - a).cross(c - a).dot(d - a); }

int sign(double x) { return (x > 0) - (x < 0); }

/// 2D orientation of (a, b, c).
double orient2d(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c) {
    return (b.x() - a.x()) * (c.y() - a.y()) - (b.y() - a.y()) * (c.x() - a.x());
}

bool segments_intersect_2d(const Eigen::Vector2d& p, const Eigen::Vector2d& q, const Eigen::Vector2d& a,
                           const Eigen::Vector2d& b) {
    const double d1 = orient2d(a, b, p), d2 = orient2d(a, b, q), d3 = orient2d(p, q, a), d4 = orient2d(p, q, b);
    if (((d1 > 0 && d2 < 0) || (d1 < 0 && d2 > 0)) && ((d3 > 0 && d4 < 0) || (d3 < 0 && d4 > 0))) return true;
    auto on = [](const Eigen::Vector2d& s, const Eigen::Vector2d& e, const Eigen::Vector2d& x, double o) {
        return o == 0 && std::min(s.x(), e.x()) <= x.x() && x.x() <= std::max(s.x(), e.x()) &&
               std::min(s.y(), e.y()) <= x.y() && x.y() <= std::max(s.y(), e.y());
    };
    return on(a, b, p, d1) || on(a, b, q, d2) || on(p, q, a, d3) || on(p, q, b, d4);
}

bool point_in_triangle_2d(const Eigen::Vector2d& p, const Eigen::Vector2d* t) {
    const double d0 = orient2d(t[0], t[1], p), d1 = orient2d(t[1], t[2], p), d2 = orient2d(t[2], t[0], p);
    const bool has_neg = d0 < 0 || d1 < 0 || d2 < 0, has_pos = d0 > 0 || d1 > 0 || d2 > 0;
    return !(has_neg && has_pos);
}

bool coplanar_intersect(const V3* a, const V3* b) {
    const V3 n = (a[1] - a[0]).cross(a[2] - a[0]);
    int drop = 0;
    if (std::fabs(n.y()) > std::fabs(n[drop])) drop = 1;
    if (std::fabs(n.z()) > std::fabs(n[drop])) drop = 2;
    const int u = (drop + 1) % 3, v = (drop + 2) % 3;
    Eigen::Vector2d p[3], q[3];
    for (int k = 0; k < 3; ++k) {
        p[k] = {a[k][u], a[k][v]};
        q[k] = {b[k][u], b[k][v]};
    }
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            if (segments_intersect_2d(p[i], p[(i + 1) % 3], q[j], q[(j + 1) % 3])) return true;
    return point_in_triangle_2d(p[0], q) || point_in_triangle_2d(q[0], p);
}

/// Does segment (p, q) meet triangle t (closed), given p and q are not both on t's plane?
bool segment_meets_triangle(const V3& p, const V3& q, const V3* t) {
    const int sp = sign(orient3d(t[0], t[1], t[2], p)), sq = sign(orient3d(t[0], t[1], t[2], q));
    if (sp == sq && sp != 0) return false;
    if (sp == 0 && sq == 0) return false;  // handled by the coplanar path
    // The segment crosses the plane: it meets t iff it passes on the same side of all three edges.
    const int s0 = sign(orient3d(p, q, t[0], t[1])), s1 = sign(orient3d(p, q, t[1], t[2])),
              s2 = sign(orient3d(p, q, t[2], t[0]));
    const bool has_neg = s0 < 0 || s1 < 0 || s2 < 0, has_pos = s0 > 0 || s1 > 0 || s2 > 0;
    return !(has_neg && has_pos);
}

}  // namespace

bool triangles_intersect(const Vec3f& a0, const Vec3f& a1, const Vec3f& a2, const Vec3f& b0, const Vec3f& b1,
                         const Vec3f& b2) {
    const V3 a[3] = {a0.cast<double>(), a1.cast<double>(), a2.cast<double>()};
    const V3 b[3] = {b0.cast<double>(), b1.cast<double>(), b2.cast<double>()};
    // Möller's rejection: all of b strictly on one side of a's plane (or vice versa) → disjoint.
    const int sb0 = sign(orient3d(a[0], a[1], a[2], b[0])), sb1 = sign(orient3d(a[0], a[1], a[2], b[1])),
              sb2 = sign(orient3d(a[0], a[1], a[2], b[2]));
    if (sb0 == sb1 && sb1 == sb2 && sb0 != 0) return false;
    const int sa0 = sign(orient3d(b[0], b[1], b[2], a[0])), sa1 = sign(orient3d(b[0], b[1], b[2], a[1])),
              sa2 = sign(orient3d(b[0], b[1], b[2], a[2]));
    if (sa0 == sa1 && sa1 == sa2 && sa0 != 0) return false;
    if (sb0 == 0 && sb1 == 0 && sb2 == 0) return coplanar_intersect(a, b);
    for (int i = 0; i < 3; ++i) {
        if (segment_meets_triangle(a[i], a[(i + 1) % 3], b)) return true;
        if (segment_meets_triangle(b[i], b[(i + 1) % 3], a)) return true;
    }
    // An edge lying in the other triangle's plane (one orientation zero on both ends) is not covered above.
    for (int i = 0; i < 3; ++i) {
        const int j = (i + 1) % 3;
        const int sbi = i == 0 ? sb0 : (i == 1 ? sb1 : sb2), sbj = j == 0 ? sb0 : (j == 1 ? sb1 : sb2);
        const int sai = i == 0 ? sa0 : (i == 1 ? sa1 : sa2), saj = j == 0 ? sa0 : (j == 1 ? sa1 : sa2);
        if (sbi == 0 && sbj == 0) {
            const V3 e[3] = {b[i], b[j], b[j]};
            if (coplanar_intersect(a, e)) return true;
        }
        if (sai == 0 && saj == 0) {
            const V3 e[3] = {a[i], a[j], a[j]};
            if (coplanar_intersect(b, e)) return true;
        }
    }
    return false;
}

bool point_inside_closed_mesh(const Vec3f& p, std::span<const Vec3f> vertices_mm,
                              std::span<const std::array<uint32_t, 3>> triangles) {
    // A skew direction makes hits exactly on edges or vertices vanishingly unlikely.
    const V3 o = p.cast<double>();
    const V3 dir = V3(0.5773502691896257, 0.6123724356957945, 0.5400617248673217).normalized();
    int crossings = 0;
    for (const auto& t : triangles)
        crossings += ray_crosses_triangle(o, dir, vertices_mm[t[0]], vertices_mm[t[1]], vertices_mm[t[2]]);
    return (crossings & 1) != 0;
}

}  // namespace eyesim::sim::collision
