#pragma once
/// \file
/// Ground truth of a synthetic recording: truth.jsonl, one JSON object per line, one line per field index i
/// (the i-th field of every camera; cameras are unsynchronised, so each camera's field has its own time).
///
/// Line layout (lengths mm, times µs, pixels in FIELD coordinates of that camera's field: x = frame column,
/// y = field row, integer = pixel centre; see camera.hpp):
/// ```
/// {"field": i, "t_us": <reference time = cam0 exposure mid-time>,
///  "cameras": [{"field": i, "parity": 0|1, "exposure_mid_us": ..., "exposure_us": ..., "end_us": ...}, ...],
///  "eye": {"center_rig_mm": [x,y,z], "q_eye_to_rig": [w,x,y,z]},
///  "instruments": [{"kind": "forceps", "trocar": 0, "tip_rig_mm": [..], "axis_rig": [..], "tip_eye_mm": [..],
///                   "axis_eye": [..], "insertion_mm": .., "jaw_opening": 0..1}, ...],
///  "pedal": {"axes": [a0, a1, a2], "buttons": b},
///  "markers": [{"body": "eye"|"<kind>", "id": k, "class": 1..4, "radius_mm": r, "center_rig_mm": [..],
///               "cams": [{"visible": true|false, "center_rig_mm": [..], "projected_px": [x,y],
///                         "centroid_px": [x,y], "radius_px": r, "area_px": a, "occluded_fraction": f}, ...]}],
///  "board": {"squares": [nx, ny], "square_mm": s, "q_board_to_rig": [w,x,y,z], "origin_rig_mm": [..],
///            "cams": [{"q_board_to_rig": [..], "origin_rig_mm": [..], "facing": true|false,
///                      "corners_in_image": n, "motion_px": m}, ...]}}
/// ```
/// `board` is present only when the scene has a calibration board (the `checkerboard` scenario; board.hpp).
/// Eye, instruments, pedal and the marker-level `center_rig_mm` are at `t_us`. Per camera, `center_rig_mm` is
/// the marker centre at that camera's exposure mid-time, `projected_px` its projection (camera model), and
/// `centroid_px` the centroid of the marker's rendered intensity (luma contribution, integrated over each
/// field pixel's aperture and the exposure, before noise and quantisation), which differs from the projected
/// centre under perspective, distortion, shading and motion blur. `axis` is the unit shaft direction from the
/// tip towards the handle. `visible` = some part of the marker is rendered in this field (area_px > 0); when
/// false, centroid_px equals projected_px (or is absent when the centre does not project).

#include "eyesim/rig/bodies.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <fstream>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace eyesim::rig {

/// Per-camera timing of field i.
struct CameraFieldTruth {
    int64_t field = 0;              ///< field index in this camera's stream
    int parity = 0;                 ///< 0 top, 1 bottom
    double exposure_mid_us = 0.0;   ///< truth time of this camera's field
    double exposure_us = 0.0;       ///< shutter time
    double end_us = 0.0;            ///< last active pixel delivered
};

/// One marker as seen by one camera.
struct MarkerCameraTruth {
    bool visible = false;                                       ///< area_px > 0
    bool projectable = false;                                   ///< the centre projects (in front, in model range)
    Eigen::Vector3d center_rig_mm = Eigen::Vector3d::Zero();    ///< at this camera's exposure mid-time
    Eigen::Vector2d projected_px = Eigen::Vector2d::Zero();     ///< projection of center_rig_mm, field px
    Eigen::Vector2d centroid_px = Eigen::Vector2d::Zero();      ///< rendered intensity centroid, field px
    double radius_px = 0.0;   ///< projected sphere radius (angular radius × fx), frame px horizontally
    double area_px = 0.0;     ///< visible coverage in field pixels, averaged over the exposure
    double occluded_fraction = 0.0;  ///< 1 - visible / unoccluded coverage (0 = clear; parts outside the image count as hidden)
};

