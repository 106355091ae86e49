#pragma once
/// \file
/// poses.jsonl: one JSON object per tracking frame (lengths mm, times µs, quaternions [w,x,y,z]).
/// `{"frame", "reference_field", "t_device_us", "flags", "cameras_used",
///   "timing": {"sample_host_us", "field_end_host_us", "received_host_us", "poses_ready_host_us", "compute_us"},
///   "eye": {"measured", "q_eye_to_rig", "fit_rms_mm", "markers"},
///   "instruments": [{"name", "measured", "no_roll", "tip_rig_mm", "axis_rig", "tip_eye_mm", "axis_eye",
///                    "insertion_mm", "opening", "fit_rms_mm", "markers"}],
///   "markers": [{"class", "body", "id", "x_rig_mm", "sigma_mm", "views", "rms_px"}]}`
/// (axes are unit vectors from the tip towards the handle, as in truth.jsonl).

#include "eyesim/tracking/body_model.hpp"
#include "eyesim/tracking/tracker.hpp"

#include <string>

namespace eyesim::tracking {

/// One poses.jsonl line (no trailing newline) for `frame`; body names from `bodies`.
std::string frame_json_line(const TrackingFrame& frame, const BodySet& bodies);

}  // namespace eyesim::tracking
