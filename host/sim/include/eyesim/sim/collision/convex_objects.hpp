#pragma once
/// \file
/// Collision case 3 (paper §3.3): an instrument against the simple rigid convex objects of the abstract
/// training tasks, through FCL (GJK/EPA and its analytic shape pairs; nothing hand-written here).
/// The instrument is modelled by a capsule around its shaft whose front cap touches the tip.

#include "eyesim/sim/mesh.hpp"

#include <Eigen/Geometry>

#include <memory>
#include <span>
#include <vector>

namespace eyesim::sim::collision {

/// Convex primitives of the training tasks.
enum class ConvexShape : uint8_t { Sphere, Box, Cylinder, Capsule, Cone };

/// One rigid object. `size_mm`: sphere (radius, –, –); box (side x, side y, side z); cylinder, capsule, cone
/// (radius, length along the object's z, –). The object frame is centred on the shape.
struct ConvexObject {
    ConvexShape shape = ConvexShape::Sphere;                         ///< primitive
    Vec3f size_mm{1, 1, 1};                                         ///< dimensions, see above
    Eigen::Isometry3f object_to_eye = Eigen::Isometry3f::Identity();  ///< pose object → eye
};

/// A closed triangle mesh of the object's surface in the eye frame, for pictures (outward normals, counter-
/// clockwise seen from outside). Curved shapes use `segments` around their axis (≥ 6).
TriangleMesh convex_object_mesh(const ConvexObject& object, int segments = 32);

/// Instrument vs one object.
struct ConvexContact {
    uint32_t object = 0;              ///< index of the object
    bool colliding = false;           ///< shapes overlap
    float distance_mm = 0.0f;         ///< separation (≥ 0) or −penetration depth when colliding
    Vec3f point_instrument_eye_mm{0, 0, 0};  ///< closest point / contact point on the instrument side
    Vec3f point_object_eye_mm{0, 0, 0};      ///< closest point on the object (contact point when colliding)
    Vec3f normal_eye{0, 0, 0};        ///< contact normal (from the instrument towards the object) when colliding
};

/// The object set of a training task. Shapes are created in `add`; queries reuse the result buffer.
class ConvexObjectSet {
public:
    ConvexObjectSet();
    ~ConvexObjectSet();
    ConvexObjectSet(const ConvexObjectSet&) = delete;
    ConvexObjectSet& operator=(const ConvexObjectSet&) = delete;

    /// Adds an object; returns its index.
    uint32_t add(const ConvexObject& object);
    /// Moves an object.
    void set_pose(uint32_t index, const Eigen::Isometry3f& object_to_eye);
    /// Number of objects.
    size_t size() const;

    /// Distances and contacts of the instrument capsule (radius `shaft_radius_mm`, from the tip back
    /// `shaft_length_mm` along −z of the instrument frame) against every object, in object order.
    std::span<const ConvexContact> query(const Eigen::Isometry3f& instrument_to_eye, float shaft_radius_mm,
                                         float shaft_length_mm);

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace eyesim::sim::collision
