#pragma once
/// \file
/// Procedural surgical instruments as closed triangle meshes in the instrument frame.
///
/// Instrument frame: the working tip at the origin, the instrument points along +z (forward, into the eye),
/// the shaft extends towards −z. Units mm. An instrument is a union of closed parts (each part is a watertight
/// triangle range with outward normals) so that "inside the instrument" is well defined per part.

#include "eyesim/sim/mesh.hpp"

#include <Eigen/Geometry>

#include <cstdint>
#include <span>
#include <string_view>
#include <vector>

namespace eyesim::sim::collision {

/// The instrument types of the simulator.
enum class InstrumentKind : uint8_t { Forceps, Vitrector, Pick, InjectionNeedle, LightPipe };

/// Name of an instrument kind ("forceps", "vitrector", "pick", "injection_needle", "light_pipe").
std::string_view instrument_name(InstrumentKind kind);

/// Which rigid sub-body a vertex belongs to: the shaft, or one of the two forceps jaws.
enum class InstrumentPart : uint8_t { Shaft = 0, JawA = 1, JawB = 2 };

/// A procedural instrument (~2k triangles). Topology is fixed; forceps jaws rotate about a hinge.
struct Instrument {
    InstrumentKind kind = InstrumentKind::Pick;
    TriangleMesh mesh;                        ///< rest shape (jaws closed), instrument frame, mm
    std::vector<InstrumentPart> vertex_part;  ///< per vertex: which rigid sub-body moves it
    std::vector<uint32_t> part_triangle_begin;  ///< closed parts: triangles [begin[k], begin[k+1])
    Vec3f hinge_local_mm{0, 0, 0};            ///< forceps: jaw hinge point (jaws rotate about +y through it)
    float shaft_radius_mm = 0.3f;             ///< outer radius of the shaft
    Vec3f port_local_mm{0, 0, 0};             ///< vitrector: centre of the side opening
    Vec3f port_dir_local{1, 0, 0};            ///< vitrector: outward unit normal of the side opening

    /// Number of closed parts.
    size_t part_count() const { return part_triangle_begin.empty() ? 0 : part_triangle_begin.size() - 1; }

    /// Writes the articulated vertices (instrument frame) into `out_local_mm` (size == vertex count): forceps
    /// jaws rotated symmetrically to a total opening angle `opening_deg` (0 = closed); other kinds copy the
    /// rest shape. No allocation.
    void articulate(float opening_deg, std::span<Vec3f> out_local_mm) const;
};

/// Forceps: shaft plus two jaws (each ~0.45k triangles) hinged 1.5 mm behind the tip; ~2k triangles.
Instrument make_forceps();
/// Vitrector: closed tube with a rounded end and a recessed side opening (port) facing +x near the tip.
Instrument make_vitrector();
/// Pick: shaft with a short hook bent towards +x; the hook point is the tip.
Instrument make_pick();
/// Injection needle: thin tube with a bevelled end; the bevel point is the tip.
Instrument make_injection_needle();
/// Light pipe: wider tube with a flat polished end; the centre of the end face is the tip.
Instrument make_light_pipe();
/// A rigid body used like an instrument (e.g. the sphere or teapot of the paper's Fig. 7): `mesh` in the
/// instrument frame (tip at the origin, pointing along +z), made of closed parts split at
/// `part_triangle_begin` (empty: one part).
Instrument make_rigid_instrument(TriangleMesh mesh, std::vector<uint32_t> part_triangle_begin = {});
/// Any of the above by kind.
Instrument make_instrument(InstrumentKind kind);

/// An instrument with its articulation buffer: what a frame loop keeps per instrument.
class PosedInstrument {
public:
    /// Takes ownership of `instrument`; the articulation buffer is sized once here.
    explicit PosedInstrument(Instrument instrument);

    /// Sets the jaw opening (forceps; ignored otherwise) and the pose instrument→eye. No allocation.
    void set_state(float opening_deg, const Eigen::Isometry3f& instrument_to_eye);

    const Instrument& instrument() const { return instrument_; }             ///< the shape
    std::span<const Vec3f> vertices_local_mm() const { return vertices_; }   ///< articulated, instrument frame
    const Eigen::Isometry3f& instrument_to_eye() const { return pose_; }     ///< pose: instrument → eye
    float opening_deg() const { return opening_deg_; }                       ///< last jaw opening
    Vec3f tip_eye_mm() const { return pose_.translation(); }                 ///< tip position, eye frame
    Vec3f forward_eye() const { return pose_.linear().col(2); }              ///< unit +z of the instrument

private:
    Instrument instrument_;
    std::vector<Vec3f> vertices_;
    Eigen::Isometry3f pose_ = Eigen::Isometry3f::Identity();
    float opening_deg_ = -1.0f;
};

}  // namespace eyesim::sim::collision
