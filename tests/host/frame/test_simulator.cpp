// The host frame loop against independent truth: analytic contact geometry, the injection rule, determinism,
// and "skip what a scene does not need".
#include "eyesim/frame/pose_source.hpp"
#include "eyesim/frame/simulator.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/scenario.hpp"
#include "eyesim/sim/scenes/scene.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <memory>

using namespace eyesim;
using frame::FramePoses;
using frame::Simulator;

namespace {
std::string scene_path(const char* name) { return std::string(EYESIM_SOURCE_DIR) + "/scenes/" + name + ".json"; }

/// Runs a scene on the rig scenario's truth poses at 50 frames/s.
void run_on_truth(Simulator& sim, const char* scenario, double seconds, uint64_t seed = 1) {
    const auto bodies = rig::load_bodies(rig::default_bodies_path());
    const auto sc = rig::Scenario::make(scenario, seed, seconds * 1e6, bodies);
    for (int k = 0; k < int(seconds * 50); ++k) sim.step(frame::poses_from_truth(sc.state_at(k * 20000.0)));
}

/// Distance between a point and the segment [a, b].
float point_segment_mm(const Eigen::Vector3f& p, const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
    const Eigen::Vector3f ab = b - a;
    const float t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0f, 1.0f);
    return (a + t * ab - p).norm();
}
}  // namespace

TEST_CASE("a rigid-only scene runs no tissue and no ZCOLL code", "[sim][frame]") {
    Simulator sim(sim::scenes::load_scene(scene_path("abstract-shadow")));
    run_on_truth(sim, "surgery", 2.0);
    CHECK(sim.use().tissue_steps == 0);
    CHECK(sim.use().exact_push + sim.use().zcoll_push + sim.use().zcoll_boolean + sim.use().zcoll_suction == 0);
    CHECK(sim.use().convex > 0);
    CHECK(sim.use().eye_sphere > 0);
    CHECK(sim.tissue() == nullptr);
    CHECK(sim.timer().frames() == 100);
    CHECK(sim.timer().summary(frame::Stage::kTissue).max_us == 0.0);
}

TEST_CASE("case-3 contacts match the analytic capsule–sphere distance", "[sim][frame]") {
    // One sphere on the working hand's path; the instrument is a capsule of the shaft radius from the tip back
    // 10 mm along the shaft. Count rising edges of (distance ≤ 0) independently and compare.
    auto scene = sim::scenes::parse_scene(R"({"name": "one-sphere", "instruments": [{"kind": "pick"}],
        "collision": {"eye_sphere": false, "convex_objects": [
            {"shape": "sphere", "size_mm": [0.6, 0, 0], "center_eye_mm": [2.84, 5.0, -1.35]}]}})", "test");
    Simulator sim(scene);
    const auto bodies = rig::load_bodies(rig::default_bodies_path());
    const auto sc = rig::Scenario::make("surgery", 1, 4e6, bodies);
    const float shaft_r = sim::collision::make_instrument(sim::collision::InstrumentKind::Pick).shaft_radius_mm;
    int expected = 0, near_boundary = 0;
    bool was = false;
    for (int k = 0; k < 200; ++k) {
        const FramePoses p = frame::poses_from_truth(sc.state_at(k * 20000.0));
        sim.step(p);
        const Eigen::Vector3f tip = p.tissue_to_eye.translation();
        const Eigen::Vector3f back = tip - 10.0f * p.tissue_to_eye.linear().col(2);
        const float d = point_segment_mm(Eigen::Vector3f(2.84f, 5.0f, -1.35f), tip, back) - 0.6f - shaft_r;
        if (std::fabs(d) < 0.02f) ++near_boundary;  // the pick's hook makes the capsule model approximate here
        const bool now = d <= 0.0f;
        if (now && !was) ++expected;
        was = now;
    }
    REQUIRE(expected > 0);
    if (near_boundary == 0) CHECK(sim.scores().object_contacts == uint64_t(expected));
    CHECK(sim.scores().object_contacts >= 1);
}

