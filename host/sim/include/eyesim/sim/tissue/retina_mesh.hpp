#pragma once
/// \file
/// Retina mesh generator: the rear hemisphere of the eye, on which every retina node starts attached.

#include "eyesim/sim/mesh.hpp"

namespace eyesim::sim::tissue {

/// Rear hemisphere (z ≤ 0, eye frame: origin at the eye centre, +z toward the pupil) of radius `radius_mm`:
/// a vertex at the posterior pole (0, 0, −r) and `rings` rings of `segments` vertices at polar angles
/// k·90°/rings from the pole. Triangles face the eye centre (their normal points inward, toward the instruments).
/// Triangles: segments·(2·rings − 1).
TriangleMesh make_retina_hemisphere(float radius_mm, int rings, int segments);

}  // namespace eyesim::sim::tissue
