#pragma once
/// \file
/// Collision case 2 (paper §3.3): instrument tip against the inner eyeball sphere. The instruments enter
/// through trocars, so the tip is the first point to reach the wall; the tip is a point P and the wall the
/// sphere of the eye's inner radius around the eye centre (the eye-frame origin).

#include "eyesim/sim/mesh.hpp"

namespace eyesim::sim::collision {

/// Thresholds of the eye-wall monitor.
struct EyeSphereConfig {
    float inner_radius_mm = kEyeRadius_mm - 0.5f;  ///< inner wall radius (eye radius minus sclera/retina)
    float warn_distance_mm = 0.5f;                 ///< warning when the tip is closer than this to the wall
    float release_distance_mm = 0.6f;              ///< warning ends above this (hysteresis, ≥ warn distance)
};

/// Result of one update.
struct EyeSphereContact {
    float distance_mm = 0.0f;     ///< wall distance: inner radius − |P| (negative: the tip is beyond the wall)
    bool warning = false;         ///< the tip is within the warning distance (with hysteresis)
    bool warning_started = false; ///< event: the warning turned on in this update
    bool warning_ended = false;   ///< event: the warning turned off in this update
};

/// Signed distance of a tip from the inner eye wall (positive inside the eye), mm.
float eye_wall_distance_mm(const Vec3f& tip_eye_mm, float inner_radius_mm);

/// Per-instrument monitor: distance, threshold and warning events. No allocation.
class EyeSphereMonitor {
public:
    /// Monitor with the given thresholds.
    explicit EyeSphereMonitor(const EyeSphereConfig& config = {}) : config_(config) {}
    /// Evaluates a new tip position (eye frame).
    EyeSphereContact update(const Vec3f& tip_eye_mm);
    /// Whether the warning is on.
    bool warning() const { return warning_; }

private:
    EyeSphereConfig config_;
    bool warning_ = false;
};

}  // namespace eyesim::sim::collision
