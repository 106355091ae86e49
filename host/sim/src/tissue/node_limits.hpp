#pragma once
// Per-node end-of-step rules shared by all integrators: the v_max clamp and the container sphere.

#include "eyesim/sim/tissue/mass_spring.hpp"

#include <cmath>

namespace eyesim::sim::tissue::detail {

/// Scales v to at most v_max (v_max = 0 zeroes it: the paper's "kinetic energy damped to zero").
inline void clamp_speed(Vec3f& v, float v_max) {
    const float s2 = v.squaredNorm();
    if (s2 > v_max * v_max) v *= v_max > 0.0f ? v_max / std::sqrt(s2) : 0.0f;
}

/// Keeps x inside the container sphere and removes the outward normal velocity at the wall.
inline void contain(Vec3f& x, Vec3f& v, const Vec3f& centre, float radius) {
    const Vec3f r = x - centre;
    const float r2 = r.squaredNorm();
    if (!(r2 > radius * radius)) return;
    const Vec3f n = r / std::sqrt(r2);
    x = centre + radius * n;
    const float vn = v.dot(n);
    if (vn > 0.0f) v -= vn * n;
}

/// Applies both end-of-step rules to one dynamic node.
inline void finish_node(Vec3f& x, Vec3f& v, const TissueParams& p) {
    if (p.v_max_mm_per_s < kUnlimited) clamp_speed(v, p.v_max_mm_per_s);
    if (p.container_radius_mm < kUnlimited) contain(x, v, p.container_centre_mm, p.container_radius_mm);
}

}  // namespace eyesim::sim::tissue::detail