TEST_CASE("membrane peel: the forceps pushes and grabs the membrane, deterministically", "[sim][frame]") {
    const auto scene = sim::scenes::load_scene(scene_path("membrane-peel"));
    Simulator a(scene), b(scene);
    run_on_truth(a, "peel", 8.0);
    run_on_truth(b, "peel", 8.0);
    CHECK(a.state_hash() == b.state_hash());
    REQUIRE(a.events().size() == b.events().size());
    for (size_t i = 0; i < a.events().size(); ++i) {
        CHECK(a.events()[i].kind == b.events()[i].kind);
        CHECK(a.events()[i].time_s == b.events()[i].time_s);
    }
    CHECK(a.use().exact_push > 0);  // deformation and grab from the exact contact query
    CHECK(a.use().zcoll_push == 0);
    CHECK(a.use().zcoll_boolean == 0);
    CHECK(a.use().tissue_steps == 400);
    CHECK(a.scores().tissue_contact_frames > 0);
    CHECK(a.scores().grabs > 0);
    CHECK(a.scores().path_length_mm > 1.0);
    for (const auto& v : a.tissue_mesh().vertices_mm) REQUIRE(v.allFinite());
}

TEST_CASE("membrane peel: pushed nodes move out of the instrument's way, along its forward axis", "[sim][frame]") {
    // While the tip is past the membrane's rest plane, the nearest nodes must be displaced along the forward axis
    // by a good part of the penetration (Eq. 1 pushes against elastic recoil), never backwards. A flat membrane in
    // the vitreous (nothing behind it), anchored ahead of the free-hand `surgery` strokes' first tip.
    auto scene = sim::scenes::load_scene(scene_path("membrane-peel"));
    scene.tissue.shape = sim::scenes::MembraneShape::kFlat;
    scene.tissue.anchor_ahead_of_tip_mm = 0.15f;
    scene.tissue.width_mm = 6.0f;
    Simulator sim(scene);
    const auto bodies = rig::load_bodies(rig::default_bodies_path());
    const auto sc = rig::Scenario::make("surgery", 1, 4e6, bodies);
    float max_penetration = 0, max_push = 0;
    for (int k = 0; k < 150; ++k) {
        const FramePoses p = frame::poses_from_truth(sc.state_at(k * 20000.0));
        sim.step(p);
        const auto& sys = sim.tissue()->system();
        // Rest plane from three fixed rim nodes (they never move).
        const Eigen::Vector3f o = sys.x_mm[0];
        const Eigen::Vector3f n = (sys.x_mm[1] - o).cross(sys.x_mm[23] - o).normalized();  // faces the instrument
        const Eigen::Vector3f tip = p.tissue_to_eye.translation();
        const float penetration = -(tip - o).dot(n);
        if (penetration <= 0.05f) continue;
        max_penetration = std::max(max_penetration, penetration);
        float push = 0;
        for (uint32_t i = 0; i < sys.x_mm.size(); ++i)
            if ((sys.x_mm[i] - tip).norm() < 1.0f) push = std::max(push, -(sys.x_mm[i] - o).dot(n));
        max_push = std::max(max_push, push);
    }
    REQUIRE(max_penetration > 0.1f);
    CHECK(max_push > 0.5f * max_penetration);
    CHECK(max_push < 2.0f * max_penetration + 0.05f);
}

TEST_CASE("boolean ZCOLL is used when the scene needs no deformation vectors", "[sim][frame]") {
    auto scene = sim::scenes::load_scene(scene_path("membrane-peel"));
    for (auto& in : scene.instruments)
        if (in.zcoll == sim::scenes::ZcollMode::kPush) in.zcoll = sim::scenes::ZcollMode::kBoolean;
    Simulator sim(scene);
    run_on_truth(sim, "peel", 8.0);
    CHECK(sim.use().zcoll_push + sim.use().exact_push == 0);
    CHECK(sim.use().zcoll_boolean > 0);
    CHECK(sim.scores().tissue_contact_frames > 0);
}

