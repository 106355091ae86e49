#pragma once
/// \file
/// Builds the tracker's hot-path types from the rig's files: CameraGeometry + field timing from rig.yaml's
/// CameraModel, and the BodySet from scenes/bodies.json for the instruments present in a scene.

#include "eyesim/tracking/body_model.hpp"
#include "eyesim/tracking/camera_geometry.hpp"
#include "eyesim/tracking/field_sync.hpp"
#include "eyesim/tracking/pose.hpp"

#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/camera.hpp"
#include "eyesim/rig/truth.hpp"

#include <span>
#include <string>
#include <utility>
#include <vector>

namespace eyesim::tracking {

/// Intrinsics, distortion and pose of a rig camera (frame pixels; 5-coefficient OpenCV model).
CameraGeometry camera_geometry(const rig::CameraModel& cam);

/// Field timing of a rig camera: device field end → exposure mid-time per parity (rig PAL timing model).
CameraTiming camera_timing(const rig::CameraModel& cam);

/// One instrument in a scene: its kind and the trocar it goes through (−1: none).
struct SceneInstrument {
    rig::InstrumentKind kind = rig::InstrumentKind::kPick;  ///< which body
    int trocar = -1;                                         ///< trocar id (0 tissue instrument, 1 light pipe)
};

/// Eye and the listed instruments from the bodies file. Instrument i of the result is `scene[i]`. Throws
/// std::invalid_argument naming the kind or trocar when the bodies lack it, or when a body has more markers
/// than kMaxBodyMarkers.
BodySet body_set(const rig::Bodies& bodies, const std::vector<SceneInstrument>& scene);

/// Every instrument kind of the bodies file, the first through trocar 0 and the light pipe through trocar 1
/// (the usual rig), for live tracking when the scene is not known: each kind's colour order is unique, so only
/// the instruments present are acquired.
std::vector<SceneInstrument> all_instruments(const rig::Bodies& bodies);

/// The rig's truth poses at a field's reference time as measured tracker poses (rig frame; instruments in the
/// truth's order, as body_set() of the truth's scene lists them; the roll the shaft's axis does not give is the
/// least turn from the body's z): what tests and benchmarks hand MarkerHintSource in place of a tracker. Returns
/// how many instruments were written (at most instruments.size()).
int truth_poses(const rig::FieldTruth& truth, EyePose& eye, std::span<InstrumentPose> instruments);

}  // namespace eyesim::tracking
