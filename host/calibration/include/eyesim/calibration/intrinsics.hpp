#pragma once
/// \file
/// Intrinsic calibration of one camera from a recording of a checkerboard held still at many poses.
///
/// Board: a flat checkerboard with `board_cols` × `board_rows` INNER corners (OpenCV's pattern size: a board of
/// (board_cols + 1) × (board_rows + 1) squares) of side `square_mm`, with a white margin round the squares.
/// The rig's own board (rig::kCheckerboard, the `checkerboard` scenario) is 9 × 7 squares of 3 mm: 8 × 6 inner
/// corners, the defaults below. The square size only scales the board poses; K and distortion do not depend on it.
///
/// Pipeline:
/// 1. Scan: every `field_step`-th field (`woven_frames`: the first field of every `field_step`-th frame, a frame
///    being the field pair (2n, 2n+1)) is searched for the whole board (`find_board_corners`). A field is 720 × 288
///    and its row y of parity p is frame row 2y + p, so corners are kept in FRAME pixels: field (x, y) → (x, 2y + p).
/// 2. Holds: a scan whose corners moved less than `still_px` (frame px, every corner) since the previous scan of
///    the same parity AND until the next one is still (a moving board blurs, and woven, combs); still scans at
///    most one same-parity step apart that agree make one hold, one view.
/// 3. Selection: when there are more holds than `max_views`, a well spread subset (greedy farthest point on the
///    board's image position, size and foreshortening).
/// 4. Corners of each chosen view (`refine_board_corners`) on the hold's fields (every field from its first still
///    scan to its last) averaged per parity (noise down by their number), both parities' rows in one fit at their
///    own frame rows (a single parity cannot place an edge that lies between its rows): fields: each parity with
///    its own levels and shading; woven: one set for both, i.e. the woven frame.
/// 5. cv::calibrateCamera with K (fx, fy, cx, cy, no skew) and 5 distortion coefficients k1 k2 p1 p2 k3 in FRAME
///    pixels (720 × 576), exactly the model of rig::CameraModel; views whose own RMS is beyond 3× the median
///    (and 0.02 px) are dropped and the fit repeated (twice at most).
/// 6. Coverage: a PNG of the frame with every view's board outline and corners, and the fraction of a 16 × 12
///    grid over the image that holds a corner.

#include "eyesim/calibration/wand.hpp"
#include "eyesim/rig/board.hpp"
#include "eyesim/rig/camera.hpp"

#include <opencv2/core.hpp>

#include <cstdint>
#include <string>
#include <vector>

namespace eyesim::rig {
class Recording;
}

