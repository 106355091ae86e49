#pragma once
/// \file
/// Motion scenarios of the rig: the eye (3 rotational DOF on springs), two instruments through the trocars and
/// the foot pedal as smooth, deterministic functions of time (seeded).
///
/// Scenarios: "static" (everything still), "sweep" (slow sweeps of both instruments and the eye over the whole
/// working volume), "surgery" (membrane-peel-like strokes near the retina, forceps closing/opening with the
/// pedal, light pipe following), "fast" (quick moves: motion blur of several pixels), "occlusion" (instruments
/// crossing, retracting out of view, large eye rotations hiding markers behind the eye), "injection" (retina
/// relocation: the injection needle penetrates the posterior retina, the pedal injects, a quick flick at 3 s),
/// "wand" (extrinsic calibration: the calibration wand of bodies.json waved by hand through the working volume
/// around the eye, the eye at rest, both instruments lifted out of the eye and clear of every camera's view),
/// "checkerboard" (intrinsic calibration: the "static" scene with a calibration checkerboard held in front of
/// each camera in turn at many poses; board.hpp).
///
/// Synthetic surgeons (rig/surgeon.hpp says where their tissue lies), deterministic from the seed with human-like
/// variation (grasp point, pull direction, timing, 8–12 Hz tremor): "peel" (forceps to the epiretinal membrane's
/// edge, jaws closed with the pedal, lift and pull along the surface, release, regrasp elsewhere, pull again),
/// "peel-hard" (the same, pulled too far too fast: the rim lifts off), "vitrectomy" (the vitrector's port swept
/// over a vitreous membrane with the pedal pressed: suction and cutting). Their tips move through the trocar and
/// stay inside the eye, clear of the retina.

#include "eyesim/rig/board.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/camera.hpp"
#include "eyesim/rig/truth.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace eyesim::rig {

/// Pose of one instrument, in the eye frame (it goes through a trocar fixed on the eye).
struct InstrumentPose {
    InstrumentKind kind = InstrumentKind::kPick;
    int trocar = 0;                                        ///< trocar id
    Eigen::Vector3d tip_eye_mm = Eigen::Vector3d::Zero();  ///< tip, eye frame
    Eigen::Vector3d axis_eye = Eigen::Vector3d::UnitZ();   ///< unit, tip → handle, eye frame
    double insertion_mm = 0.0;                             ///< tip depth behind the trocar (negative: outside)
    double jaw_opening = 0.0;                              ///< forceps jaws 0 closed .. 1 open
};

/// State of the whole scene at one instant.
struct SceneState {
    double t_us = 0.0;                                          ///< time on the recording clock
    Eigen::Quaterniond q_eye_to_rig = Eigen::Quaterniond::Identity();  ///< eye rotation
    Eigen::Vector3d eye_center_rig_mm = Eigen::Vector3d::Zero();       ///< fixed rotation centre
    std::vector<InstrumentPose> instruments;                    ///< tissue instrument first, then light pipe
    PedalTruth pedal;                                           ///< foot pedal
    std::optional<BoardPose> board;                             ///< calibration board, when the scene has one
    bool wand_present = false;                                  ///< the calibration wand is in the scene
    Eigen::Vector3d wand_origin_rig_mm = Eigen::Vector3d::Zero();  ///< wand frame origin (marker 0's centre)
    Eigen::Vector3d wand_axis_rig = Eigen::Vector3d::UnitZ();      ///< unit, marker 0 → last marker

    /// Eye-frame point → rig frame.
    Eigen::Vector3d eye_to_rig(const Eigen::Vector3d& p_eye_mm) const { return eye_center_rig_mm + q_eye_to_rig * p_eye_mm; }
};

/// Names accepted by `Scenario::make`.
std::vector<std::string> scenario_names();

