#pragma once
/// \file
/// Scene files (scenes/*.json): which instruments, collision cases, tissue, integrator and warnings a training
/// scene needs. The host frame loop runs only what a scene declares: a scene without tissue runs no tissue code,
/// a scene without deformation use runs ZCOLL in boolean mode. The format is specified in docs/simulation.md
/// ("Scene files"); `parse_scene` validates every key and rejects unknown ones.

#include "eyesim/sim/collision/convex_objects.hpp"
#include "eyesim/sim/collision/instrument.hpp"
#include "eyesim/sim/tissue/integrator.hpp"
#include "eyesim/sim/tissue/tissue_params.hpp"

#include <Eigen/Core>

#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace eyesim::sim::scenes {

/// How ZCOLL (collision case 4) runs for an instrument against the scene's tissue.
enum class ZcollMode : uint8_t {
    kOff,      ///< no case-4 collision for this instrument
    kPush,     ///< deformation vectors → Eq. 1 node pushes, and the forceps grab rule
    kBoolean,  ///< collision yes/no only: no deformation vectors, no read-back
    kSuction,  ///< vitrector: central-projection cone, colour-only analysis, force ∝ 1/distance
};

/// Which tracked instrument drives a scene instrument: the handpiece in the working hand, or the light pipe.
/// (The simulator's handpieces are generic; the scene decides which virtual instrument each one is.)
enum class InstrumentRole : uint8_t { kTissue, kLight };

/// One instrument of the scene.
struct InstrumentSpec {
    collision::InstrumentKind kind = collision::InstrumentKind::Pick;  ///< virtual instrument
    InstrumentRole role = InstrumentRole::kTissue;                     ///< tracked handpiece driving it
    ZcollMode zcoll = ZcollMode::kOff;                                 ///< case-4 mode against the tissue
    bool cuts = false;             ///< vitrector: removes tissue in the cutter's reach while the pedal is pressed
    float pedal_threshold = 0.5f;  ///< pedal axis value (0..1) above which the instrument function is on
    float active_from_s = 0.0f;    ///< several instruments may share a role (forceps, then pick, then
                                   ///< vitrector): the one with the latest active_from_s ≤ t is in use
};

/// Tissue models a scene may hold.
enum class TissueKind : uint8_t { kNone, kMembrane, kRetina };

/// Where and how a membrane lies.
enum class MembraneShape : uint8_t {
    kEpiretinal,  ///< on the retina's inner surface, irregular outline, rim attached (the paper's rule)
    kFlat,        ///< a flat square patch (Table-3 meshes; benchmarks and free-hand recordings)
};

/// Tissue set-up (paper §4.5).
struct TissueSpec {
    TissueKind kind = TissueKind::kNone;
    MembraneShape shape = MembraneShape::kEpiretinal;  ///< membrane: on the retina, or a flat patch
    int triangles = 1000;                     ///< membrane size: ≈400, ≈1k or ≈3k (flat: the Table 3 meshes)
    float width_mm = 5.0f;                    ///< epiretinal: mean diameter of the outline; flat: side length
    /// Epiretinal: direction of the membrane's centre from the eye centre (the macula by default; normalised);
    /// flat: the patch centre (normal +z, facing the cornea).
    Eigen::Vector3f center_eye_mm{0.0f, 0.0f, -11.0f};
    Eigen::Vector3f normal_eye{0.0f, 0.0f, 1.0f};  ///< flat: the patch's normal (the side facing the instruments)
    float outline_irregularity = 0.25f;       ///< epiretinal: relative depth of the outline's lobes (0 = circle)
    int outline_seed = 1;                     ///< epiretinal: shape of the lobes
    float lift_threshold_mm = 0.1f;           ///< epiretinal: a node lifted this far off the retina is peeled
    /// When set, the membrane is placed at the first tracked tip of the tissue instrument plus this distance
    /// along the instrument's forward axis, facing the instrument (for free-hand recordings).
    std::optional<float> anchor_ahead_of_tip_mm;
    /// With an anchor: place the membrane in front of the vitrector's side port (facing it) instead of the tip.
    bool anchor_to_port = false;
    int retina_rings = 16;                    ///< retina hemisphere latitude bands
    int retina_segments = 48;                 ///< retina hemisphere longitude segments
    tissue::IntegratorKind integrator = tissue::IntegratorKind::kPaperEuler;
    int substeps = 8;                         ///< tissue steps per tracking frame
    tissue::MaterialParams material;          ///< built into the springs
    tissue::TissueParams rules;               ///< a_max, v_max, p_tear, warnings, injection
};

