#pragma once
/// \file
/// A host run: FieldMarkers from a source (live transport, capture file, or a recording pushed through the FPGA
/// model in-process) → tracker → simulator, with per-frame hooks for accuracy scoring and pictures, and the
/// latency chain field end → packet received → poses ready.

#include "eyesim/frame/pose_source.hpp"
#include "eyesim/frame/simulator.hpp"
#include "eyesim/protocol/frame.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/camera.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/tracking/rig_adapter.hpp"
#include "eyesim/tracking/tracker.hpp"
#include "eyesim/transport/clock_offset.hpp"

#include <functional>
#include <memory>
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

/// Counters of one run.
struct RunStats {
    uint64_t messages = 0;            ///< decoded messages
    uint64_t field_markers = 0;       ///< FieldMarkers messages
    uint64_t frames = 0;              ///< tracking frames simulated
    uint64_t parse_errors = 0;        ///< stream parser errors (CRC, truncation, …)
    uint64_t device_queue_drops = 0;  ///< packets the device dropped (from its DeviceStatus)
    std::vector<double> latency_us;   ///< per frame: field end → poses ready (host clock)
    std::vector<double> transfer_us;  ///< per frame: field end → packet received
};

/// Tracker + simulator, fed one decoded frame at a time.
class HostRun {
public:
    /// Called after each simulated frame with the tracking frame and the poses given to the simulator.
    using FrameHook = std::function<void(const tracking::TrackingFrame&, const FramePoses&)>;

    HostRun(tracking::TrackerConfig config, Simulator& sim);
    /// Per-frame hook (accuracy scoring, pictures).
    void set_hook(FrameHook hook) { hook_ = std::move(hook); }
    /// Device − host clock offset (µs); latencies are measured on the host clock through it. Until the first
    /// call, frames are not counted in the latency figures (their device times cannot be placed on the host
    /// clock); sources whose host and device clocks coincide call it with 0 at the start.
    void set_clock_offset_us(double offset) {
        tracker_->set_clock_offset_us(offset);
        clock_known_ = true;
    }
    /// One decoded message received at `rx_host_us`.
    void on_frame(const protocol::DecodedFrame& frame, double rx_host_us);
    /// End of stream: frames still waiting are built and simulated.
    void finish();
    /// Stream parser errors seen by the source (CRC, truncation, …), for the run's counters.
    void set_parse_errors(uint64_t n) { stats_.parse_errors = n; }
    /// Counters.
    const RunStats& stats() const { return stats_; }
    /// The tracker.
    const tracking::Tracker& tracker() const { return *tracker_; }
    /// Whether the last simulated frame had the working hand measured.
    const FramePoses& last_poses() const { return poses_; }

private:
    void drain();
    std::unique_ptr<tracking::Tracker> tracker_;
    Simulator& sim_;
    TrackingPoseAdapter adapter_;
    tracking::TrackingFrame frame_;
    FramePoses poses_;
    FrameHook hook_;
    RunStats stats_;
    bool clock_known_ = false;
};

/// Pushes a recording through the FPGA model in-process (wire conversion, framing and parsing included, as the
/// device would) into `run`; receive times follow the modelled device timing. `max_fields` ≤ 0: all.
void run_recording(rig::Recording& rec, HostRun& run, int64_t max_fields = 0);

/// Replays a capture file (or raw stream) into `run`. Throws SourceError on an unreadable file; a torn tail or a
/// damaged stretch is reported through `warning` and every good record is used.
void run_capture(const std::string& path, HostRun& run, std::string& warning);

/// A device that keeps its link open but sends nothing (not even the replies to the pings sent every 0.5 s)
/// for this long is taken as stalled.
inline constexpr double kDefaultStallSeconds = 5.0;

/// Connects to a device (`tcp://HOST:PORT`, `usb`, `usb://VID:PID`), estimates the clock offset by ping/pong,
/// starts the stream and feeds `run` until the device closes the link, `max_seconds` pass, or no byte arrives for
/// `stall_seconds` (then `warning` says so and what came before is used). Throws SourceError on a connection failure.
/// Returns the clock offset used (device − host, µs).
double run_live(const std::string& uri, HostRun& run, double max_seconds, std::string& warning,
                double stall_seconds = kDefaultStallSeconds);

}  // namespace eyesim::frame
