// Scene files: every shipped scene loads; every kind of bad input is a one-line error naming the key.
#include "eyesim/sim/scenes/scene.hpp"

#include <catch2/catch.hpp>

#include <string>

using namespace eyesim::sim::scenes;

namespace {
std::string scene_path(const char* name) { return std::string(EYESIM_SOURCE_DIR) + "/scenes/" + name + ".json"; }

std::string error_of(const std::string& text) {
    try {
        parse_scene(text, "s.json");
    } catch (const SceneError& e) {
        return e.what();
    }
    return "";
}

const char* kMinimal = R"({"name": "x", "instruments": [{"kind": "pick"}]})";
}  // namespace

TEST_CASE("the shipped scenes load and declare what they need", "[scenes]") {
    const Scene peel = load_scene(scene_path("membrane-peel"));
    CHECK(peel.name == "membrane-peel");
    CHECK(peel.needs_tissue());
    CHECK(peel.needs_deformation());
    CHECK(peel.tissue.kind == TissueKind::kMembrane);
    CHECK(peel.instrument(InstrumentRole::kTissue, 0.0f)->kind == eyesim::sim::collision::InstrumentKind::Forceps);
    CHECK(peel.instrument(InstrumentRole::kTissue, 7.0f)->kind == eyesim::sim::collision::InstrumentKind::Forceps);
    CHECK(peel.scenario == "peel");
    CHECK(peel.scoring.any());
    CHECK(peel.instrument(InstrumentRole::kLight, 0.0f)->kind == eyesim::sim::collision::InstrumentKind::LightPipe);

    const Scene shadow = load_scene(scene_path("abstract-shadow"));
    CHECK_FALSE(shadow.needs_tissue());
    CHECK_FALSE(shadow.needs_deformation());
    CHECK(shadow.collision.convex_objects.size() == 3);

    const Scene vit = load_scene(scene_path("vitrectomy"));
    CHECK(vit.instrument(InstrumentRole::kTissue, 0.0f)->zcoll == ZcollMode::kSuction);
    CHECK(vit.instrument(InstrumentRole::kTissue, 0.0f)->cuts);

    const Scene ret = load_scene(scene_path("retina-relocation"));
    CHECK(ret.tissue.kind == TissueKind::kRetina);
    CHECK_FALSE(ret.needs_deformation());  // boolean ZCOLL only: no deformation vectors, no read-back
}

TEST_CASE("a minimal scene gets the documented defaults", "[scenes]") {
    const Scene s = parse_scene(kMinimal, "min.json");
    CHECK(s.instruments.size() == 1);
    CHECK(s.collision.eye_sphere);
    CHECK(s.collision.zcoll_resolution_px == 32);
    CHECK_FALSE(s.needs_tissue());
}

TEST_CASE("bad scene files give one-line errors naming file and key", "[scenes]") {
    CHECK(error_of("{") .find("s.json: not valid JSON") == 0);
    CHECK(error_of("[]").find("s.json: (top level): must be an object") == 0);
    CHECK(error_of(R"({"instruments": [{"kind": "pick"}]})") == "s.json: name: missing");
    CHECK(error_of(R"({"name": "x"})") == "s.json: instruments: missing");
    CHECK(error_of(R"({"name": "x", "instruments": []})") == "s.json: instruments: at least one instrument is needed");
    CHECK(error_of(R"({"name": "x", "instrumnts": [], "instruments": [{"kind": "pick"}]})") ==
          "s.json: instrumnts: unknown key");
    CHECK(error_of(R"({"name": "x", "instruments": [{"kind": "scalpel"}]})") ==
          "s.json: instruments[0].kind: 'scalpel' is not one of: forceps, vitrector, pick, injection_needle, light_pipe");
    CHECK(error_of(R"({"name": "x", "instruments": [{"kind": "pick", "zcoll": "suction"}]})") ==
          "s.json: instruments[0].zcoll: 'suction' needs a vitrector");
    CHECK(error_of(R"({"name": "x", "instruments": [{"kind": "pick", "zcoll": "push"}]})") ==
          "s.json: instruments: zcoll 'push' needs a tissue");
    CHECK(error_of(R"({"name": "x", "instruments": [{"kind": "pick"}], "collision": {"zcoll_resolution_px": 2}})") ==
          "s.json: collision.zcoll_resolution_px: value 2 out of range [4, 1024]");
    CHECK(error_of(R"({"name": "x", "instruments": [{"kind": "pick"}], "collision": {"zcoll_resolution_px": "32"}})") ==
          "s.json: collision.zcoll_resolution_px: must be an integer");
    CHECK(error_of(R"({"name": "x", "instruments": [{"kind": "pick"}], "tissue": {"kind": "membrane", "integrator": "rk4"}})") ==
          "s.json: tissue.integrator: 'rk4' is not one of: paper-euler, symplectic-euler, implicit-euler, xpbd");
    CHECK(error_of(R"({"name": "x", "instruments": [{"kind": "pick"}], "tissue": {"kind": "membrane", "rules": {"a_max_mm_per_s2": -1}}})") ==
          "s.json: tissue.rules.a_max_mm_per_s2: value -1 out of range [0, 1e+12]");
    CHECK(error_of(R"({"name": "x", "instruments": [{"kind": "pick"}], "tissue": {"kind": "membrane", "center_eye_mm": [0, 1]}})") ==
          "s.json: tissue.center_eye_mm: must be an array of 3 numbers");
    // JSON has no NaN literal: a NaN written into a file is a syntax error, never a silent value.
    CHECK(error_of(R"({"name": "x", "instruments": [{"kind": "pick"}], "collision": {"zcoll_ahead_mm": NaN}})")
              .find("not valid JSON") != std::string::npos);
    CHECK_THROWS_WITH(load_scene("/nonexistent/scene.json"), "/nonexistent/scene.json: cannot open scene file");
}

TEST_CASE("'inf' is accepted where a limit may be switched off", "[scenes]") {
    const Scene s = parse_scene(
        R"({"name": "x", "instruments": [{"kind": "pick"}], "tissue": {"kind": "membrane", "rules": {"p_tear_percent": "inf"}}})",
        "s.json");
    CHECK(std::isinf(s.tissue.rules.p_tear_percent));
}
