#include "eyesim/sim/collision/eye_sphere.hpp"

namespace eyesim::sim::collision {

float eye_wall_distance_mm(const Vec3f& tip_eye_mm, float inner_radius_mm) { return inner_radius_mm - tip_eye_mm.norm(); }

EyeSphereContact EyeSphereMonitor::update(const Vec3f& tip_eye_mm) {
    EyeSphereContact c;
    c.distance_mm = eye_wall_distance_mm(tip_eye_mm, config_.inner_radius_mm);
    const bool was = warning_;
    if (!warning_ && c.distance_mm < config_.warn_distance_mm) warning_ = true;
    else if (warning_ && c.distance_mm > config_.release_distance_mm) warning_ = false;
    c.warning = warning_;
    c.warning_started = warning_ && !was;
    c.warning_ended = !warning_ && was;
    return c;
}

}  // namespace eyesim::sim::collision
