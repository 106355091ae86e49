// A recording through the FPGA model, the wire format, the tracker and the simulator, in-process, against truth.
#include "eyesim/frame/session.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/rig/truth.hpp"
#include "eyesim/sim/scenes/scene.hpp"
#include "eyesim/tracking/validation.hpp"

#include <catch2/catch.hpp>

#include <filesystem>

using namespace eyesim;

TEST_CASE("a synthetic recording runs through FPGA model, tracker and simulator with truth-level accuracy",
          "[host][session]") {
    const std::string dir = (std::filesystem::temp_directory_path() / "eyesim_test_session_rec").string();
    std::filesystem::remove_all(dir);
    rig::SynthRequest req;
    req.out_dir = dir;
    req.scenario = "surgery";
    req.seconds = 0.4;
    req.seed = 5;
    rig::write_recording(req);

    rig::Recording rec = rig::Recording::open(dir);
    const auto truth = rig::read_truth(rec.truth_path());
    const auto bodies = rig::load_bodies(rig::default_bodies_path());
    std::vector<tracking::SceneInstrument> inst;
    for (const auto& it : truth[0].instruments) inst.push_back({it.kind, it.trocar});
    auto cfg = frame::tracker_config(rec.cameras(), bodies, inst);
    const tracking::BodySet body_set = cfg.bodies;

    frame::Simulator sim(sim::scenes::load_scene(std::string(EYESIM_SOURCE_DIR) + "/scenes/membrane-peel.json"));
    frame::HostRun run(std::move(cfg), sim);
    std::vector<double> tip_um;
    int measured = 0;
    run.set_hook([&](const tracking::TrackingFrame& f, const frame::FramePoses& p) {
        if (f.reference_field >= truth.size()) return;
        const auto score = tracking::score_frame(f, body_set, truth[f.reference_field]);
        for (double e : score.tip_error_mm)
            if (e >= 0) tip_um.push_back(e * 1e3);
        measured += p.tissue_valid ? 1 : 0;
    });
    frame::run_recording(rec, run);

    CHECK(run.stats().frames >= 15);                       // 20 fields per camera; frames wait for neighbours
    CHECK(sim.timer().frames() == run.stats().frames);     // every tracking frame was simulated
    CHECK(run.stats().parse_errors == 0);
    CHECK(measured >= int(run.stats().frames) - 2);
    REQUIRE(!tip_um.empty());
    auto s = tracking::summarise(tip_um);
    CHECK(s.rms < 200.0);  // µm: the tracker's figure on long runs is ~50 µm; a short run starts cold
    CHECK(sim.tissue() != nullptr);  // the membrane was placed at the first tracked tip
    std::filesystem::remove_all(dir);
}
