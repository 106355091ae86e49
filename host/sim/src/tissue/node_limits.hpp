#pragma once
// Per-node end-of-step rules shared by all integrators: the v_max clamp and the container sphere.

#include "eyesim/sim/tissue/mass_spring.hpp"

#include <cmath>

namespace eyesim::sim::tissue::detail {

/// Scales v to at most v_max (v_max = 0 zeroes it: the paper's "kinetic energy damped to zero").
/// V: Vec3f, or a four-lane vector whose fourth lane is 0.
template <class V>
inline void clamp_speed(V& v, float v_max) {
    const float s2 = v.squaredNorm();
    if (s2 > v_max * v_max) v *= v_max > 0.0f ? v_max / std::sqrt(s2) : 0.0f;
}

/// Keeps x inside the container sphere and removes the outward normal velocity at the wall.
template <class V>
inline void contain(V& x, V& v, const V& centre, float radius) {
    const V r = x - centre;
    const float r2 = r.squaredNorm();
    if (!(r2 > radius * radius)) return;
    const V n = r / std::sqrt(r2);
    x = centre + radius * n;
    const float vn = v.dot(n);
    if (vn > 0.0f) v -= vn * n;
}

/// Both end-of-step rules with the parameters copied out of TissueParams: integrators build one per step so the
/// node loop keeps them in registers (a reference into the params could alias the float arrays it writes).
struct EndOfStep {
    float v_max;
    bool clamp;
    Vec3f centre;
    Eigen::Vector4f centre4;  // the same, padded with 0 for four-lane node updates
    float radius;
    bool contained;

    explicit EndOfStep(const TissueParams& p)
        : v_max(p.v_max_mm_per_s),
          clamp(p.v_max_mm_per_s < kUnlimited),
          centre(p.container_centre_mm),
          centre4(centre.x(), centre.y(), centre.z(), 0.0f),
          radius(p.container_radius_mm),
          contained(p.container_radius_mm < kUnlimited) {}

    /// Applies both rules to one dynamic node.
    void apply(Vec3f& x, Vec3f& v) const {
        if (clamp) clamp_speed(v, v_max);
        if (contained) contain(x, v, centre, radius);
    }
    /// The same on padded four-lane copies (fourth lanes 0, and kept 0).
    void apply(Eigen::Vector4f& x, Eigen::Vector4f& v) const {
        if (clamp) clamp_speed(v, v_max);
        if (contained) contain(x, v, centre4, radius);
    }
};

}  // namespace eyesim::sim::tissue::detail
