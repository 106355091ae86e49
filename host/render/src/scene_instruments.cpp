#include "eyesim/render/scene_instruments.hpp"

namespace eyesim::render {

InstrumentView make_instrument_view(const sim::collision::PosedInstrument& posed,
                                    std::vector<Eigen::Vector3f>& vertices_eye_mm) {
    const auto local = posed.vertices_local_mm();
    const Eigen::Isometry3f& to_eye = posed.instrument_to_eye();
    vertices_eye_mm.resize(local.size());
    for (size_t i = 0; i < local.size(); ++i) vertices_eye_mm[i] = to_eye * local[i];
    InstrumentView v;
    v.mesh = MeshView{vertices_eye_mm, posed.instrument().mesh.triangles};
    v.tip_eye_mm = posed.tip_eye_mm();
    v.forward_eye = posed.forward_eye();
    v.is_light_pipe = posed.instrument().kind == sim::collision::InstrumentKind::LightPipe;
    return v;
}

}  // namespace eyesim::render
