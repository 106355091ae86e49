#pragma once
/// \file
/// The host frame loop: per tracking frame, instrument poses (eye frame) → only the collision cases and tissue
/// the scene needs → tissue substeps → events and scores → optional render. Per-stage timers give the paper's
/// Table 4 breakdown. Everything is sized in the constructor; `step` does not allocate (events go to a
/// pre-reserved list whose overflow is counted).

#include "eyesim/frame/stage_timer.hpp"
#include "eyesim/sim/collision/contact.hpp"
#include "eyesim/sim/collision/convex_objects.hpp"
#include "eyesim/sim/collision/eye_sphere.hpp"
#include "eyesim/sim/collision/instrument.hpp"
#include "eyesim/sim/collision/zcoll.hpp"
#include "eyesim/sim/mesh.hpp"
#include "eyesim/sim/scenes/scene.hpp"
#include "eyesim/sim/tissue/tissue.hpp"

#include <Eigen/Geometry>

#include <array>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace eyesim::frame {

/// Poses of the two tracked handpieces for one frame, eye frame, in the collision convention (instrument
/// frame: tip at the origin, +z forward into the eye).
struct FramePoses {
    double time_s = 0.0;                       ///< frame instant (scene time, from the first frame)
    bool tissue_valid = false;                 ///< the working-hand instrument was measured
    Eigen::Isometry3f tissue_to_eye = Eigen::Isometry3f::Identity();
    bool light_valid = false;                  ///< the light pipe was measured
    Eigen::Isometry3f light_to_eye = Eigen::Isometry3f::Identity();
    float pedal = 0.0f;                        ///< main pedal axis 0..1 (jaws, suction, injection pressure)
    double tracking_us = 0.0;                  ///< time spent by the tracking stage for this frame
};

/// Kinds of simulator events.
enum class EventKind : uint8_t {
    kEyeContact,      ///< case 2: an instrument tip came within the warning distance of the eyeball wall
    kObjectContact,   ///< case 3: an instrument touched a rigid training object
    kTissueContact,   ///< case 4: an instrument started touching the tissue
    kGrab,            ///< forceps closed on tissue nodes
    kLiftOff,         ///< membrane rim force over the limit: retina lift-off warning
    kTear,            ///< injection needle moved too fast along the retina: tear warning
    kSpringTorn,      ///< tearing rule deleted springs
    kTissueRemoved,   ///< vitrector cut tissue
    kNotPiConvex,     ///< ZCOLL saw several membrane layers in V: exact fallback used
};

/// Name of an event kind (snake_case, as in JSON output).
const char* to_string(EventKind k);

/// One event, with the frame time it happened at.
struct Event {
    double time_s;     ///< scene time
    EventKind kind;    ///< what
    float value;       ///< kind-dependent: distance mm, force nN, speed mm/s, springs, area mm², nodes
};

/// Scores a trainer wants after a run.
struct Scores {
    double task_time_s = 0.0;              ///< first to last frame
    uint64_t frames = 0;                   ///< frames simulated
    uint64_t springs_torn = 0;             ///< tissue damage by tearing
    double torn_area_mm2 = 0.0;
    double removed_area_mm2 = 0.0;         ///< tissue removed by the vitrector
    uint64_t nodes_detached = 0;           ///< retina nodes detached by injections
    uint64_t eye_contacts = 0;             ///< case-2 warnings (rising edges)
    uint64_t object_contacts = 0;          ///< case-3 contacts (rising edges)
    uint64_t lift_off_warnings = 0;        ///< frames with a lift-off warning
    uint64_t tear_warnings = 0;            ///< frames with a tear warning
    uint64_t tissue_contact_frames = 0;    ///< frames with case-4 contact
    uint64_t grabs = 0;                    ///< forceps grasps: jaws closing on tissue (rising edges)
    double membrane_area_mm2 = 0.0;        ///< epiretinal membrane: its area on the retina at the start
    double peeled_area_mm2 = 0.0;          ///< … of which lifted off the retina (every node > lift threshold)
    uint64_t not_pi_convex_frames = 0;     ///< frames that needed the exact fallback
    double path_length_mm = 0.0;           ///< working-hand tip path
    uint64_t events_dropped = 0;           ///< events beyond the list's capacity (counted, not stored)
};

/// The scene's pass rules applied to a run's scores.
struct Verdict {
    bool checked = false;              ///< the scene has pass rules
    bool passed = false;               ///< every rule held
    std::vector<std::string> failed;   ///< one line per rule that did not hold, e.g. "lift-off warnings 3 > 0"
};

/// Peeled share of the membrane, % (0 without an epiretinal membrane).
inline double peeled_percent(const Scores& s) {
    return s.membrane_area_mm2 > 0 ? 100.0 * s.peeled_area_mm2 / s.membrane_area_mm2 : 0.0;
}

/// Applies `rules` to `scores`.
Verdict judge(const sim::scenes::ScoringSpec& rules, const Scores& scores);

