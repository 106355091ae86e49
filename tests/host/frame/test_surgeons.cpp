// The synthetic surgeons against the scenes' tissue: where the tissue lies (checked against the rig's own
// description of it), what each procedure does to it (truth poses, many seeds), and that the motions stay
// physically possible.
#include "eyesim/frame/pose_source.hpp"
#include "eyesim/frame/simulator.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/scenario.hpp"
#include "eyesim/rig/surgeon.hpp"
#include "eyesim/sim/mesh.hpp"
#include "eyesim/sim/scenes/scene.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <memory>

using namespace eyesim;
using frame::Simulator;

namespace {
std::string scene_path(const char* name) { return std::string(EYESIM_SOURCE_DIR) + "/scenes/" + name + ".json"; }

std::unique_ptr<Simulator> run(const char* scene, const char* scenario, uint64_t seed) {
    auto sc = sim::scenes::load_scene(scene_path(scene));
    auto s = std::make_unique<Simulator>(sc);
    const auto bodies = rig::load_bodies(rig::default_bodies_path());
    const auto motion = rig::Scenario::make(scenario, seed, sc.duration_s * 1e6, bodies);
    for (int k = 0; k < int(std::lround(sc.duration_s * 50)); ++k)
        s->step(frame::poses_from_truth(motion.state_at(k * 20000.0)));
    return s;
}
}  // namespace

TEST_CASE("the shipped scenes place their tissue where the rig's surgeons work", "[sim][surgeon]") {
    const auto peel = sim::scenes::load_scene(scene_path("membrane-peel"));
    CHECK(peel.scenario == "peel");
    CHECK(peel.tissue.shape == sim::scenes::MembraneShape::kEpiretinal);
    CHECK((peel.tissue.center_eye_mm.cast<double>().normalized() - rig::surgeon::kMembraneCentreDir).norm() < 1e-6);
    CHECK(peel.tissue.width_mm == Approx(2.0 * rig::surgeon::kMembraneRadius_mm));
    CHECK(peel.tissue.outline_irregularity == Approx(rig::surgeon::kMembraneIrregularity));
    CHECK(peel.tissue.outline_seed == int(rig::surgeon::kMembraneOutlineSeed));
    // The rig's copy of the outline is the host's.
    for (uint32_t seed : {1u, 2u, 77u})
        for (int k = 0; k < 64; ++k) {
            const float th = float(k) * 0.1f - 3.2f;
            sim::MembraneOutline o;
            o.mean_radius_mm = 2.5f;
            o.irregularity = 0.25f;
            o.seed = seed;
            CHECK(o.radius_at(th) == Approx(rig::surgeon::membrane_outline_radius_mm(th, 2.5, 0.25, seed)).epsilon(1e-5));
        }
    const auto vit = sim::scenes::load_scene(scene_path("vitrectomy"));
    CHECK(vit.scenario == "vitrectomy");
    CHECK(vit.tissue.shape == sim::scenes::MembraneShape::kFlat);
    CHECK((vit.tissue.center_eye_mm.cast<double>() - rig::surgeon::kSheetCentre_mm).norm() < 1e-5);
    CHECK((vit.tissue.normal_eye.cast<double>() - rig::surgeon::kSheetNormal).norm() < 1e-5);
    CHECK(vit.tissue.width_mm == Approx(rig::surgeon::kSheetSize_mm));
}

TEST_CASE("the epiretinal membrane lies on the retina with an irregular outline and its rim attached", "[sim][surgeon]") {
    Simulator s(sim::scenes::load_scene(scene_path("membrane-peel")));
    s.step(frame::FramePoses{});  // places the tissue
    const auto& m = s.tissue_mesh();
    REQUIRE(m.triangle_count() > 800);
    REQUIRE(m.triangle_count() < 1300);
    double r_min = 1e9, r_max = 0;
    for (const auto& v : m.vertices_mm) {
        CHECK(v.norm() == Approx(11.45f).margin(1e-4));  // on the retina (11.5 mm), 50 µm inside it
        CHECK(v.z() < -10.9f);                              // around the posterior pole
        const double rho = 11.45 * std::acos(std::clamp(-double(v.z()) / v.norm(), -1.0, 1.0));
        r_min = std::min(r_min, rho);
        r_max = std::max(r_max, rho);
    }
    CHECK(r_max > 2.5 * 1.1);  // lobes beyond the mean radius: not a circle, not a square
    // Rim: every boundary node is fixed; the rim's nodes span radii from the lobes' troughs to their tips.
    const auto& sys = s.tissue()->system();
    double rim_lo = 1e9, rim_hi = 0;
    size_t fixed = 0;
    for (size_t v = 0; v < sys.node_count(); ++v)
        if (sys.state[v] == sim::tissue::NodeState::kFixed) {
            ++fixed;
            const Eigen::Vector3f x = sys.x_mm[v];
            const double rho = 11.45 * std::acos(std::clamp(-double(x.z()) / x.norm(), -1.0, 1.0));
            rim_lo = std::min(rim_lo, rho);
            rim_hi = std::max(rim_hi, rho);
        }
    CHECK(fixed > 40);
    CHECK(rim_lo < 2.5 * 0.9);
    CHECK(rim_hi > 2.5 * 1.1);
    CHECK(s.scores().membrane_area_mm2 > 14.0);  // about π·2.5² (1 + irr²/2) on the sphere
    CHECK(s.scores().membrane_area_mm2 < 24.0);
}

