#pragma once
/// \file
/// One simulator run as `eyesim sim` and `eyesim demo` do it: pick the marker source, track, simulate the scene,
/// score against truth when there is one, take stereo snapshots, print and write the report.

#include "eyesim/app/report.hpp"
#include "eyesim/app/frame_loop.hpp"

#include <string>
#include <vector>

namespace eyesim::app {

/// Where the markers come from (exactly one).
struct SourceSpec {
    std::string connect;    ///< live device: tcp://HOST:PORT, usb, usb://VID:PID
    std::string capture;    ///< capture file (or raw stream)
    std::string recording;  ///< recording directory, run through the FPGA model in-process
    std::string scenario;   ///< synthetic truth poses directly (no tracking): scenario name
};

/// Everything a run needs.
struct SceneRunRequest {
    std::string scene_path;            ///< scenes/*.json
    SourceSpec source;
    std::string rig_path;              ///< rig.yaml (live/capture; default: the recording's, else the default rig)
    std::string truth_path;            ///< truth.jsonl to score against (default: the recording's)
    double seconds = 0;                ///< live / scenario: run length (0: scene duration, or until the link closes)
    double stall_seconds = kDefaultStallSeconds;  ///< live: no byte for this long ends the run with a warning
    double expected_s = 0;             ///< length the snapshots are spread over (0: `seconds`, else the scene's)
    uint64_t seed = 1;                 ///< scenario seed
    std::string report_dir;            ///< write a report folder here ("" = none)
    int snapshots = 3;                 ///< stereo snapshots spread over the run (needs report_dir; 0 = none)
    double animation_fps = 10;         ///< stereo animation of the whole run, frames/s (needs report_dir; 0 = none)
    bool json = false;                 ///< one JSON object on stdout instead of the text report
    bool precision = false;            ///< precision mode (live, capture): markers refined on the device's patches
    bool no_hints = false;             ///< precision mode without occlusion hints: every fit a whole sphere
    std::string sync = "interpolate";  ///< the tracker's camera combination: interpolate, extrapolate, nearest, async
    double report_delay_ms = 19.0;     ///< async: fixed-lag frames this long after exposure (AsyncOptions)
    std::string title = "eyesim sim";  ///< report title
};

/// Runs it; returns the process exit code. Throws Error on bad input.
int run_scene(const SceneRunRequest& req);

}  // namespace eyesim::app
