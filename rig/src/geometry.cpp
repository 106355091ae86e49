#include "eyesim/rig/geometry.hpp"

namespace eyesim::rig {

std::vector<SceneMarker> scene_markers(const Bodies& bodies, const std::vector<InstrumentKind>& kinds, bool wand) {
    std::vector<SceneMarker> out;
    for (const EyeMarker& m : bodies.eye.markers)
        out.push_back({"eye", -1, m.id, m.colour_class, m.radius_mm, m.position_eye_mm});
    for (size_t k = 0; k < kinds.size(); ++k) {
        const InstrumentBody& b = bodies.instrument(kinds[k]);
        for (size_t i = 0; i < b.markers.size(); ++i)
            out.push_back({b.name, static_cast<int>(k), b.markers[i].id, b.markers[i].colour_class,
                           b.markers[i].radius_mm, b.marker_position_mm(i)});
    }
    if (wand)
        for (size_t i = 0; i < bodies.wand.markers.size(); ++i) {
            const WandMarker& m = bodies.wand.markers[i];
            out.push_back({"wand", kWandMarkerBody, m.id, m.colour_class, m.radius_mm, bodies.wand.marker_position_mm(i)});
        }
    return out;
}

Eigen::Vector3d marker_center_rig(const SceneMarker& m, const SceneState& s) {
    if (m.instrument == kWandMarkerBody) return s.wand_origin_rig_mm + m.local_mm.z() * s.wand_axis_rig;
    if (m.instrument < 0) return s.eye_to_rig(m.local_mm);
    const InstrumentPose& p = s.instruments.at(static_cast<size_t>(m.instrument));
    const Eigen::Vector3d tip = s.eye_to_rig(p.tip_eye_mm);
    const Eigen::Vector3d axis = s.q_eye_to_rig * p.axis_eye;
    return tip + m.local_mm.z() * axis;
}

void scene_geometry(const SceneState& s, const Bodies& bodies, const std::vector<SceneMarker>& markers,
                    SceneGeometry& out) {
    out.eye_center_rig_mm = s.eye_center_rig_mm;
    out.eye_radius_mm = bodies.eye.radius_mm;
    out.board = s.board;
    out.markers.resize(markers.size());
    for (size_t i = 0; i < markers.size(); ++i) {
        out.markers[i].center_rig_mm = marker_center_rig(markers[i], s);
        out.markers[i].radius_mm = markers[i].radius_mm;
        out.markers[i].colour_class = markers[i].colour_class;
    }
    out.shafts.resize(s.instruments.size());
    for (size_t k = 0; k < s.instruments.size(); ++k) {
        const InstrumentPose& p = s.instruments[k];
        const InstrumentBody& b = bodies.instrument(p.kind);
        const Eigen::Vector3d tip = s.eye_to_rig(p.tip_eye_mm);
        const Eigen::Vector3d axis = s.q_eye_to_rig * p.axis_eye;
        out.shafts[k].a_rig_mm = tip + b.tip_offset_mm * axis;
        out.shafts[k].b_rig_mm = tip + b.shaft_length_mm * axis;
        out.shafts[k].radius_mm = b.shaft_radius_mm;
    }
}

}  // namespace eyesim::rig
