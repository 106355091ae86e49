#include "eyesim/sim/collision/convex_objects.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

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

TriangleMesh convex_object_mesh(const ConvexObject& o, int segments) {
    TriangleMesh m;
    const Vec3f s = o.size_mm;
    if (o.shape == ConvexShape::Box) {
        for (int k = 0; k < 8; ++k)
            m.vertices_mm.emplace_back((k & 1 ? 0.5f : -0.5f) * s.x(), (k & 2 ? 0.5f : -0.5f) * s.y(),
                                       (k & 4 ? 0.5f : -0.5f) * s.z());
        // Faces −x, +x, −y, +y, −z, +z as quads (a, b, c, d) counter-clockwise from outside.
        const uint32_t q[6][4] = {{0, 4, 6, 2}, {1, 3, 7, 5}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 2, 3, 1}, {4, 5, 7, 6}};
        for (const auto& f : q) {
            m.triangles.push_back({f[0], f[1], f[2]});
            m.triangles.push_back({f[0], f[2], f[3]});
        }
    } else {
        // A solid of revolution about z: profile (radius, z) from the bottom pole to the top pole.
        std::vector<std::pair<float, float>> profile;
        const float r = s.x(), half = 0.5f * s.y();
        const int arc = std::max(3, segments / 4);
        const float pi = 3.14159265358979f;
        auto cap = [&](float z0, float sign) {  // hemisphere of radius r about (0, 0, z0)
            for (int i = 0; i <= arc; ++i) {
                const float a = 0.5f * pi * float(i) / float(arc);  // 0 at the pole
                profile.emplace_back(r * std::sin(a), z0 + sign * r * std::cos(a));
            }
        };
        switch (o.shape) {
            case ConvexShape::Sphere:
                for (int i = 0; i <= 2 * arc; ++i) {
                    const float a = pi * float(i) / float(2 * arc);
                    profile.emplace_back(r * std::sin(a), -r * std::cos(a));
                }
                break;
            case ConvexShape::Cylinder: profile = {{0, -half}, {r, -half}, {r, half}, {0, half}}; break;
            case ConvexShape::Cone: profile = {{0, -half}, {r, -half}, {0, half}}; break;  // apex at +z, as FCL
            case ConvexShape::Capsule: {
                cap(-half, -1.0f);
                std::vector<std::pair<float, float>> top;
                std::swap(top, profile);
                cap(half, 1.0f);
                std::reverse(profile.begin(), profile.end());
                top.insert(top.end(), profile.begin(), profile.end());
                profile = std::move(top);
                break;
            }
            case ConvexShape::Box: break;
        }
        const int seg = std::max(6, segments);
        const uint32_t bottom = 0;
        m.vertices_mm.emplace_back(0.0f, 0.0f, profile.front().second);
        const int rings = int(profile.size()) - 2;  // profile points strictly between the poles
        for (int i = 1; i <= rings; ++i)
            for (int k = 0; k < seg; ++k) {
                const float a = 2.0f * pi * float(k) / float(seg);
                m.vertices_mm.emplace_back(profile[size_t(i)].first * std::cos(a), profile[size_t(i)].first * std::sin(a),
                                           profile[size_t(i)].second);
            }
        const uint32_t top = uint32_t(m.vertices_mm.size());
        m.vertices_mm.emplace_back(0.0f, 0.0f, profile.back().second);
        auto ring = [seg](int i, int k) { return uint32_t(1 + (i - 1) * seg + (k % seg)); };
        for (int k = 0; k < seg; ++k) m.triangles.push_back({bottom, ring(1, k + 1), ring(1, k)});
        for (int i = 1; i < rings; ++i)
            for (int k = 0; k < seg; ++k) {
                m.triangles.push_back({ring(i, k), ring(i, k + 1), ring(i + 1, k + 1)});
                m.triangles.push_back({ring(i, k), ring(i + 1, k + 1), ring(i + 1, k)});
            }
        for (int k = 0; k < seg; ++k) m.triangles.push_back({top, ring(rings, k), ring(rings, k + 1)});
    }
    for (auto& v : m.vertices_mm) v = o.object_to_eye * v;
    m.build_adjacency();
    return m;
}

}  // namespace eyesim::sim::collision