TEST_CASE("peel: the forceps grasps, peels the membrane and tears springs without lifting the retina", "[sim][surgeon]") {
    // Seeds beyond those the surgeon's constants were chosen on (1–10).
    for (uint64_t seed : {11u, 23u, 37u, 52u, 64u}) {
        INFO("seed " << seed);
        const auto s = run("membrane-peel", "peel", seed);
        const auto& sc = s->scores();
        CHECK(sc.grabs >= 2);  // grasp, release, regrasp
        CHECK(sc.peeled_area_mm2 > 0.05 * sc.membrane_area_mm2);
        CHECK(sc.springs_torn > 0);
        CHECK(sc.lift_off_warnings == 0);
        CHECK(sc.eye_contacts == 0);
        CHECK(frame::judge(s->scene().scoring, sc).passed);
    }
}

TEST_CASE("peel-hard: pulled too hard at the attached edge, the lift-off warning fires and the task fails", "[sim][surgeon]") {
    for (uint64_t seed : {11u, 23u, 37u, 52u, 64u}) {
        INFO("seed " << seed);
        const auto s = run("membrane-peel", "peel-hard", seed);
        CHECK(s->scores().grabs >= 1);
        CHECK(s->scores().lift_off_warnings > 0);
        const auto v = frame::judge(s->scene().scoring, s->scores());
        CHECK_FALSE(v.passed);
        REQUIRE(!v.failed.empty());
        CHECK(v.failed[0].rfind("lift-off warnings", 0) == 0);
    }
}

TEST_CASE("vitrectomy: suction and cutting remove the vitreous membrane", "[sim][surgeon]") {
    for (uint64_t seed : {11u, 23u, 37u}) {
        INFO("seed " << seed);
        const auto s = run("vitrectomy", "vitrectomy", seed);
        CHECK(s->scores().removed_area_mm2 > 1.0);
        CHECK(s->use().zcoll_suction > 0);
        CHECK(s->scores().eye_contacts == 0);
    }
}

TEST_CASE("the surgeons' instruments go through their trocars, stay in the eye and off the retina", "[rig][surgeon]") {
    const auto bodies = rig::load_bodies(rig::default_bodies_path());
    for (const char* name : {"peel", "peel-hard", "vitrectomy", "injection"})
        for (uint64_t seed : {1u, 11u, 23u}) {
            INFO(name << " seed " << seed);
            const auto sc = rig::Scenario::make(name, seed, 8e6, bodies);
            double pedal_lo = 1, pedal_hi = 0;
            for (int k = 0; k <= 400; ++k) {
                const auto st = sc.state_at(k * 20000.0);
                pedal_lo = std::min(pedal_lo, st.pedal.axes[0]);
                pedal_hi = std::max(pedal_hi, st.pedal.axes[0]);
                for (const auto& in : st.instruments) {
                    const Eigen::Vector3d troc = bodies.eye.trocars.at(size_t(in.trocar)).position_eye_mm;
                    // The shaft passes through the trocar: tip + insertion·axis is the trocar.
                    CHECK((in.tip_eye_mm + in.insertion_mm * in.axis_eye - troc).norm() < 1e-6);
                    // Only the injection needle enters the retina, by at most 0.15 mm (subretinal injection).
                    const bool needle = in.kind == rig::InstrumentKind::kInjection;
                    CHECK(in.tip_eye_mm.norm() < rig::surgeon::kRetinaRadius_mm + (needle ? 0.15 : -0.05));
                    CHECK(in.insertion_mm <= bodies.instrument(in.kind).max_insertion_mm + 1e-9);
                }
            }
            CHECK(pedal_lo < 0.05);  // the pedal is released and pressed
            CHECK(pedal_hi >= 0.75);
        }
}
