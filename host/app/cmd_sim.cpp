// `eyesim sim`: run a scene from a live device, a capture, a recording or a scripted scenario.
#include "eyesim/app/command.hpp"
#include "eyesim/app/run_scene.hpp"
#include "eyesim/rig/scenario.hpp"
#include "eyesim/tracking/async_fusion.hpp"

#include <memory>

namespace {

eyesim::app::Registrar reg{
    "sim", "Run a simulator scene on tracked instruments (device, capture, recording or scenario)", [](CLI::App& sub) {
        auto req = std::make_shared<eyesim::app::SceneRunRequest>();
        sub.add_option("--scene", req->scene_path, "scene file (scenes/*.json)")->required();
        auto* src = sub.add_option_group("source", "where the markers come from (exactly one)");
        src->add_option("--connect", req->source.connect, "live device: tcp://HOST:PORT, usb or usb://VID:PID");
        src->add_option("--capture", req->source.capture, "capture file (or raw protocol stream)");
        src->add_option("--recording", req->source.recording, "recording directory (run through the FPGA model)");
        src->add_option("--scenario", req->source.scenario, "synthetic scenario, truth poses (no tracking)")
            ->check(CLI::IsMember(eyesim::rig::scenario_names()));
        src->require_option(1);
        sub.add_option("--rig", req->rig_path, "rig.yaml for --connect/--capture (default: the synthetic rig)");
        sub.add_option("--truth", req->truth_path, "truth.jsonl to score tracking against");
        sub.add_option("--seconds", req->seconds, "run length for --connect/--scenario; fields for --recording / 50")
            ->check(eyesim::app::finite_in(0.02, 3600.0));
        sub.add_option("--stall-s", req->stall_seconds, "--connect: end the run when the device sends nothing for this long")
            ->check(eyesim::app::finite_in(0.1, 3600.0))
            ->capture_default_str();
        sub.add_option("--seed", req->seed, "scenario seed")->check(eyesim::app::unsigned_integer());
        sub.add_option("--report", req->report_dir, "write a report folder (index.html, stereo snapshots, plots)");
        sub.add_option("--snapshots", req->snapshots, "stereo snapshots in the report")
            ->check(CLI::Range(0, 100))
            ->capture_default_str();
        sub.add_flag("--precision", req->precision,
                     "--connect/--capture: precision mode (every camera's marker patches, each centroid refined on its "
                     "patch where the fit accepts)");
        sub.add_flag("--no-hints", req->no_hints,
                     "with --precision: fit every marker as a whole sphere (by default a marker's fit leaves out what "
                     "the newest poses say hides part of it: its shaft, the eye)");
        sub.add_option("--sync", req->sync,
                       "tracking: interpolate (whole fields, the cameras interpolated to one time) or async (per-body "
                       "filters fed each part as it arrives; with a device in its per-blob mode, --low-latency)")
            ->check(CLI::IsMember({"async", "interpolate"}))
            ->capture_default_str();
        eyesim::app::add_report_delay_option(sub, req->report_delay_ms,
                                             eyesim::tracking::AsyncOptions::kMaxReportDelayUs * 1e-3);
        sub.add_flag("--json", req->json, "one JSON object on stdout");
        return [req]() -> int { return eyesim::app::run_scene(*req); };
    }};

}  // namespace
