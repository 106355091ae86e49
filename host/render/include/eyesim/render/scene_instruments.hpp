#pragma once
/// \file
/// Glue from the simulation's posed instruments to the scene renderer's InstrumentView.

#include "eyesim/render/scene_renderer.hpp"
#include "eyesim/sim/collision/instrument.hpp"

#include <vector>

namespace eyesim::render {

/// Transforms `posed`'s articulated vertices into the eye frame (into `vertices_eye_mm`, resized; keep it alive
/// for as long as the returned view is used) and fills the view: tip = pose translation, forward = pose +z,
/// is_light_pipe from the instrument kind. No allocation once `vertices_eye_mm` has reached the vertex count.
InstrumentView make_instrument_view(const sim::collision::PosedInstrument& posed,
                                    std::vector<Eigen::Vector3f>& vertices_eye_mm);

}  // namespace eyesim::render
