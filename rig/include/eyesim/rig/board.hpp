#pragma once
/// \file
/// The calibration checkerboard of the `checkerboard` scenario: its geometry, how it is moved in front of the
/// cameras, and its truth.
///
/// Board (kCheckerboard): a flat printed sheet of `squares_x` × `squares_y` alternating black and white squares
/// of side `square_mm`, the top-left square black, with a white margin one square wide all round (the quiet zone
/// corner detectors want). Its (squares_x − 1) × (squares_y − 1) inner corners are what calibration uses
/// (OpenCV's pattern size). Board frame (mm): origin at the first inner corner, x along a row of corners, y
/// down the columns, z = x × y into the board, the printed face on its −z side; inner corner (col, row) is at
/// (col · square_mm, row · square_mm, 0). The back of the sheet is plain grey.
///
/// Motion (BoardMotion): a person holds the board in front of one camera after the other. Each hold keeps the
/// board still for kBoardHoldS, then it moves to the next pose in kBoardMoveS (minimum-jerk translation,
/// spherical interpolation of the rotation), so fields in a hold are sharp and fields in between blurred. The
/// poses of a camera spread the board over its whole image (the centre, the four corners, the four edges, then
/// again with other tilts), tilted 10°–40° in varied directions, rolled up to ±25°, 40–50 mm from the camera at
/// the centre, 46–58 mm at the edges and 52–64 mm in the corners, pushed as far out as the squares and half a
/// square of margin stay inside the image (5 px). The poses are planned with the true cameras, as a user looks at
/// the live image, and are deterministic from the seed. The cameras take turns in blocks: the recording's holds are
/// split evenly between them in camera order. Everything is nearer the camera than the eye (74 mm and more).

#include "eyesim/rig/camera.hpp"
#include "eyesim/rig/truth.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <vector>

namespace eyesim::rig {

/// A checkerboard's layout (see the file comment).
struct BoardSpec {
    int squares_x = 9;        ///< squares along the board x axis
    int squares_y = 7;        ///< squares along the board y axis
    double square_mm = 3.0;   ///< side of one square

    /// Inner corners along x (OpenCV pattern width).
    int inner_cols() const noexcept { return squares_x - 1; }
    /// Inner corners along y (OpenCV pattern height).
    int inner_rows() const noexcept { return squares_y - 1; }
    /// Inner corner (col, row) in the board frame.
    Eigen::Vector3d corner_board_mm(int col, int row) const { return {col * square_mm, row * square_mm, 0.0}; }
    /// Inner corners row by row (row 0 first), board frame.
    std::vector<Eigen::Vector3d> corners_board_mm() const;
    /// Corners of the sheet's outline (margin included), board frame, clockwise from the top left.
    std::array<Eigen::Vector3d, 4> outline_board_mm() const;
    /// Reflectance class of the unit cell (a, b) = [a, a+1) × [b, b+1) squares in board coordinates:
    /// 0 black, 1 white (checker or margin), -1 off the sheet.
    int cell_class(int a, int b) const noexcept;
};

/// The board of the `checkerboard` scenario: 9 × 7 squares of 3 mm (8 × 6 inner corners, 33 × 27 mm sheet).
inline const BoardSpec kCheckerboard{};

/// Printed colours (sRGB code values, fully lit) and the back of the sheet.
inline constexpr std::array<float, 3> kBoardWhiteRgb{205.f, 205.f, 200.f};
/// See kBoardWhiteRgb.
inline constexpr std::array<float, 3> kBoardBlackRgb{24.f, 24.f, 26.f};
/// See kBoardWhiteRgb.
inline constexpr std::array<float, 3> kBoardBackRgb{120.f, 118.f, 112.f};

/// How long the board is held still at each pose, and how long a move to the next pose takes (seconds).
inline constexpr double kBoardHoldS = 0.4;
/// See kBoardHoldS.
inline constexpr double kBoardMoveS = 0.3;

/// Pose of the board: board frame → rig frame.
struct BoardPose {
    Eigen::Quaterniond q_board_to_rig = Eigen::Quaterniond::Identity();  ///< rotation board → rig
    Eigen::Vector3d origin_rig_mm = Eigen::Vector3d::Zero();             ///< first inner corner, rig frame

    /// Board-frame point → rig frame.
    Eigen::Vector3d to_rig(const Eigen::Vector3d& p_board_mm) const { return origin_rig_mm + q_board_to_rig * p_board_mm; }
};

/// The board's path through a recording (see the file comment). A pure function of time.
class BoardMotion {
public:
    /// Plans the holds of a recording of `duration_us` for `cameras` (at least one hold per camera).
    static BoardMotion plan(const BoardSpec& spec, const std::vector<CameraModel>& cameras, uint64_t seed,
                            double duration_us);

    /// Board pose at time t_us (held at the first pose before 0 and at the last after the end).
    BoardPose pose_at(double t_us) const;
    /// The board layout.
    const BoardSpec& spec() const noexcept { return spec_; }
    /// Number of holds.
    int hold_count() const noexcept { return static_cast<int>(holds_.size()); }
    /// Camera the hold `k` is meant for.
    int hold_camera(int k) const { return holds_.at(static_cast<size_t>(k)).camera; }
    /// Start time of hold `k` (its end is start + kBoardHoldS).
    double hold_start_us(int k) const { return k * (kBoardHoldS + kBoardMoveS) * 1e6; }

private:
    struct Hold {
        int camera = 0;
        BoardPose pose;
    };
    BoardSpec spec_;
    std::vector<Hold> holds_;
};

/// Board truth of one field index: the pose at `t_us` and, per camera, at its exposure mid-time with what the
/// camera sees of it (camera.hpp frames; corner motion over the exposure in frame px).
BoardTruth board_truth(const BoardMotion& motion, const std::vector<CameraModel>& cameras, int64_t index, double t_us);

}  // namespace eyesim::rig
