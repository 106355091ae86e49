#pragma once
/// \file
/// Exact triangle–triangle intersection test (closed triangles, touching counts), used by the exact narrow
/// phase: ZCOLL's fallback where the membrane is not π-convex, and the reference for recall/precision.

#include "eyesim/sim/mesh.hpp"

#include <Eigen/Core>

#include <array>
#include <cmath>
#include <cstdint>
#include <span>

namespace eyesim::sim::collision {

/// True when the closed triangles (a0, a1, a2) and (b0, b1, b2) share at least one point. Orientation
/// predicates in double precision: a plane-side rejection (Möller), then, for crossing planes, an edge of one
/// triangle piercing the other (the intersection segment of two non-coplanar triangles ends on an edge of
/// one of them); coplanar pairs are decided in 2D by edge crossings and containment.
bool triangles_intersect(const Vec3f& a0, const Vec3f& a1, const Vec3f& a2, const Vec3f& b0, const Vec3f& b1,
                         const Vec3f& b2);

/// True when the ray o + t·dir, t > 0, crosses the triangle (a, b, c) (Möller–Trumbore in double; a ray in the
/// triangle's plane does not cross it). The parity of the crossings of a closed mesh says inside or outside.
inline bool ray_crosses_triangle(const Eigen::Vector3d& o, const Eigen::Vector3d& dir, const Vec3f& a, const Vec3f& b,
                                 const Vec3f& c) {
    const Eigen::Vector3d v0 = a.cast<double>();
    const Eigen::Vector3d e1 = b.cast<double>() - v0, e2 = c.cast<double>() - v0;
    const Eigen::Vector3d h = dir.cross(e2);
    const double det = e1.dot(h);
    if (std::fabs(det) < 1e-18) return false;
    const Eigen::Vector3d s = o - v0;
    const double u = s.dot(h) / det;
    if (u < 0 || u > 1) return false;
    const Eigen::Vector3d q = s.cross(e1);
    const double w = dir.dot(q) / det;
    if (w < 0 || u + w > 1) return false;
    return e2.dot(q) / det > 0;
}

/// True when point `p` is inside the closed, consistently oriented triangle range (ray parity along a fixed
/// skew direction). `triangles` index `vertices_mm`.
bool point_inside_closed_mesh(const Vec3f& p, std::span<const Vec3f> vertices_mm,
                              std::span<const std::array<uint32_t, 3>> triangles);

}  // namespace eyesim::sim::collision
