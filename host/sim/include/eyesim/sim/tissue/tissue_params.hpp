#pragma once
/// \file
/// Parameters of a tissue: material (used when the springs are built) and the paper's run-time rules.
/// Units: mm, s, mg; force nN (= mg·mm/s²), stiffness nN/mm, damping nN·s/mm.

#include <Eigen/Core>

#include <limits>

namespace eyesim::sim::tissue {

/// Infinity: a limit that never triggers.
inline constexpr float kUnlimited = std::numeric_limits<float>::infinity();

/// Material, applied when a MassSpringSystem is built from a triangle mesh. The values are tuning values (the
/// paper found its parameters "in an iterative process"), not measured tissue properties.
struct MaterialParams {
    float areal_density_mg_per_mm2 = 0.02f;   ///< node mass = density × (1/3 of its triangles' area)
    float edge_stiffness_nN_per_mm = 1000.0f; ///< k of every edge spring
    float edge_damping_nN_s_per_mm = 0.05f;   ///< c of every edge spring (axial)
    float bending_stiffness_nN_per_mm = 0.0f; ///< k of bending springs across shared edges; 0 = none built
    float bending_damping_nN_s_per_mm = 0.0f; ///< c of bending springs
    float rest_length_scale = 1.0f;           ///< rest length = scale × mesh edge length (< 1: pre-tension)
};

/// Run-time rules of paper §4.5 and the tool and safety constants. All may change between steps.
struct TissueParams {
    // --- the paper's stability rules ---
    float a_max_mm_per_s2 = kUnlimited;  ///< per-node acceleration limit (paper Euler clamps to it)
    float v_max_mm_per_s = kUnlimited;   ///< per-node speed limit on the velocity kept after a step; 0 allowed
    float p_tear_percent = kUnlimited;   ///< tear when |a| > a_max·(1 + p_tear/100); infinite = no tearing
    // --- loads ---
    Eigen::Vector3f gravity_mm_per_s2 = Eigen::Vector3f::Zero();  ///< body acceleration (buoyancy-corrected)
    float drag_per_s = 0.0f;             ///< viscous drag of the surrounding fluid: f = −drag·m·v
    // --- membrane peeling ---
    float lift_off_force_nN = kUnlimited;  ///< warn when the net spring force on a fixed node exceeds this
    float suction_min_distance_mm = 0.05f; ///< suction 1/d force is evaluated at max(d, this) (no singularity)
    // --- retina relocation ---
    float detach_pressure_min = 0.0f;            ///< injection pressure below which nothing detaches
    float detach_radius_mm_per_pressure = 1.0f;  ///< d = this × p
    float injection_force_nN_per_pressure = 1.0f;///< constant force magnitude on a detached node = this × p
    float tear_warning_speed_mm_per_s = kUnlimited; ///< needle speed along the retina that raises a tear warning
    // --- safety: the tissue lives inside the eye ---
    Eigen::Vector3f container_centre_mm = Eigen::Vector3f::Zero();  ///< eye centre
    float container_radius_mm = kUnlimited;  ///< nodes are kept inside this sphere (eye wall), velocity stopped
    // --- solver settings ---
    float cg_tolerance = 1e-6f;    ///< implicit Euler: relative residual of the conjugate-gradient solve
    int cg_max_iterations = 200;   ///< implicit Euler: CG iteration cap
    int xpbd_iterations = 8;       ///< XPBD: Gauss–Seidel sweeps per substep
};

}  // namespace eyesim::sim::tissue
