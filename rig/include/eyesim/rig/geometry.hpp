#pragma once
/// \file
/// What the renderer draws at one instant: the eye sphere, marker spheres and instrument shafts in the rig
/// frame, derived from a SceneState and the marker bodies.

#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/scenario.hpp"

#include <Eigen/Core>

#include <optional>
#include <string>
#include <vector>

namespace eyesim::rig {

/// SceneMarker::instrument of the calibration wand's markers.
inline constexpr int kWandMarkerBody = -2;

/// One marker of the scene (which body, which marker), in a fixed order: eye markers, then the markers of
/// each instrument in `Scenario::kinds()` order, then the wand's (scenes with the wand).
struct SceneMarker {
    std::string body;          ///< "eye", the instrument kind name or "wand"
    int instrument = -1;       ///< -1 for the eye, kWandMarkerBody for the wand, else index into SceneState::instruments
    int id = 0;                ///< marker index within its body
    int colour_class = 1;      ///< 1..4
    double radius_mm = 0.6;    ///< sphere radius
    Eigen::Vector3d local_mm = Eigen::Vector3d::Zero();  ///< eye, instrument or wand frame
};

/// The scene's markers in their fixed order; `wand`: with the wand's markers (Scenario::has_wand()).
std::vector<SceneMarker> scene_markers(const Bodies& bodies, const std::vector<InstrumentKind>& kinds, bool wand = false);

/// Renderable geometry at one instant (rig frame, mm).
struct SceneGeometry {
    /// A coloured marker sphere.
    struct Sphere {
        Eigen::Vector3d center_rig_mm = Eigen::Vector3d::Zero();
        double radius_mm = 0.6;
        int colour_class = 1;
    };
    /// A grey instrument shaft (finite cylinder without caps) from a to b.
    struct Cylinder {
        Eigen::Vector3d a_rig_mm = Eigen::Vector3d::Zero();
        Eigen::Vector3d b_rig_mm = Eigen::Vector3d::Zero();
        double radius_mm = 0.3;
    };
    Eigen::Vector3d eye_center_rig_mm = Eigen::Vector3d::Zero();  ///< white eye sphere centre
    double eye_radius_mm = 12.0;                                  ///< 0 = no eye
    std::vector<Sphere> markers;                                  ///< same order as scene_markers()
    std::vector<Cylinder> shafts;                                 ///< one per instrument
    std::optional<BoardPose> board;                               ///< calibration checkerboard (board.hpp)
};

/// Marker centre in the rig frame for a scene state.
Eigen::Vector3d marker_center_rig(const SceneMarker& m, const SceneState& s);

/// Fills `out` (reusing its storage) with the geometry of state `s`.
void scene_geometry(const SceneState& s, const Bodies& bodies, const std::vector<SceneMarker>& markers,
                    SceneGeometry& out);

}  // namespace eyesim::rig