/// A deterministic motion scenario. `state_at` is a pure function of t (any t, also before 0).
class Scenario {
public:
    /// Builds scenario `name` for `seed`, valid on [-1 s, duration_us + 1 s]. Throws RigError on an unknown name.
    /// `cameras`: the rig the recording is made with (the checkerboard is held in front of these; empty =
    /// default_rig()).
    static Scenario make(const std::string& name, uint64_t seed, double duration_us, const Bodies& bodies,
                         const std::vector<CameraModel>& cameras = {});

    /// Scene state at time t_us.
    SceneState state_at(double t_us) const;
    /// Scenario name.
    const std::string& name() const noexcept { return name_; }
    /// Instrument kinds in the scene (tissue instrument, light pipe).
    const std::vector<InstrumentKind>& kinds() const noexcept { return kinds_; }
    /// The calibration board's motion ("checkerboard"), or null when the scene has no board.
    const BoardMotion* board() const noexcept { return board_.get(); }
    /// Whether the calibration wand is in the scene ("wand").
    bool has_wand() const noexcept { return wand_; }

    /// Eye spring model: natural frequency (Hz) and damping ratio of each rotation axis.
    static constexpr double kEyeSpringHz = 2.0;
    static constexpr double kEyeDamping = 0.7;

private:
    struct Wave { double amp, freq_hz, phase; };
    static double eval(const std::vector<Wave>& waves, double t_s);

    std::string name_;
    std::vector<InstrumentKind> kinds_;
    Bodies bodies_;
    // Per instrument: pivot tilt x/y (rad) about the trocar normal, insertion (mm); sums of sines around bases.
    struct InstrumentMotion {
        double tilt_x0 = 0, tilt_y0 = 0, insertion0 = 10;
        std::vector<Wave> tilt_x, tilt_y, insertion;
        double retract_start_s = 1e30, retract_end_s = 1e30;  ///< occlusion: pulled out of the eye and back
        double flick_s = 1e30;  ///< injection: a quick 4° tilt starting here (fast move along the retina)
    };
    std::vector<InstrumentMotion> motion_;
    // Synthetic surgeon: the tissue instrument's tip (or, aim_port_, the vitrector's port) through waypoints with
    // minimum-jerk segments, plus tremor; the main pedal axis follows the waypoints too.
    struct Waypoint { double t_s; Eigen::Vector3d p_eye_mm; double pedal; };
    std::vector<Waypoint> path_;
    std::vector<Wave> tremor_[3];
    bool aim_port_ = false;
    Eigen::Vector3d path_at(double t_s, double& pedal) const;
    std::vector<Wave> pedal0_, pedal1_, pedal2_;
    double pedal0_base_ = 0.0;
    bool injection_ = false;  ///< "injection": the needle reaches the retina, pedal = injection pressure
    // "wand": marker centroid (rig frame, mm) and rod direction (azimuth with a steady turn, elevation) as sums
    // of sines; the eye stays at rest.
    bool wand_ = false;
    Eigen::Vector3d wand_centre0_mm_ = Eigen::Vector3d::Zero();
    std::vector<Wave> wand_centre_[3], wand_elevation_;
    double wand_azimuth0_ = 0.0, wand_azimuth_rate_ = 0.0;
    double wand_centroid_mm_ = 0.0;     // marker centroid along the rod from marker 0
    double wand_clear_mm_ = 0.0;        // least distance of the marker centroid from the eye centre
    std::vector<Wave> wand_azimuth_;
    void wand_state(double t_s, SceneState& st) const;
    // Eye rotation vector (rad) sampled on a fixed grid by integrating the spring model (RK4).
    double eye_t0_s_ = -1.0, eye_dt_s_ = 0.002;  // RK4 step and table spacing (2 Hz spring: ω·dt = 0.025)
    std::vector<Eigen::Vector3d> eye_rot_, eye_rate_;
    std::shared_ptr<const BoardMotion> board_;  ///< "checkerboard": the board's path
};

}  // namespace eyesim::rig