namespace eyesim::calibration {

/// Board and view-selection settings.
struct IntrinsicsOptions {
    int board_cols = rig::kCheckerboard.inner_cols();  ///< inner corners along a board row (OpenCV pattern width)
    int board_rows = rig::kCheckerboard.inner_rows();  ///< inner corners along a board column
    double square_mm = rig::kCheckerboard.square_mm;   ///< side of one square
    bool woven_frames = false;   ///< corners from frames woven of fields (2n, 2n+1) instead of single fields
    int max_views = 40;          ///< at most this many views go to calibrateCamera
    int field_step = 2;          ///< search every n-th field (woven: frame) for the board; the corners come from
                                 ///< every field of a hold either way
    double still_px = 0.3;       ///< a scan is still when no corner moved more than this (frame px) to its neighbours
    int64_t max_fields = -1;     ///< scan only the first n fields (< 0: all)
    std::string coverage_png;    ///< write the coverage picture here ("" = none)
};

/// One view given to calibrateCamera.
struct IntrinsicsView {
    int64_t first_field = 0;      ///< first field of the hold's still scans
    int64_t last_field = 0;       ///< last field of the hold's still scans (woven: its frame's second field)
    int scans = 0;                ///< still scans in the hold (woven: frames, two fields each)
    double rms_px = 0;            ///< reprojection RMS of this view after the fit, frame px
    bool used = true;             ///< false: dropped as an outlier or left out by the selection
};

/// Result of `calibrate_intrinsics`.
struct IntrinsicsResult {
    /// The recording's camera with fx, fy, cx, cy, dist (frame px, 720 × 576, as rig.yaml) and max_r2 calibrated;
    /// name, field order, clock, exposure and pose are the recording's own (the pose is not calibrated here).
    rig::CameraModel camera;
    double rms_px = 0;            ///< reprojection RMS over every corner of the views used, frame px
    int views_used = 0;           ///< views in the final fit
    int holds = 0;                ///< still holds found (views before selection)
    int fields_seen = 0;          ///< scanned fields in which the whole board was found
    int64_t scans = 0;            ///< fields scanned
    double coverage = 0;          ///< fraction of a 16 × 12 grid over the frame with a corner of a used view
    std::vector<IntrinsicsView> views;                           ///< every hold, in time order
    std::vector<std::vector<cv::Point2f>> corners_frame_px;      ///< per used view: corners row by row, frame px
    std::vector<cv::Mat> board_rvecs, board_tvecs;               ///< per used view: board → camera (mm)
    std::string coverage_png;     ///< the picture written, or "" when none was asked for
};

/// Calibrates camera `cam` of a board recording (see the file comment). Throws CalibrationError naming the
/// camera when the board is never found, or found still in fewer than 3 holds; std::invalid_argument on bad
/// options. `progress` (may be empty) gets phase kDetect (done/total scans, samples_per_camera[cam] = scans with
/// the board) and kSolve.
IntrinsicsResult calibrate_intrinsics(rig::Recording& rec, int cam, const IntrinsicsOptions& opt,
                                      const Progress& progress = {});

/// Detects the board in one 720 × 288 luma field of parity `parity` (or, parity < 0, a 720 × 576 frame): corners
/// row by row in FRAME pixels, or empty when the whole board is not found. cv::findChessboardCorners, then
/// cv::cornerSubPix on the field stretched to frame geometry (good to a few tenths of a pixel: what finding the
/// board and telling still from moving need; `refine_board_corners` gives the corners calibration uses).
std::vector<cv::Point2f> find_board_corners(const cv::Mat& luma, int parity, int board_cols, int board_rows);

/// One image of a still board for corner refinement: luma (CV_32F) whose row r is frame row
/// row_scale · r + row_offset (a field of parity p: 2, p; a frame: 1, 0). Each sample integrates the frame pixel
/// square around its centre, as a camera's frame-integration CCD does.
struct BoardImage {
    cv::Mat luma;          ///< CV_32F, 720 wide
    int row_scale = 1;     ///< frame rows per image row
    int row_offset = 0;    ///< frame row of image row 0
    int group = 0;         ///< photometric group 0..7: images of one group share the corner model's levels and shading
};

/// Refines board corners (frame px, row by row, as `find_board_corners` gives them) by a least-squares fit of a
/// corner model to the samples of `images` within 0.4 squares of each corner: two straight edges through the corner
/// (their angles free), an edge spread σ (a Gaussian, free), the two levels with a linear shading across the window
/// (per photometric group), each sample integrated over its pixel square (3 × 3 points). The model is point-symmetric about the corner, as a
/// checkerboard corner is, so the fit has no bias from the edge profile; it uses the actual sample positions, so a
/// field's rows two frame rows apart are used as they are. `information` (may be null) gets each corner's
/// information matrix (inverse covariance up to the noise variance; zero where the fit failed), to weigh fits of
/// the same corners. Returns the number of corners refined; a corner whose fit fails keeps its position.
int refine_board_corners(const std::vector<BoardImage>& images, int board_cols, int board_rows,
                          std::vector<cv::Point2f>& corners, std::vector<cv::Matx22d>* information = nullptr);

/// A calibrated camera against the true one.
struct IntrinsicsError {
    double fx_error_pct = 0;       ///< (fx − fx_true) / fx_true × 100
    double fy_error_pct = 0;       ///< (fy − fy_true) / fy_true × 100
    double cx_error_px = 0;        ///< cx − cx_true
    double cy_error_px = 0;        ///< cy − cy_true
    /// Whole-model error over the image: for frame pixels on an 8 px grid, the calibrated projection of the true
    /// ray through the pixel minus the pixel (K and distortion together), max and RMS, frame px.
    double max_image_error_px = 0;
    double rms_image_error_px = 0;
    /// Distortion alone: the distortion's pixel displacement (distorted − undistorted projection) of the same
    /// rays under each model, max difference over the grid, frame px.
    double max_distortion_error_px = 0;
};

/// Compares a calibration with the truth over the whole frame.
IntrinsicsError compare_intrinsics(const rig::CameraModel& calibrated, const rig::CameraModel& truth);

/// Largest r² (≤ 2) of undistorted normalised radius up to which the model's radial mapping is monotonic, × 0.9;
/// what rig::CameraModel::max_r2 should be for a calibrated distortion.
double monotonic_max_r2(const std::array<double, 5>& dist);

}  // namespace eyesim::calibration