/// One marker at field time i.
struct MarkerTruth {
    std::string body;          ///< "eye" or the instrument kind name
    int id = 0;                ///< marker index within its body
    int colour_class = 0;      ///< 1..4
    double radius_mm = 0.0;    ///< sphere radius
    Eigen::Vector3d center_rig_mm = Eigen::Vector3d::Zero();  ///< at t_us
    std::vector<MarkerCameraTruth> cams;                      ///< one per camera
};

/// One instrument's pose at t_us.
struct InstrumentTruth {
    InstrumentKind kind = InstrumentKind::kPick;
    int trocar = 0;                                          ///< trocar id it passes through
    Eigen::Vector3d tip_rig_mm = Eigen::Vector3d::Zero();
    Eigen::Vector3d axis_rig = Eigen::Vector3d::UnitZ();     ///< unit, tip → handle
    Eigen::Vector3d tip_eye_mm = Eigen::Vector3d::Zero();
    Eigen::Vector3d axis_eye = Eigen::Vector3d::UnitZ();     ///< unit, tip → handle
    double insertion_mm = 0.0;                               ///< tip depth behind the trocar along the axis
    double jaw_opening = 0.0;                                ///< forceps: 0 closed .. 1 open; others 0
};

/// Foot pedal state.
struct PedalTruth {
    std::array<double, 3> axes{};  ///< a0: main pedal 0..1 (forceps close / suction / injection), a1,a2: -1..1
    uint32_t buttons = 0;          ///< bit mask
};

/// The calibration board as one camera sees it (board.hpp frames).
struct BoardCameraTruth {
    Eigen::Quaterniond q_board_to_rig = Eigen::Quaterniond::Identity();  ///< at this camera's exposure mid-time
    Eigen::Vector3d origin_rig_mm = Eigen::Vector3d::Zero();             ///< first inner corner, same time
    bool facing = false;        ///< the printed face is towards the camera
    int corners_in_image = 0;   ///< inner corners projecting inside the frame [-0.5, 719.5] × [-0.5, 575.5]
    double motion_px = 0.0;     ///< largest inner-corner image displacement over the exposure, frame px
};

/// The calibration board at one field index.
struct BoardTruth {
    int squares_x = 0;          ///< squares along the board x axis
    int squares_y = 0;          ///< squares along the board y axis
    double square_mm = 0.0;     ///< side of one square
    Eigen::Quaterniond q_board_to_rig = Eigen::Quaterniond::Identity();  ///< at t_us
    Eigen::Vector3d origin_rig_mm = Eigen::Vector3d::Zero();             ///< at t_us
    std::vector<BoardCameraTruth> cams;                                  ///< one per camera
};

/// One line of truth.jsonl.
struct FieldTruth {
    int64_t field = 0;                          ///< field index i
    double t_us = 0.0;                          ///< reference time (cam0 exposure mid-time)
    std::vector<CameraFieldTruth> cameras;      ///< per camera
    Eigen::Vector3d eye_center_rig_mm = Eigen::Vector3d::Zero();
    Eigen::Quaterniond q_eye_to_rig = Eigen::Quaterniond::Identity();  ///< rotation eye→rig
    std::vector<InstrumentTruth> instruments;   ///< usually two: tissue instrument and light pipe
    PedalTruth pedal;
    std::vector<MarkerTruth> markers;           ///< every marker of every body in the scene
    std::optional<BoardTruth> board;            ///< the calibration board, when the scene has one
};

/// Serialises one line (no trailing newline).
std::string truth_to_json_line(const FieldTruth& truth);
/// Parses one line; throws RigError "<where>: <key>: <why>" (where = e.g. "truth.jsonl:12").
FieldTruth truth_from_json_line(const std::string& line, const std::string& where);

/// Reads a whole truth.jsonl. Throws RigError naming file and line.
std::vector<FieldTruth> read_truth(const std::string& path);

/// Appends lines to a truth.jsonl.
class TruthWriter {
public:
    /// Creates/truncates `path`; throws RigError if it cannot.
    explicit TruthWriter(const std::string& path);
    /// Writes one line.
    void write(const FieldTruth& truth);
    /// Flushes and closes; throws RigError on a write failure.
    void close();

private:
    std::string path_;
    std::ofstream out_;
};

}  // namespace eyesim::rig
