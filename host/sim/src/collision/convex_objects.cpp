#include "eyesim/sim/collision/convex_objects.hpp"

#include <fcl/geometry/shape/box.h>
#include <fcl/geometry/shape/capsule.h>
#include <fcl/geometry/shape/cone.h>
#include <fcl/geometry/shape/cylinder.h>
#include <fcl/geometry/shape/sphere.h>
#include <fcl/narrowphase/collision.h>
#include <fcl/narrowphase/collision_object.h>
#include <fcl/narrowphase/distance.h>

namespace eyesim::sim::collision {

struct ConvexObjectSet::Impl {
    std::vector<std::unique_ptr<fcl::CollisionObjectd>> objects;
    std::vector<ConvexContact> contacts;
    std::unique_ptr<fcl::CollisionObjectd> instrument;
    double radius = -1, length = -1;
    fcl::CollisionRequestd creq{1, true};
    fcl::CollisionResultd cres;
    fcl::DistanceRequestd dreq{true};
    fcl::DistanceResultd dres;
};

namespace {
fcl::Transform3d to_fcl(const Eigen::Isometry3f& t) {
    fcl::Transform3d out = fcl::Transform3d::Identity();
    out.linear() = t.linear().cast<double>();
    out.translation() = t.translation().cast<double>();
    return out;
}
}  // namespace

ConvexObjectSet::ConvexObjectSet() : impl_(std::make_unique<Impl>()) {}
ConvexObjectSet::~ConvexObjectSet() = default;

uint32_t ConvexObjectSet::add(const ConvexObject& o) {
    std::shared_ptr<fcl::CollisionGeometryd> g;
    const Eigen::Vector3d s = o.size_mm.cast<double>();
    switch (o.shape) {
        case ConvexShape::Sphere: g = std::make_shared<fcl::Sphered>(s.x()); break;
        case ConvexShape::Box: g = std::make_shared<fcl::Boxd>(s.x(), s.y(), s.z()); break;
        case ConvexShape::Cylinder: g = std::make_shared<fcl::Cylinderd>(s.x(), s.y()); break;
        case ConvexShape::Capsule: g = std::make_shared<fcl::Capsuled>(s.x(), s.y()); break;
        case ConvexShape::Cone: g = std::make_shared<fcl::Coned>(s.x(), s.y()); break;
    }
    impl_->objects.push_back(std::make_unique<fcl::CollisionObjectd>(g, to_fcl(o.object_to_eye)));
    impl_->contacts.resize(impl_->objects.size());
    return uint32_t(impl_->objects.size() - 1);
}

void ConvexObjectSet::set_pose(uint32_t index, const Eigen::Isometry3f& object_to_eye) {
    impl_->objects.at(index)->setTransform(to_fcl(object_to_eye));
    impl_->objects[index]->computeAABB();
}

size_t ConvexObjectSet::size() const { return impl_->objects.size(); }

std::span<const ConvexContact> ConvexObjectSet::query(const Eigen::Isometry3f& instrument_to_eye,
                                                      float shaft_radius_mm, float shaft_length_mm) {
    Impl& m = *impl_;
    if (!m.instrument || m.radius != shaft_radius_mm || m.length != shaft_length_mm) {
        // Shape changes only when the instrument does (not per frame).
        m.radius = shaft_radius_mm;
        m.length = shaft_length_mm;
        m.instrument = std::make_unique<fcl::CollisionObjectd>(std::make_shared<fcl::Capsuled>(m.radius, m.length));
    }
    // Capsule centre: its front cap ends at the tip (instrument origin), the shaft runs along −z.
    Eigen::Isometry3f capsule = instrument_to_eye;
    capsule.translate(Vec3f(0, 0, -(shaft_radius_mm + 0.5f * shaft_length_mm)));
    m.instrument->setTransform(to_fcl(capsule));
    m.instrument->computeAABB();
    for (size_t i = 0; i < m.objects.size(); ++i) {
        ConvexContact& c = m.contacts[i];
        c = ConvexContact{};
        c.object = uint32_t(i);
        m.cres.clear();
        fcl::collide(m.instrument.get(), m.objects[i].get(), m.creq, m.cres);
        if (m.cres.isCollision()) {
            const auto& k = m.cres.getContact(0);
            c.colliding = true;
            c.distance_mm = float(-k.penetration_depth);
            c.normal_eye = k.normal.cast<float>();
            c.point_object_eye_mm = k.pos.cast<float>();
            c.point_instrument_eye_mm = c.point_object_eye_mm;
            continue;
        }
        m.dres.clear();
        fcl::distance(m.instrument.get(), m.objects[i].get(), m.dreq, m.dres);
        c.distance_mm = float(m.dres.min_distance);
        c.point_instrument_eye_mm = m.dres.nearest_points[0].cast<float>();
        c.point_object_eye_mm = m.dres.nearest_points[1].cast<float>();
    }
    return m.contacts;
}

}  // namespace eyesim::sim::collision
