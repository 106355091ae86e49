#pragma once
/// \file
/// The synthetic surgeons' view of the shipped scenes' tissue (eye frame, mm): where the membranes lie that the
/// `peel`, `peel-hard` and `vitrectomy` scenarios work on. The scene files (scenes/membrane-peel.json,
/// scenes/vitrectomy.json) place their tissue here; a test checks that both agree.

#include <Eigen/Core>

#include <cmath>
#include <cstdint>

namespace eyesim::rig::surgeon {

/// Retina: the inner eye wall (eye radius 12 mm less 0.5 mm of choroid and sclera).
inline constexpr double kRetinaRadius_mm = 11.5;
/// Epiretinal membrane (membrane-peel): on the retina around the posterior pole (the macula).
inline const Eigen::Vector3d kMembraneCentreDir{0.0, 0.0, -1.0};
/// Its nodes' distance from the eye centre (just inside the retina).
inline constexpr double kMembraneSurface_mm = kRetinaRadius_mm - 0.05;
/// Mean geodesic radius of its outline and the outline's relative lobe depth: the outline lies between
/// radius·(1 ± irregularity), so a grasp at radius·(1 − irregularity) − 0.25 mm is always on the membrane.
inline constexpr double kMembraneRadius_mm = 2.5;
inline constexpr double kMembraneIrregularity = 0.25;
/// The scene's `outline_seed`.
inline constexpr std::uint32_t kMembraneOutlineSeed = 1;

/// The outline's geodesic radius at polar angle θ about the centre (the host's sim::MembraneOutline::radius_at,
/// which builds the mesh; a test checks that both agree). θ is measured from e1 = eye +x made perpendicular to
/// the centre direction, towards e2 = e1 × centre.
inline double membrane_outline_radius_mm(double theta, double mean_mm = kMembraneRadius_mm,
                                         double irregularity = kMembraneIrregularity,
                                         std::uint32_t seed = kMembraneOutlineSeed) {
    std::uint64_t s = seed * 0x9E3779B97F4A7C15ull + 0x632BE59BD9B4E019ull;
    auto next = [&s] {
        std::uint64_t z = (s += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return double((z ^ (z >> 31)) >> 11) * 0x1.0p-53;
    };
    double amp[4], phase[4], sum = 0.0;
    for (int k = 0; k < 4; ++k) {
        amp[k] = 0.2 + next();
        phase[k] = 2.0 * 3.14159265358979323846 * next();
        sum += amp[k];
    }
    double lobes = 0.0;
    for (int k = 0; k < 4; ++k) lobes += amp[k] / sum * std::cos(double(k + 2) * theta + phase[k]);
    return mean_mm * (1.0 + irregularity * lobes);
}

/// Vitreous membrane (vitrectomy): a flat 4 mm sheet in the posterior vitreous, its normal towards the
/// vitrector's side port as a vitrector through trocar 0 holds it.
inline const Eigen::Vector3d kSheetCentre_mm{2.5, 0.0, -5.0};
inline const Eigen::Vector3d kSheetNormal{-0.83, 0.16, -0.52};  ///< normalised where used
inline constexpr double kSheetSize_mm = 4.0;

/// The vitrector's side port in the instrument frame (tip at the origin, +z forward into the eye, +x: the shaft
/// frame's x axis, eye +x made perpendicular to the shaft), as the host's collision model has it.
inline const Eigen::Vector3d kVitrectorPort_mm{0.18, 0.0, -0.5};

}  // namespace eyesim::rig::surgeon
