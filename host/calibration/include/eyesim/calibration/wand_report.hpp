#pragma once
/// \file
/// What `eyesim calibrate` tells people: per-camera figures of the wand solve (image error px, world error mm,
/// samples, coverage, time offset), the wand-length check, the rig frame fit, the intrinsics' figures, and, when
/// a true rig is given, the errors against it; as one JSON object and as a report folder (index.html + PNGs).

#include "eyesim/calibration/wand.hpp"
#include "eyesim/rig/camera.hpp"

#include <nlohmann/json.hpp>

#include <optional>
#include <string>
#include <vector>

namespace eyesim::calibration {

/// One camera of a calibrated rig against the true one.
struct CameraTruthError {
    double centre_error_um = 0;        ///< |camera centre − true centre| in the rig frame
    double rotation_error_deg = 0;     ///< angle of R · R_trueᵀ
    double fx_error_pct = 0, fy_error_pct = 0;  ///< (f − f_true) / f_true × 100
    double time_offset_error_us = 0;   ///< field_time_offset_us − the true one
    /// Points of the working volume (a 2 mm grid over the box |x|, |y| ≤ 30 mm, −20 ≤ z ≤ 35 mm round the eye,
    /// outside the eye, inside the true camera's image): calibrated projection − true projection, RMS and max,
    /// frame px. What the tracker sees of the calibration error.
    double projection_error_px_rms = 0, projection_error_px_max = 0;
};

/// Compares every camera of `calibrated` with `truth` (same count). Throws CalibrationError on a count mismatch.
std::vector<CameraTruthError> compare_with_truth(const std::vector<rig::CameraModel>& calibrated,
                                                 const std::vector<rig::CameraModel>& truth,
                                                 const rig::EyeBody& eye);

/// Intrinsics figures per camera when they were calibrated from a board.
struct BoardFigures {
    double rms_px = 0;          ///< reprojection RMS over the board corners, frame px
    int views_used = 0;         ///< board views in the fit
    double coverage = 0;        ///< fraction of a 16 × 12 grid with a corner
    std::string coverage_png;   ///< picture of the views (inside the report folder), or ""
};

/// Everything the summary and the report show.
struct CalibrationSummary {
    std::string out;                       ///< rig.yaml written
    std::string wand_dir;                  ///< wand recording
    std::string board_dir;                 ///< board recording ("" when intrinsics came from a file)
    std::string intrinsics_file;           ///< --intrinsics file ("" when from the board)
    int64_t fields = 0;                    ///< wand fields per camera searched
    double detect_s = 0;                   ///< FPGA model over the wand recording, wall s
    std::vector<rig::CameraModel> cameras; ///< the calibrated rig as written
    WandViews views;                       ///< per camera views and reasons (views themselves may be empty)
    WandSolve solve;                       ///< the bundle adjustment
    RigFrameFit rig_frame;                 ///< the rig frame from the eye
    std::vector<std::optional<BoardFigures>> board;  ///< per camera, when calibrated from the board
    std::vector<CameraTruthError> truth;   ///< per camera against --truth-rig (empty: not given)
    std::string truth_file;                ///< the true rig.yaml (scoring only)
    std::vector<std::string> warnings;     ///< non-fatal findings
};

/// The summary as one JSON object (docs/calibration.md, "Command").
nlohmann::json summary_json(const CalibrationSummary& s);

/// Writes `dir`/index.html with tables and pictures (residual histograms, image coverage, wand-length errors).
/// Returns the path of index.html. Throws CalibrationError when the folder cannot be written.
std::string write_report(const std::string& dir, const CalibrationSummary& s);

}  // namespace eyesim::calibration