namespace {
/// Scripted injection: the needle approaches the posterior retina along −z, injects with a pressure ramp, then
/// slides along the retina at `slide_mm_per_s`.
std::unique_ptr<Simulator> run_injection(double slide_mm_per_s, double peak_pressure) {
    auto sim_ptr = std::make_unique<Simulator>(sim::scenes::load_scene(scene_path("retina-relocation")));
    Simulator& sim = *sim_ptr;
    const Eigen::Vector3d axis(0.3, 0.0, 1.0);  // tip → handle
    for (int k = 0; k < 150; ++k) {
        const double t = k * 0.02;
        FramePoses p;
        p.time_s = t;
        const double r = std::min(11.0 + 0.4 * t, 11.55);       // reaches the retina (11.5 mm) after 1.25 s
        const double ang = t > 2.0 ? slide_mm_per_s * (t - 2.0) / 11.55 : 0.0;  // slide along the wall
        const Eigen::Vector3d dir(std::sin(ang), 0.0, -std::cos(ang));
        p.tissue_valid = true;
        p.tissue_to_eye = frame::instrument_pose_eye(r * dir, axis.normalized());
        p.pedal = float(t < 1.3 ? 0.0 : std::min(peak_pressure, (t - 1.3) * 2.0));
        sim.step(p);
    }
    return sim_ptr;
}
}  // namespace

TEST_CASE("retina relocation: injection detaches nodes within d = k·p of the needle", "[sim][frame]") {
    auto sim_ptr = run_injection(0.0, 0.8);
    Simulator& sim = *sim_ptr;
    const auto* tissue = sim.tissue();
    REQUIRE(tissue != nullptr);
    const auto& sys = tissue->system();
    const float d_max = sim.scene().tissue.rules.detach_radius_mm_per_pressure * 0.8f;
    const Eigen::Vector3f x0(0.0f, 0.0f, -11.55f);
    int detached = 0;
    for (size_t i = 0; i < sys.state.size(); ++i) {
        if (sys.state[i] != sim::tissue::NodeState::kDetached) continue;
        ++detached;
        // Rest position (on the hemisphere): within d of x0 (plus one mesh spacing for the rest-vs-now shift).
        CHECK((sys.x_mm[i] - x0).norm() < d_max + 1.5f);
    }
    CHECK(detached > 0);
    CHECK(sim.scores().nodes_detached == uint64_t(detached));
    CHECK(sim.scores().tear_warnings == 0);  // the needle did not move along the retina
}

TEST_CASE("retina relocation: a fast needle along the retina raises the tear warning, a slow one does not",
          "[sim][frame]") {
    CHECK(run_injection(20.0, 0.8)->scores().tear_warnings > 0);
    CHECK(run_injection(1.0, 0.8)->scores().tear_warnings == 0);
}

TEST_CASE("retina relocation on the rig's injection scenario: detaches, then warns of the fast flick", "[sim][frame]") {
    Simulator sim(sim::scenes::load_scene(scene_path("retina-relocation")));
    run_on_truth(sim, "injection", 4.0);
    CHECK(sim.scores().nodes_detached > 0);
    REQUIRE(sim.scores().tear_warnings > 0);
    // The only fast move along the retina is the flick at 3.0–3.1 s.
    for (const auto& e : sim.events())
        if (e.kind == frame::EventKind::kTear) CHECK((e.time_s >= 2.98 && e.time_s <= 3.2));
}

TEST_CASE("every shipped scene runs headless for seconds with deterministic events", "[sim][frame]") {
    for (const char* name : {"abstract-shadow", "membrane-peel", "vitrectomy", "retina-relocation"}) {
        INFO(name);
        const auto scene = sim::scenes::load_scene(scene_path(name));
        Simulator a(scene), b(scene);
        run_on_truth(a, scene.scenario.c_str(), 3.0);
        run_on_truth(b, scene.scenario.c_str(), 3.0);
        CHECK(a.state_hash() == b.state_hash());
        REQUIRE(a.events().size() == b.events().size());
        for (size_t i = 0; i < a.events().size(); ++i) {
            CHECK(a.events()[i].kind == b.events()[i].kind);
            CHECK(a.events()[i].time_s == b.events()[i].time_s);
            CHECK(a.events()[i].value == b.events()[i].value);
        }
        CHECK(a.timer().frames() == 150);
        CHECK(a.use().tissue_steps == (scene.needs_tissue() ? 150u : 0u));
        for (const auto& v : a.tissue_mesh().vertices_mm) REQUIRE(v.allFinite());
    }
}
