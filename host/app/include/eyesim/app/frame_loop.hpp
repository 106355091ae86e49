#pragma once
/// \file
/// The frame loop (host/frame, namespace eyesim::frame) under the names the commands and reports use.

#include "eyesim/frame/pose_source.hpp"
#include "eyesim/frame/session.hpp"
#include "eyesim/frame/simulator.hpp"
#include "eyesim/frame/stage_timer.hpp"

namespace eyesim::app {

using frame::Event;
using frame::EventKind;
using frame::FramePoses;
using frame::HostRun;
using frame::host_now_us;
using frame::instrument_pose_eye;
using frame::judge;
using frame::kDefaultStallSeconds;
using frame::LossCounts;
using frame::loss_summary;
using frame::peeled_percent;
using frame::percentile;
using frame::poses_from_truth;
using frame::run_capture;
using frame::run_live;
using frame::run_recording;
using frame::RunStats;
using frame::Scores;
using frame::ScopedStage;
using frame::Simulator;
using frame::SourceError;
using frame::Stage;
using frame::StageSummary;
using frame::StageTimer;
using frame::StageUse;
using frame::to_string;
using frame::tracker_config;
using frame::TrackingPoseAdapter;
using frame::Verdict;

}  // namespace eyesim::app
