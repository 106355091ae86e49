#pragma once
/// \file
/// A host run: FieldMarkers from a source (live transport, capture file, or a recording pushed through the FPGA
/// model in-process) → tracker → simulator, with per-frame hooks for accuracy scoring and pictures, and the
/// latency chain field end → packet received → poses ready.

#include "eyesim/frame/loss.hpp"
#include "eyesim/frame/pose_source.hpp"
#include "eyesim/frame/precision.hpp"
#include "eyesim/frame/simulator.hpp"
#include "eyesim/protocol/frame.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/camera.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/tracking/rig_adapter.hpp"
#include "eyesim/tracking/tracker.hpp"
#include "eyesim/transport/clock_offset.hpp"
#include "eyesim/transport/transport.hpp"

#include <functional>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

namespace eyesim::frame {

/// A source or rig file that cannot be used: one line naming the file, device or field at fault.
class SourceError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// Tracker configuration for rig cameras and the listed instruments, with the FPGA's field timing (device
/// field end → exposure mid-time). Throws SourceError naming the camera or body at fault.
tracking::TrackerConfig tracker_config(const std::vector<rig::CameraModel>& cams, const rig::Bodies& bodies,
                                       const std::vector<tracking::SceneInstrument>& instruments);

/// Host clock, µs (steady).
double host_now_us();

/// Per-frame samples of one figure: every sample up to kMaxSamples, then a uniform random sample of that many
/// (reservoir sampling), so a run of any length holds bounded memory; `count` and `max` stay exact.
struct Samples {
    static constexpr size_t kMaxSamples = size_t(1) << 16;  ///< ≈ 22 minutes of frames at 50 per second
    std::vector<double> v;   ///< the samples kept (in arrival order until the reservoir is full)
    uint64_t count = 0;      ///< samples offered
    double max = 0.0;        ///< largest sample offered
    Samples() { v.reserve(kMaxSamples); }
    /// Offers one sample (no allocation).
    void add(double x);
    bool empty() const { return count == 0; }
    void clear() { v.clear(), count = 0, max = 0.0; }

private:
    uint64_t rng_ = 0x9E3779B97F4A7C15ull;
};

/// Counters of one run.
struct RunStats {
    uint64_t messages = 0;            ///< decoded messages
    uint64_t field_markers = 0;       ///< FieldMarkers messages
    uint64_t fields = 0;              ///< camera fields completed (FieldMarkers without more_follows)
    protocol::ParserStats parser;     ///< the source's stream parser counters
    uint64_t frames = 0;              ///< tracking frames built (and simulated, when there is a simulator)
    uint64_t parse_errors = 0;        ///< stream parser errors (CRC, truncation, …)
    LossCounts loss;                  ///< what the stream lost (sequence numbers, fields, device drops, resyncs)
    /// Per frame: field end (device clock, placed on the host clock through the ping/pong offset) → poses ready
    /// (host clock). Empty when the clocks cannot be related (no pong received, or a device that does not run
    /// at real-time pace: see latency_note).
    Samples latency_us;
    Samples transfer_us;              ///< per frame: field end → its last packet received (same clocks)
    /// Per frame: the frame's instant (exposure mid of its reference field, placed on the host clock) → poses ready.
    Samples exposure_to_pose_us;
    Samples ready_us;                 ///< per frame: last packet received → poses ready (host clock only)
    Samples compute_us;               ///< per frame: tracking stage wall time
    std::string latency_note;         ///< why latency_us is empty, when it is
    double device_clock_rate = 0.0;   ///< device µs per host µs, first to last pong of the segment (≥ 1 s apart;
                                      ///< 0: unknown)
    bool precision = false;           ///< precision mode: markers refined on their patches (HostRun::enable_precision)
    PrecisionStats patches;           ///< precision mode's counters
};

/// Where a run's receive times come from, which decides what "poses ready" is measured against.
enum class RunClock : uint8_t {
    kHost,      ///< live: receive times and "poses ready" are this machine's clock now
    kRecorded,  ///< replay (a capture, a modelled link): receive times are those recorded; poses are ready at
                ///< the receive time of the packet that completed the frame plus the compute time measured now
};

/// Tracker (+ simulator), fed one decoded frame at a time. Handles pongs (clock offset), backward time jumps
/// (a new segment: the tracker restarts), and counts losses.
class HostRun {
public:
    /// Called after each frame with the tracking frame and the poses given to the simulator.
    using FrameHook = std::function<void(const tracking::TrackingFrame&, const FramePoses&)>;

