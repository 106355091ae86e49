#pragma once
/// \file
/// Turns tracker output (or, for tests and scripted runs, the synthetic rig's ground truth) into the frame
/// loop's FramePoses: the working-hand instrument and the light pipe in the eye frame, collision convention
/// (tip at the origin, +z forward into the eye), and the main pedal axis.

#include "eyesim/frame/simulator.hpp"
#include "eyesim/rig/scenario.hpp"
#include "eyesim/tracking/tracker.hpp"

#include <array>

namespace eyesim::frame {

/// Collision-convention pose from a tip and a shaft direction (tip → handle), both eye frame.
Eigen::Isometry3f instrument_pose_eye(const Eigen::Vector3d& tip_eye_mm, const Eigen::Vector3d& axis_tip_to_handle);

/// Converts tracking frames. The working hand is the first instrument that is not a light pipe to be measured;
/// a pose is used once it has been measured at least once (held poses keep the last measurement).
class TrackingPoseAdapter {
public:
    /// `bodies` is the tracker's body set (instrument order of TrackingFrame::instruments).
    explicit TrackingPoseAdapter(const tracking::BodySet& bodies);
    /// Fills `out` from `frame`; `tracking_us` is the tracking stage's compute time for it.
    void convert(const tracking::TrackingFrame& frame, FramePoses& out);

private:
    int hand_ = -1, light_ = -1;
    std::array<bool, tracking::kMaxInstruments> ever_{};
    std::array<bool, tracking::kMaxInstruments> is_light_{};
};

/// FramePoses from the rig scenario's truth at `state.t_us` (instrument 0: working hand, 1: light pipe).
FramePoses poses_from_truth(const rig::SceneState& state);

}  // namespace eyesim::frame
