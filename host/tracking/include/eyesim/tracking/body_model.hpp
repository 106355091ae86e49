#pragma once
/// \file
/// Rigid bodies the tracker fits: the mechanical eye (markers about a centre fixed in the rig) and instruments
/// (markers along the shaft, tip offset). Filled from the rig's bodies file by `rig_adapter.hpp`.

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <string>

namespace eyesim::tracking {

/// Markers one body can carry.
inline constexpr int kMaxBodyMarkers = 8;
/// Instruments one tracker follows (every kind of the bodies file, for live use).
inline constexpr int kMaxInstruments = 6;

/// One marker of a body, in the body frame.
struct BodyMarker {
    std::uint8_t colour_class = 0;                      ///< 1..4
    Eigen::Vector3d pos_body_mm = Eigen::Vector3d::Zero();  ///< marker centre in the body frame (mm)
    double radius_mm = 0.0;                             ///< sphere radius (0: unknown)
};

/// The mechanical eye: body frame = eye frame, origin at the eye's rotation centre.
struct EyeModel {
    std::string name = "eye";                                   ///< for reports
    Eigen::Vector3d centre_rig_mm = Eigen::Vector3d::Zero();    ///< fixed rotation centre in the rig frame
    double radius_mm = 12.0;                                    ///< eye radius (reports, sanity checks)
    int marker_count = 0;                                       ///< valid entries in `markers`
    std::array<BodyMarker, kMaxBodyMarkers> markers{};          ///< markers in the eye frame
};

/// A straight instrument. Body frame as in scenes/bodies.json: origin at the tip, +z along the shaft from the tip
/// towards the handle; the markers are on that axis, so roll is unobservable unless a model adds off-axis markers.
struct InstrumentModel {
    std::string name;                                          ///< e.g. "forceps", "light_pipe"
    Eigen::Vector3d tip_body_mm = Eigen::Vector3d::Zero();     ///< tip in the body frame
    Eigen::Vector3d axis_body = Eigen::Vector3d::UnitZ();      ///< unit shaft direction (tip → handle)
    Eigen::Vector3d trocar_eye_mm = Eigen::Vector3d::Zero();   ///< entry point through the eye wall (eye frame)
    bool has_trocar = false;                                   ///< false: no insertion depth reported
    double shaft_radius_mm = 0.0;                              ///< shaft through the markers (occlusion model)
    double shaft_length_mm = 0.0;                              ///< tip to the shaft's end (0: unknown, unbounded)
    int marker_count = 0;                                      ///< valid entries in `markers`
    std::array<BodyMarker, kMaxBodyMarkers> markers{};         ///< markers in the body frame

    /// True when every marker lies on the shaft line through the tip (roll cannot be measured).
    bool markers_on_axis(double tol_mm = 1e-6) const;
};

/// All bodies of a scene.
struct BodySet {
    double marker_radius_mm = 0.0;                        ///< marker sphere radius (occlusion test; 0: unknown)
    EyeModel eye;                                         ///< the eye
    int instrument_count = 0;                             ///< valid entries in `instruments`
    std::array<InstrumentModel, kMaxInstruments> instruments{};  ///< the instruments
};

}  // namespace eyesim::tracking
