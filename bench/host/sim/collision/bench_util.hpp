#pragma once
// What the collision benchmarks share: the thread's CPU clock and an instrument pose from its tip and direction.

#include "eyesim/sim/mesh.hpp"
#include "thread_cpu.hpp"

#include <Eigen/Geometry>

#include <cmath>

namespace eyesim::sim::collision::bench {

using eyesim::bench::thread_cpu_us;

/// Pose of an instrument whose tip is at `tip` and whose +z (body frame) points along `forward`.
inline Eigen::Isometry3f pose_at(const Vec3f& tip, const Vec3f& forward) {
    const Vec3f z = forward.normalized();
    const Vec3f y = z.cross(std::fabs(z.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY()).normalized();
    Eigen::Isometry3f t = Eigen::Isometry3f::Identity();
    t.linear().col(0) = y.cross(z);
    t.linear().col(1) = y;
    t.linear().col(2) = z;
    t.translation() = tip;
    return t;
}

}  // namespace eyesim::sim::collision::bench
