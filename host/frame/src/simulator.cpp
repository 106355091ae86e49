#include "eyesim/frame/simulator.hpp"

#include "eyesim/sim/collision/view.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

namespace eyesim::frame {

namespace col = sim::collision;
namespace tis = sim::tissue;
using sim::scenes::InstrumentRole;
using sim::scenes::TissueKind;
using sim::scenes::ZcollMode;

namespace {
constexpr float kRetinaRadius_mm = sim::kEyeRadius_mm - 0.5f;  // inner wall: where the retina lies
constexpr float kMembraneSurface_mm = kRetinaRadius_mm - 0.05f; // an epiretinal membrane's nodes, on the retina
constexpr float kForcepsMaxOpening_deg = 30.0f;                // pedal released: jaws fully open
constexpr float kCutterRadius_mm = 0.15f;                      // vitrector cutter reach around its port
constexpr float kSuctionRange_mm = 1.5f;
constexpr float kGrabRadius_mm = 0.3f;
constexpr double kMaxFrameDt_s = 0.04;                         // a gap in tracking is not simulated as one step

/// Rotation whose +z column is `n` (unit), with a deterministic x axis.
Eigen::Matrix3f frame_with_z(const Eigen::Vector3f& n) {
    const Eigen::Vector3f z = n.normalized();
    const Eigen::Vector3f a = std::fabs(z.x()) < 0.9f ? Eigen::Vector3f::UnitX() : Eigen::Vector3f::UnitY();
    const Eigen::Vector3f x = (a - a.dot(z) * z).normalized();
    Eigen::Matrix3f r;
    r.col(0) = x;
    r.col(1) = z.cross(x);
    r.col(2) = z;
    return r;
}

sim::PatchSize patch_for(int triangles) {
    if (triangles <= 600) return sim::kPatch400;
    if (triangles <= 2000) return sim::kPatch1k;
    if (triangles <= 4000) return sim::kPatch3k;
    const int n = int(std::lround(std::sqrt(double(triangles) / 2.0)));
    return {n, n};
}

}  // namespace

const char* to_string(EventKind k) {
    switch (k) {
        case EventKind::kEyeContact: return "eye_contact";
        case EventKind::kObjectContact: return "object_contact";
        case EventKind::kTissueContact: return "tissue_contact";
        case EventKind::kGrab: return "grab";
        case EventKind::kLiftOff: return "retina_lift_off";
        case EventKind::kTear: return "tear_warning";
        case EventKind::kSpringTorn: return "springs_torn";
        case EventKind::kTissueRemoved: return "tissue_removed";
        case EventKind::kNotPiConvex: return "not_pi_convex";
    }
    return "?";
}

/// One scene instrument with its shape, pose buffer and case-2 monitor.
struct Simulator::Tool {
    sim::scenes::InstrumentSpec spec;
    col::PosedInstrument posed;
    col::EyeSphereMonitor eye_monitor;
    bool valid = false;
    Tool(const sim::scenes::InstrumentSpec& s, float warn_mm)
        : spec(s), posed(col::make_instrument(s.kind)),
          eye_monitor(col::EyeSphereConfig{kRetinaRadius_mm, warn_mm, warn_mm + 0.1f}) {}
};

Simulator::Simulator(const sim::scenes::Scene& scene, size_t event_capacity)
    : scene_(scene), event_capacity_(event_capacity) {
    for (const auto& spec : scene_.instruments)
        tools_.push_back(std::make_unique<Tool>(spec, scene_.collision.eye_warn_distance_mm));
    if (!scene_.collision.convex_objects.empty()) {
        convex_ = std::make_unique<col::ConvexObjectSet>();
        for (const auto& o : scene_.collision.convex_objects) convex_->add(o);
        object_contact_.assign(scene_.collision.convex_objects.size() * tools_.size(), 0);
    }
    events_.reserve(event_capacity_);
    pushes_.reserve(4096);
    grabbed_nodes_.reserve(4096);
}

Simulator::~Simulator() = default;

const col::PosedInstrument* Simulator::tissue_instrument() const {
    for (const auto& t : tools_)
        if (t->spec.role == InstrumentRole::kTissue && t->valid) return &t->posed;
    return nullptr;
}

const col::PosedInstrument* Simulator::light_instrument() const {
    for (const auto& t : tools_)
        if (t->spec.role == InstrumentRole::kLight && t->valid) return &t->posed;
    return nullptr;
}

Simulator::Tool* Simulator::active_tool(InstrumentRole role, double t_s) {
    const auto* spec = scene_.instrument(role, float(t_s));
    for (size_t i = 0; spec && i < tools_.size(); ++i)
        if (&scene_.instruments[i] == spec) return tools_[i].get();
    return nullptr;
}

void Simulator::add_event(double t, EventKind k, float v) {
    if (events_.size() < event_capacity_) events_.push_back({t, k, v});
    else ++scores_.events_dropped;
}

void Simulator::place_tissue(const FramePoses& poses) {
    const auto& ts = scene_.tissue;
    if (ts.kind == TissueKind::kMembrane && ts.shape == sim::scenes::MembraneShape::kEpiretinal) {
        // On the retina (a thin membrane: its nodes just inside the retina's surface), rim attached.
        sim::MembraneOutline outline;
        outline.mean_radius_mm = 0.5f * ts.width_mm;
        outline.irregularity = ts.outline_irregularity;
        outline.seed = uint32_t(ts.outline_seed);
        mesh_ = sim::make_epiretinal_membrane(kMembraneSurface_mm, ts.center_eye_mm, outline, ts.triangles);
        rest_radius_mm_.resize(mesh_.vertex_count());
        for (size_t v = 0; v < mesh_.vertex_count(); ++v) rest_radius_mm_[v] = mesh_.vertices_mm[v].norm();
        peeled_.assign(mesh_.vertex_count(), 0);
        rest_triangles_ = mesh_.triangles;
        rest_area_mm2_.resize(rest_triangles_.size());
        double total = 0.0;
        for (size_t k = 0; k < rest_triangles_.size(); ++k) {
            const auto& t = rest_triangles_[k];
            rest_area_mm2_[k] = 0.5f * (mesh_.vertices_mm[t[1]] - mesh_.vertices_mm[t[0]])
                                           .cross(mesh_.vertices_mm[t[2]] - mesh_.vertices_mm[t[0]])
                                           .norm();
            total += rest_area_mm2_[k];
        }
        scores_.membrane_area_mm2 = total;
    } else if (ts.kind == TissueKind::kMembrane) {
        const sim::PatchSize p = patch_for(ts.triangles);
        mesh_ = sim::make_membrane_patch(ts.width_mm, ts.width_mm, p.nx, p.ny);
        Eigen::Matrix3f rot = frame_with_z(ts.normal_eye);
        Eigen::Vector3f centre = ts.center_eye_mm;
        if (ts.anchor_ahead_of_tip_mm) {
            Eigen::Vector3f from = poses.tissue_to_eye.translation();
            Eigen::Vector3f fwd = poses.tissue_to_eye.linear().col(2);
            const Tool* hand = active_tool(InstrumentRole::kTissue, 0.0);
            if (ts.anchor_to_port && hand) {
                from = poses.tissue_to_eye * hand->posed.instrument().port_local_mm;
                fwd = poses.tissue_to_eye.linear() * hand->posed.instrument().port_dir_local;
            }
            centre = from + *ts.anchor_ahead_of_tip_mm * fwd;
            rot = frame_with_z(-fwd);  // the membrane faces the instrument
        }
        for (auto& v : mesh_.vertices_mm) v = rot * v + centre;
    } else {
        mesh_ = sim::make_retina_hemisphere(kRetinaRadius_mm, ts.retina_rings, ts.retina_segments);
    }
    tis::TissueParams rules = ts.rules;
    rules.container_centre_mm = Eigen::Vector3f::Zero();
    rules.container_radius_mm = kRetinaRadius_mm;
    tissue_ = std::make_unique<tis::Tissue>(mesh_, ts.material, rules, ts.integrator);
    if (ts.kind == TissueKind::kMembrane) tissue_->fix_rim();
    else tissue_->attach_all();
    tissue_->write_to(mesh_);

    col::ZcollConfig zc;
    zc.resolution_px = scene_.collision.zcoll_resolution_px;
    zc.grab_radius_mm = kGrabRadius_mm;
    zcoll_ = std::make_unique<col::ZcollEngine>(mesh_, zc);
    contact_ = std::make_unique<col::ExactContact>(mesh_);
    pushes_.reserve(mesh_.vertex_count());
    grabbed_nodes_.reserve(mesh_.vertex_count());
    placed_ = true;
}

void Simulator::step(const FramePoses& poses) {
    if (!have_prev_) first_time_s_ = poses.time_s;
    const double t = poses.time_s - first_time_s_;
    const double dt = have_prev_ ? std::clamp(poses.time_s - prev_time_s_, 0.0, kMaxFrameDt_s) : 0.02;

    timer_.begin_frame();
    timer_.add(Stage::kTracking, poses.tracking_us);

    Tool* hand = active_tool(InstrumentRole::kTissue, t);
    Tool* light = active_tool(InstrumentRole::kLight, t);
    for (auto& tool : tools_) tool->valid = false;

    // Pose the instruments (misc: bookkeeping).
    {
        ScopedStage s(timer_, Stage::kMisc);
        if (hand && poses.tissue_valid) {
            const float opening = hand->spec.kind == col::InstrumentKind::Forceps
                                      ? kForcepsMaxOpening_deg * (1.0f - std::clamp(poses.pedal, 0.0f, 1.0f))
                                      : 0.0f;
            hand->posed.set_state(opening, poses.tissue_to_eye);
            hand->valid = true;
        }
        if (light && poses.light_valid) {
            light->posed.set_state(0.0f, poses.light_to_eye);
            light->valid = true;
        }
        if (scene_.needs_tissue() && !placed_ && (!scene_.tissue.anchor_ahead_of_tip_mm || (hand && hand->valid)))
            place_tissue(poses);
    }

    // Collision: only the cases the scene declares.
    bool tissue_contact = false, suction_on = false;
    pushes_.clear();
    grabbed_nodes_.clear();
    {
        ScopedStage s(timer_, Stage::kCollision);
        if (inject_collision_work_) inject_collision_work_();
        if (inject_collision_us_ > 0.0) {
            const auto end = StageTimer::Clock::now() + std::chrono::nanoseconds(int64_t(inject_collision_us_ * 1e3));
            while (StageTimer::Clock::now() < end) {
            }
        }
        for (size_t ti = 0; ti < tools_.size(); ++ti) {
            Tool& tool = *tools_[ti];
            if (!tool.valid) continue;
            if (scene_.collision.eye_sphere) {
                ++use_.eye_sphere;
                const auto c = tool.eye_monitor.update(tool.posed.tip_eye_mm());
                if (c.warning_started) {
                    ++scores_.eye_contacts;
                    add_event(t, EventKind::kEyeContact, c.distance_mm);
                }
            }
            if (convex_) {
                ++use_.convex;
                const auto contacts =
                    convex_->query(tool.posed.instrument_to_eye(), tool.posed.instrument().shaft_radius_mm, 10.0f);
                for (size_t k = 0; k < contacts.size(); ++k) {
                    const bool touching = contacts[k].distance_mm <= 0.0f;
                    uint8_t& was = object_contact_[ti * contacts.size() + k];
                    if (touching && !was) {
                        ++scores_.object_contacts;
                        add_event(t, EventKind::kObjectContact, -contacts[k].distance_mm);
                    }
                    was = touching;
                }
            }
        }
        if (placed_ && hand && hand->valid && hand->spec.zcoll != ZcollMode::kOff) {
            const auto& cs = scene_.collision;
            const auto verts = std::span<const sim::Vec3f>(mesh_.vertices_mm);
            switch (hand->spec.zcoll) {
                case ZcollMode::kPush: {
                    // Deformation wanted: the exact colliding set inside ZCOLL's V, ZI − ZM along its π per colliding
                    // triangle, Eq. 1 node pushes; the grab rule when the forceps jaws are closed.
                    ++use_.exact_push;
                    const auto view = col::make_tip_view(poses.tissue_to_eye, cs.zcoll_half_width_mm, cs.zcoll_ahead_mm,
                                                         cs.zcoll_behind_mm, cs.zcoll_resolution_px);
                    const col::OrientedBox volume = col::view_volume(view);
                    col::ContactOptions opt;
                    opt.within = &volume;
                    opt.grab = hand->spec.kind == col::InstrumentKind::Forceps &&
                               hand->posed.opening_deg() < zcoll_->config().grab_below_deg;
                    opt.grab_tip_eye_mm = hand->posed.tip_eye_mm();
                    opt.grab_radius_mm = zcoll_->config().grab_radius_mm;
                    if (!zcoll_->volume_touches(verts, view)) {
                        ++use_.zcoll_gated;  // V misses the membrane's bounds: nothing to test
                        break;
                    }
                    const col::ContactResult& r = contact_->query(verts, hand->posed, view.direction_eye(), opt);
                    tissue_contact = r.colliding || r.grabbed;
                    for (size_t k = 0; k < r.pushed_nodes.size(); ++k)
                        pushes_.push_back({r.pushed_nodes[k], r.node_push_eye_mm[k]});
                    grabbed_nodes_.assign(r.grabbed_nodes.begin(), r.grabbed_nodes.end());
                    break;
                }
                case ZcollMode::kBoolean: {
                    ++use_.zcoll_boolean;
                    const auto view = col::make_tip_view(poses.tissue_to_eye, cs.zcoll_half_width_mm, cs.zcoll_ahead_mm,
                                                         cs.zcoll_behind_mm, cs.zcoll_resolution_px);
                    tissue_contact = zcoll_->collides(verts, hand->posed, view);
                    break;
                }
                case ZcollMode::kSuction: {
                    if (poses.pedal < hand->spec.pedal_threshold) break;
                    ++use_.zcoll_suction;
                    const auto view = col::make_suction_view(poses.tissue_to_eye, hand->posed.instrument(),
                                                             cs.suction_half_angle_deg, cs.suction_length_mm,
                                                             cs.zcoll_resolution_px);
                    const sim::Vec3f port = poses.tissue_to_eye * hand->posed.instrument().port_local_mm;
                    const col::ZcollResult& r = zcoll_->suction(verts, view, port);
                    if (r.gated_out) ++use_.zcoll_gated;
                    suction_on = !r.suction_nodes.empty();
                    tissue_contact = suction_on;
                    break;
                }
                case ZcollMode::kOff: break;
            }
        }
        if (tissue_contact) ++scores_.tissue_contact_frames;
        if (tissue_contact && !tissue_contact_) add_event(t, EventKind::kTissueContact, 0.0f);
        tissue_contact_ = tissue_contact;
    }

    // Tissue: tool inputs, substeps, events.
    if (placed_) {
        ScopedStage s(timer_, Stage::kTissue);
        ++use_.tissue_steps;
        tis::ForcepsInput forceps;
        tis::SuctionInput suction;
        tis::CutterInput cutter;
        tis::NeedleInput needle;
        if (hand && hand->valid) {
            const sim::Vec3f tip = hand->posed.tip_eye_mm();
            const auto kind = hand->spec.kind;
            if (kind == col::InstrumentKind::Forceps) {
                forceps.tip_mm = tip;
                forceps.closed = hand->posed.opening_deg() < zcoll_->config().grab_below_deg;
                forceps.grab_radius_mm = kGrabRadius_mm;
            }
            if (kind == col::InstrumentKind::Vitrector) {
                const auto& inst = hand->posed.instrument();
                const sim::Vec3f port = poses.tissue_to_eye * inst.port_local_mm;
                const sim::Vec3f dir = poses.tissue_to_eye.linear() * inst.port_dir_local;
                if (suction_on) {
                    suction.on = true;
                    suction.apex_mm = port;
                    suction.axis = dir;
                    suction.half_angle_deg = scene_.collision.suction_half_angle_deg;
                    suction.range_mm = kSuctionRange_mm;
                    suction.strength_nN_mm = 50.0f * poses.pedal;
                }
                if (hand->spec.cuts && poses.pedal >= hand->spec.pedal_threshold) {
                    cutter.on = true;
                    cutter.centre_mm = port;
                    cutter.radius_mm = kCutterRadius_mm;
                }
            }
            if (kind == col::InstrumentKind::InjectionNeedle) {
                needle.tip_mm = tip;
                needle.inserted = tip.norm() >= kRetinaRadius_mm - 0.05f;
                // Velocity over the last kNeedleWindow frames (≈ 60 ms): tracking noise of tens of µm per frame
                // must not read as a fast move along the retina; a real flick lasts longer than the window.
                const size_t head = needle_count_ % kNeedleWindow;
                const size_t oldest = needle_count_ >= kNeedleWindow ? head : 0;
                const double span_s = t - needle_t_s_[oldest];
                needle.velocity_mm_per_s = needle_count_ > 0 && span_s > 0
                                               ? sim::Vec3f((tip - needle_tip_mm_[oldest]) / float(span_s))
                                               : sim::Vec3f::Zero();
                needle.pressure = poses.pedal;
                needle_tip_mm_[head] = tip;
                needle_t_s_[head] = t;
                ++needle_count_;
            }
        }
        tissue_->set_forceps(forceps);
        tissue_->set_suction(suction);
        tissue_->set_cutter(cutter);
        tissue_->set_needle(needle);
        tissue_->push(pushes_);
        tissue_->step(float(dt), scene_.tissue.substeps);
        const auto& ev = tissue_->events();
        uint32_t torn = 0;
        for (size_t i = 0; i < ev.size(); ++i) {
            switch (ev[i].kind) {
                case tis::TissueEventKind::kLiftOff:
                    ++scores_.lift_off_warnings;
                    add_event(t, EventKind::kLiftOff, ev[i].value);
                    break;
                case tis::TissueEventKind::kTearWarning:
                    ++scores_.tear_warnings;
                    add_event(t, EventKind::kTear, ev[i].value);
                    break;
                case tis::TissueEventKind::kSpringTorn: ++torn; break;
                case tis::TissueEventKind::kTissueRemoved: add_event(t, EventKind::kTissueRemoved, ev[i].value); break;
            }
        }
        if (torn) add_event(t, EventKind::kSpringTorn, float(torn));
        // A grasp: the jaws closed on tissue this frame (held nodes, not held before).
        const bool holding = tissue_->grabbed_count() > 0;
        if (holding && !holding_) {
            ++scores_.grabs;
            add_event(t, EventKind::kGrab, float(tissue_->grabbed_count()));
        }
        holding_ = holding;
    }

    // Geometry transfer: positions (and topology after tearing or cutting) back into the collision/render mesh.
    if (placed_) {
        ScopedStage s(timer_, Stage::kTransfer);
        if (tissue_->write_to(mesh_)) {
            // Topology changed: the collision engines keep per-triangle buffers; rebuild them (rare: tearing,
            // cutting; they allocate then).
            col::ZcollConfig zc = zcoll_->config();
            zcoll_ = std::make_unique<col::ZcollEngine>(mesh_, zc);
            contact_->set_membrane(mesh_);  // keeps the instrument's structure
        }
    }

    // Scores.
    {
        ScopedStage s(timer_, Stage::kMisc);
        if (hand && hand->valid) {
            const sim::Vec3f tip = hand->posed.tip_eye_mm();
            if (have_prev_) scores_.path_length_mm += (tip - prev_tip_mm_).norm();
            prev_tip_mm_ = tip;
        }
        if (tissue_ && !peeled_.empty()) {
            // Peeled: every node of a triangle lifted off the retina by the threshold at some time (a separated
            // membrane does not stick again).
            const auto& sys = tissue_->system();
            const float lift = scene_.tissue.lift_threshold_mm;
            bool changed = false;
            for (size_t v = 0; v < peeled_.size(); ++v) {
                if (peeled_[v] || sys.state[v] == tis::NodeState::kRemoved) continue;
                if (sys.x_mm[v].norm() < rest_radius_mm_[v] - lift) peeled_[v] = changed = true;
            }
            if (changed) {
                double area = 0.0;
                for (size_t k = 0; k < rest_triangles_.size(); ++k) {
                    const auto& tri = rest_triangles_[k];
                    if (peeled_[tri[0]] && peeled_[tri[1]] && peeled_[tri[2]]) area += rest_area_mm2_[k];
                }
                scores_.peeled_area_mm2 = area;
            }
        }
        if (tissue_) {
            const auto& d = tissue_->damage();
            scores_.springs_torn = d.springs_torn;
            scores_.torn_area_mm2 = d.torn_area_mm2;
            scores_.removed_area_mm2 = d.removed_area_mm2;
            scores_.nodes_detached = d.nodes_detached;
        }
        ++scores_.frames;
        scores_.task_time_s = t;
    }
    timer_.end_frame();
    prev_time_s_ = poses.time_s;
    have_prev_ = true;
}

Verdict judge(const sim::scenes::ScoringSpec& r, const Scores& s) {
    Verdict v;
    v.checked = r.any();
    auto at_least = [&](const std::optional<double>& lim, double value, const char* what) {
        if (lim && !(value >= *lim)) v.failed.push_back(fmt::format("{} {:.4g} < {:.4g}", what, value, *lim));
    };
    auto at_most = [&](const std::optional<double>& lim, double value, const char* what) {
        if (lim && !(value <= *lim)) v.failed.push_back(fmt::format("{} {:.4g} > {:.4g}", what, value, *lim));
    };
    const double peeled_pct = peeled_percent(s);
    at_least(r.min_grabs, double(s.grabs), "grabs");
    at_least(r.min_peeled_percent, peeled_pct, "peeled %");
    at_least(r.min_removed_mm2, s.removed_area_mm2, "removed mm²");
    at_least(r.min_nodes_detached, double(s.nodes_detached), "retina nodes detached");
    at_most(r.max_lift_off_warnings, double(s.lift_off_warnings), "lift-off warnings");
    at_most(r.max_tear_warnings, double(s.tear_warnings), "tear warnings");
    at_most(r.max_retina_contacts, double(s.eye_contacts), "retina contacts");
    at_most(r.max_object_contacts, double(s.object_contacts), "object contacts");
    at_most(r.max_time_s, s.task_time_s, "time s");
    v.passed = v.checked && v.failed.empty();
    return v;
}

uint64_t Simulator::state_hash() const {
    uint64_t h = 1469598103934665603ull;
    auto mix = [&h](const void* p, size_t n) {
        const auto* b = static_cast<const unsigned char*>(p);
        for (size_t i = 0; i < n; ++i) h = (h ^ b[i]) * 1099511628211ull;
    };
    for (const auto& v : mesh_.vertices_mm) mix(v.data(), sizeof(float) * 3);
    for (const auto& tri : mesh_.triangles) mix(tri.data(), sizeof(uint32_t) * 3);
    const uint64_t counters[] = {scores_.frames, scores_.springs_torn, scores_.eye_contacts, scores_.object_contacts,
                                 scores_.lift_off_warnings, scores_.tear_warnings, scores_.grabs,
                                 scores_.tissue_contact_frames, scores_.nodes_detached};
    mix(counters, sizeof(counters));
    return h;
}

}  // namespace eyesim::frame
