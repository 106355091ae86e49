#pragma once
/// \file
/// Weighted rigid fits (Kabsch/Umeyama without scale): rotation + translation between corresponding point sets,
/// and rotation-only about a fixed centre (the mechanical eye). Fixed-size, allocation-free.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <span>

namespace eyesim::tracking {

/// Result of a rigid fit mapping body-frame points onto measured rig-frame points: X_rig ≈ R·X_body + t.
struct RigidFit {
    Eigen::Matrix3d R = Eigen::Matrix3d::Identity();  ///< rotation body→rig
    Eigen::Vector3d t_mm = Eigen::Vector3d::Zero();   ///< translation body→rig (mm)
    double rms_mm = 0.0;      ///< RMS distance of the fitted body points from the measured ones
    bool ok = false;          ///< false: too few points, non-finite data or a degenerate (collinear) set
};

/// Weighted Kabsch/Umeyama (no scale) on n ≥ 3 non-collinear pairs: minimises Σ wᵢ‖R·bᵢ + t − mᵢ‖².
/// `weights` may be empty (all 1). Returns ok = false (and identity) when the spread of the body points is
/// rank < 2, so the rotation is not determined.
RigidFit fit_rigid(std::span<const Eigen::Vector3d> body_mm, std::span<const Eigen::Vector3d> measured_mm,
                   std::span<const double> weights = {});

/// Rotation only about a known centre (translation fixed): minimises Σ wᵢ‖R·bᵢ + c − mᵢ‖² for n ≥ 2 vectors
/// that are not all parallel. Used for the eye, whose centre is fixed in the rig.
RigidFit fit_rotation_about(const Eigen::Vector3d& centre_rig_mm, std::span<const Eigen::Vector3d> body_mm,
                            std::span<const Eigen::Vector3d> measured_mm, std::span<const double> weights = {});

/// Rotation between two orientations in degrees (angle of Ra·Rbᵀ), robust near 0° and 180°.
double rotation_angle_deg(const Eigen::Matrix3d& Ra, const Eigen::Matrix3d& Rb);

}  // namespace eyesim::tracking