/// Collision settings.
struct CollisionSpec {
    bool eye_sphere = true;                   ///< case 2: tip vs inner eyeball sphere
    float eye_warn_distance_mm = 0.5f;        ///< case-2 warning distance
    int zcoll_resolution_px = 32;             ///< ZCOLL viewport R×R
    float zcoll_half_width_mm = 0.6f;         ///< V: half width around the tip
    float zcoll_ahead_mm = 0.4f;              ///< V: in front of the tip
    float zcoll_behind_mm = 2.0f;             ///< V: behind the tip along the shaft
    float suction_half_angle_deg = 30.0f;     ///< vitrector suction cone
    float suction_length_mm = 1.5f;
    std::vector<collision::ConvexObject> convex_objects;  ///< case 3 (FCL)
};

/// A scene's rules for passing the task (every rule present must hold). Absent rules are not checked.
struct ScoringSpec {
    std::optional<double> min_grabs;              ///< forceps grasps of tissue
    std::optional<double> min_peeled_percent;     ///< membrane area lifted off the retina, % of the membrane
    std::optional<double> min_removed_mm2;        ///< tissue removed by the vitrector
    std::optional<double> min_nodes_detached;     ///< retina nodes detached by injections
    std::optional<double> max_lift_off_warnings;  ///< frames with a retina lift-off warning
    std::optional<double> max_tear_warnings;      ///< frames with a tear warning
    std::optional<double> max_retina_contacts;    ///< case-2 warnings: an instrument tip at the eye wall
    std::optional<double> max_object_contacts;    ///< case-3 contacts
    std::optional<double> max_time_s;             ///< task time
    bool any() const {
        return min_grabs || min_peeled_percent || min_removed_mm2 || min_nodes_detached || max_lift_off_warnings ||
               max_tear_warnings || max_retina_contacts || max_object_contacts || max_time_s;
    }
};

/// A whole scene.
struct Scene {
    std::string name;                         ///< e.g. "membrane-peel"
    std::string description;                  ///< one line for people
    std::string scenario = "surgery";         ///< rig scenario used when the scene is run on synthetic data
    float duration_s = 4.0f;                  ///< default length of a synthetic run
    std::vector<InstrumentSpec> instruments;  ///< per role, ordered by active_from_s
    CollisionSpec collision;
    TissueSpec tissue;
    ScoringSpec scoring;                      ///< pass rules of the task

    /// True when tissue must be simulated.
    bool needs_tissue() const { return tissue.kind != TissueKind::kNone; }
    /// True when some instrument needs deformation vectors (push mode).
    bool needs_deformation() const;
    /// The instrument driven by `role` at scene time `t_s`, or null.
    const InstrumentSpec* instrument(InstrumentRole role, float t_s) const;
};

/// A scene file error; `what()` is one line "FILE: KEY: what is wrong".
class SceneError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// Reads and validates a scene file.
Scene load_scene(const std::string& path);
/// Parses scene JSON; `origin` names the source in error messages.
Scene parse_scene(const std::string& json_text, const std::string& origin);

/// Canonical names used in scene files.
const char* to_string(ZcollMode m);
const char* to_string(TissueKind k);

}  // namespace eyesim::sim::scenes