    /// Tracking and simulation.
    HostRun(tracking::TrackerConfig config, Simulator& sim);
    /// Tracking only (`eyesim track`).
    explicit HostRun(tracking::TrackerConfig config);
    /// Which clock receive times are on (run_recording and run_capture set kRecorded; default kHost).
    void set_run_clock(RunClock c) { run_clock_ = c; }
    /// Per-frame hook (accuracy scoring, pictures, poses.jsonl).
    void set_hook(FrameHook hook) { hook_ = std::move(hook); }
    /// Fixes the device − host clock offset (µs) for sources whose clocks are related by construction (a
    /// modelled link: 0). Without it the offset comes from the ping replies in the stream, and until the first
    /// one frames are not counted in the latency figures.
    void set_clock_offset_us(double offset);
    /// Precision mode: FieldMarkers parts wait for their BlobPatch messages and each marker's centroid becomes
    /// the sphere fit on its patch where the fit accepts (PatchRefiner). `class_mask`: the PATCH_ENABLE bits the
    /// device was given; `config`: the fit (see patch_fit_config); `occlusion_hints`: a marker the newest frame's
    /// poses say is partly hidden by its shaft or the eye is fitted with that left out (tracking::MarkerHint).
    void enable_precision(const tracking::SphereFitConfig& config, uint8_t class_mask, bool occlusion_hints = true);
    /// One decoded message received at `rx_host_us`.
    void on_frame(const protocol::DecodedFrame& frame, double rx_host_us);
    /// End of stream: frames still waiting are built (and simulated); the latency figures are settled.
    void finish();
    /// Host time a waiting fixed-lag frame falls due (tracking::Tracker::next_report_host_us; +∞: none): a live
    /// loop waits for bytes no longer than this and then calls poll().
    double next_due_host_us() const;
    /// Releases the frames due by `now_us` (host clock) with no message arriving.
    void poll(double now_us) { drain(now_us); }
    /// The source's stream parser counters (errors, resyncs), for the run's counters.
    void set_parser_stats(const protocol::ParserStats& s);
    /// The link dropped and came back (USB unplug): sequence numbers and field counters start again.
    void link_dropped();
    /// Counters.
    const RunStats& stats() const { return stats_; }
    /// The tracker.
    const tracking::Tracker& tracker() const { return *tracker_; }
    /// Whether the last simulated frame had the working hand measured.
    const FramePoses& last_poses() const { return poses_; }
    /// Clock offset from the pongs (or fixed).
    const transport::ClockOffsetEstimator& clock() const { return clock_; }
    /// Backward time jumps so far (each began a new segment).
    uint64_t time_jumps() const { return stats_.loss.time_jumps; }

private:
    void drain(double now_us);
    void on_pong(const protocol::Reply& r, double rx_host_us);
    void push_markers(const protocol::FieldMarkers& part);
    std::unique_ptr<tracking::Tracker> tracker_;
    std::unique_ptr<PatchRefiner> precision_;
    tracking::MarkerHintSource marker_hints_;  // the precision fits' occluders, from the newest frame's poses
    // Precision mode: wall time spent refining since the last frame, added to the next frame's tracking compute
    // (the refinement is tracking work, done as the patches arrive rather than when the frame is built).
    double refine_wall_us_ = 0.0;
    double push_rx_us_ = 0.0;  // receive time of the message being handled (a held part's push time)
    Simulator* sim_ = nullptr;
    // Asynchronous fusion gives a frame per part of a reference field (low-latency parts), all at that field's
    // time: the simulation steps once per field time, on its first frame (the pose as early as it exists).
    bool step_once_per_time_ = false;
    double last_step_time_us_ = -1e300;
    double unstepped_tracking_us_ = 0.0;  // tracking compute of the frames that did not step the simulation
    RunClock run_clock_ = RunClock::kHost;
    TrackingPoseAdapter adapter_;
    tracking::TrackingFrame frame_;
    FramePoses poses_;
    FrameHook hook_;
    RunStats stats_;
    LossCounter loss_;
    transport::ClockOffsetEstimator clock_;
    bool clock_fixed_ = false;
    bool clock_known_ = false;
    double last_rx_us_ = 0.0;
    double newest_device_us_ = -1.0;   // newest field time of the current segment
    // First and latest pong of the segment (device µs, host µs): the device clock's rate.
    bool have_pong_ = false;
    double pong0_dev_ = 0, pong0_host_ = 0, pong1_dev_ = 0, pong1_host_ = 0;
};

/// A device clock whose rate differs from the host's by more than this (fraction) is not at real-time pace:
/// its field times cannot be placed on the host clock, and no field-end latency is reported.
inline constexpr double kMaxClockRateError = 0.02;

/// Calls `on_bytes(span<const uint8_t> frame, double rx_us)` for every frame the device would send for a
/// recording: the FPGA model in-process, wire conversion and framing, one PedalState per field period, receive
/// times from the modelled device timing and link (device clock = host clock). `max_fields` ≤ 0: all.
void for_each_recording_frame(rig::Recording& rec, int64_t max_fields,
                              const std::function<void(std::span<const uint8_t>, double)>& on_bytes);

/// Pushes a recording through the FPGA model in-process (for_each_recording_frame, parsed) into `run` on the
/// modelled clock (RunClock::kRecorded, offset 0). `max_fields` ≤ 0: all.
void run_recording(rig::Recording& rec, HostRun& run, int64_t max_fields = 0);

/// Replays a capture file (or raw stream) into `run` (RunClock::kRecorded). Throws SourceError on an
/// unreadable file. Damage (a torn tail, a damaged stretch), receive times going backwards and device time
/// going backwards (a new segment) are reported in `warnings`, one line each naming the byte offset; every good
/// record is used.
void run_capture(const std::string& path, HostRun& run, std::vector<std::string>& warnings, int64_t max_frames = 0);

/// A device that keeps its link open but sends nothing (not even the replies to the pings) for this long is
/// taken as stalled.
inline constexpr double kDefaultStallSeconds = 5.0;

/// Settings of a live run.
struct LiveOptions {
    double max_seconds = 0.0;                   ///< stop after this long (0: until the link ends)
    double stall_seconds = kDefaultStallSeconds;  ///< end the run after this long without a byte
    int64_t max_frames = 0;                     ///< stop after this many tracking frames (0: no limit)
    bool progress = false;                      ///< a progress line on stderr
    /// Precision mode: PATCH_ENABLE (bit c-1: class c) written to every camera before stream_start (0: off).
    uint8_t patch_enable = 0;
    /// When set, every chunk received is also written to this capture file with its receive time on the host
    /// clock (docs/protocol.md section 6), as it arrived, damage and all.
    std::string capture_out;
};

/// How a live run ended.
struct LiveResult {
    std::string source;                 ///< the link (`tcp://…`, `usb://…`)
    std::string end;                    ///< why it ended: "device closed the link", "connection reset by peer", …
    bool clean = true;                  ///< false for a reset, a stall, a lost device
    std::vector<std::string> warnings;  ///< one line each (link drops, the end when not clean)
    double wall_s = 0.0;                ///< run time
};

/// Runs a live session over an open transport: sends stream_start (again after a reconnect), pings for the
/// clock offset, feeds `run` until the link ends however it ends (FIN, RST, stall, device gone), the time or
/// frame limit is reached; then every frame still in the parser and the tracker is delivered. Never throws for
/// a link that fails after it opened: the end is in the result. Throws SourceError when `capture_out` cannot be
/// created.
LiveResult run_live(transport::Transport& link, HostRun& run, const LiveOptions& opt);

/// Opens `uri` (`tcp://HOST:PORT`, `usb`, `usb://VID:PID`) and runs run_live on it. Throws SourceError when the
/// link cannot be opened.
LiveResult run_live(const std::string& uri, HostRun& run, const LiveOptions& opt);

}  // namespace eyesim::frame