/// Which parts of the frame loop a scene made run (for "skip what a scene does not need" checks). Push-mode
/// tissue contact (deformation vectors, grab) runs the exact contact query (`exact_push`); `zcoll_push` counts
/// ZCOLL push queries, which the frame loop no longer makes.
struct StageUse {
    uint64_t eye_sphere = 0, convex = 0, exact_push = 0, zcoll_push = 0, zcoll_boolean = 0, zcoll_suction = 0,
             zcoll_gated = 0, tissue_steps = 0;
};

/// The simulator for one scene.
class Simulator {
public:
    /// Builds instruments, collision engines and tissue as the scene declares. Throws std::runtime_error on an
    /// impossible scene.
    explicit Simulator(const sim::scenes::Scene& scene, size_t event_capacity = 8192);
    ~Simulator();
    Simulator(const Simulator&) = delete;
    Simulator& operator=(const Simulator&) = delete;

    /// Advances one tracking frame. `dt_s` is the time since the previous frame (0 on the first).
    void step(const FramePoses& poses);

    /// The scene.
    const sim::scenes::Scene& scene() const { return scene_; }
    /// Events so far (time ordered).
    const std::vector<Event>& events() const { return events_; }
    /// Scores so far.
    const Scores& scores() const { return scores_; }
    /// Per-stage times of every frame.
    const StageTimer& timer() const { return timer_; }
    /// Fault injection for the latency harness's own test: busy-waits this long inside every collision stage.
    void inject_collision_delay_us(double us) { inject_collision_us_ = us; }
    /// Fault injection for the latency harness: runs `work` (real computation, which slows down with the machine
    /// as code does) inside every collision stage; empty: none.
    void inject_collision_work(std::function<void()> work) { inject_collision_work_ = std::move(work); }
    /// Adds rendering time (a picture of frame `frame`'s state) to that frame's row.
    void record_render_us(size_t frame, double us) { timer_.add_to_row(frame, Stage::kRender, us); }
    /// How often each part ran.
    const StageUse& use() const { return use_; }
    /// The tissue mesh as last written (empty when the scene has no tissue).
    const sim::TriangleMesh& tissue_mesh() const { return mesh_; }
    /// The posed instruments (working hand, light pipe); null when absent in the scene.
    const sim::collision::PosedInstrument* tissue_instrument() const;
    const sim::collision::PosedInstrument* light_instrument() const;
    /// The tissue (null when the scene has none).
    const sim::tissue::Tissue* tissue() const { return tissue_.get(); }
    /// Nodes currently grabbed by the forceps (for pictures).
    const std::vector<uint32_t>& grabbed_nodes() const { return grabbed_nodes_; }
    /// A stable hash of the tissue positions and scores (determinism tests).
    uint64_t state_hash() const;

private:
    struct Tool;
    void place_tissue(const FramePoses& poses);
    void add_event(double t, EventKind k, float v);
    Tool* active_tool(sim::scenes::InstrumentRole role, double t_s);

    sim::scenes::Scene scene_;
    std::vector<std::unique_ptr<Tool>> tools_;
    sim::TriangleMesh mesh_;              // tissue geometry for collision and rendering (eye frame)
    std::unique_ptr<sim::tissue::Tissue> tissue_;
    std::unique_ptr<sim::collision::ZcollEngine> zcoll_;     // boolean and suction modes
    std::unique_ptr<sim::collision::ExactContact> contact_;  // push mode: exact set + deformation values
    std::unique_ptr<sim::collision::ConvexObjectSet> convex_;
    std::vector<sim::tissue::NodePush> pushes_;
    std::vector<uint32_t> grabbed_nodes_;
    std::vector<Event> events_;
    size_t event_capacity_;
    Scores scores_;
    StageUse use_;
    StageTimer timer_;
    bool placed_ = false;
    double inject_collision_us_ = 0.0;
    std::function<void()> inject_collision_work_;
    bool have_prev_ = false;
    double prev_time_s_ = 0.0, first_time_s_ = 0.0;
    Eigen::Vector3f prev_tip_mm_ = Eigen::Vector3f::Zero();
    static constexpr size_t kNeedleWindow = 3;  // frames the needle's velocity is measured over
    std::array<Eigen::Vector3f, kNeedleWindow> needle_tip_mm_{};
    std::array<double, kNeedleWindow> needle_t_s_{};
    size_t needle_count_ = 0;
    bool holding_ = false;                  // forceps held tissue after the last frame
    // Epiretinal membrane: rest distance of each node from the eye centre, peeled latch, rest triangles.
    std::vector<float> rest_radius_mm_;
    std::vector<uint8_t> peeled_;
    std::vector<std::array<uint32_t, 3>> rest_triangles_;
    std::vector<float> rest_area_mm2_;
    bool tissue_contact_ = false;
    std::vector<uint8_t> object_contact_;
};

}  // namespace eyesim::frame
