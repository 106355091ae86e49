#pragma once
/// \file
/// The host tracker: FieldMarkers (from a transport or a capture) in, one TrackingFrame per reference-camera
/// field out, with instrument poses in the eye frame, eye rotation, 3D markers with covariance, and timing.
///
/// Host frame loop:
/// \code
///   Tracker tracker(config);
///   tracker.set_clock_offset_us(estimator.offset_us());     // device − host, from ping/pong
///   on message: tracker.push(field_markers, host_now_us);     // or push(pedal_state, host_now_us)
///   TrackingFrame frame;
///   while (tracker.pop(frame, host_now_us)) use(frame);       // frame.instruments[i].tip_eye_mm, frame.eye ...
///   at end of a capture: tracker.finish(); then pop the rest.
/// \endcode
/// Everything after construction is allocation-free.

#include "eyesim/tracking/async_fusion.hpp"
#include "eyesim/tracking/body_model.hpp"
#include "eyesim/tracking/camera_geometry.hpp"
#include "eyesim/tracking/correspondence.hpp"
#include "eyesim/tracking/distortion.hpp"
#include "eyesim/tracking/field_sync.hpp"
#include "eyesim/tracking/pose.hpp"

#include "eyesim/protocol/messages.hpp"

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

namespace eyesim::tracking {

/// Everything the tracker needs to know up front.
struct TrackerConfig {
    std::vector<CameraGeometry> cameras;   ///< one per camera id (≤ kMaxCameras)
    std::vector<CameraTiming> timing;      ///< one per camera (field end → exposure mid), same order
    BodySet bodies;                        ///< eye and instruments to fit
    SyncOptions sync;                      ///< time alignment
    AsyncOptions async;                    ///< per-body filters (sync.mode = SyncMode::Async)
    CorrespondenceOptions correspondence;  ///< matching and triangulation
    PoseOptions pose;                      ///< body fits
    UndistortOptions undistort;            ///< inverse distortion
    double centroid_sigma_px = 0.05;       ///< 1σ centroid noise assumed for covariance (frame pixels)
    int opening_pedal_axis = 0;            ///< pedal axis that drives the instrument function (jaws, suction)
    /// Correct instrument-marker centroids for the shaft that runs through each marker sphere: the half-shaft
    /// pointing at a camera hides a strip of the sphere's image and shifts its centroid along the projected
    /// shaft (~0.5 px on the default rig). Modelled from the first pose fit (uniform disk minus the strip), then
    /// the markers are re-triangulated and the instruments refitted.
    bool shaft_occlusion_correction = true;
    /// Correct centroids for the eye in front: at its outline the eye hides part of a marker (its own markers at
    /// the limb, instrument markers seen past it), whose centroid is then the visible part's (off its centre by up
    /// to a marker radius). Modelled from the first fit's poses (the marker's shaded sphere less the eye, and its
    /// shaft for an instrument marker: refine.hpp hinted_centroid_offset), every view the eye hides corrected, the
    /// views judged occluded included, the marker re-triangulated and the bodies refitted. Instrument markers are
    /// corrected within the shaft correction's pass (both on).
    bool eye_occlusion_correction = true;
    /// Every marker view the eye does not hide is moved back by where the pipeline's centroid of its image lies from
    /// its centre at the pose — the shaded sphere less its shaft (an instrument marker), sampled on the field's
    /// lines two frame rows apart (refine.hpp hinted_centroid_offset, the eye's correction's model; on a view blended
    /// from two fields, mixed by their weights) — in the filters (--sync async, at the predicted pose) and in the
    /// shaft and eye corrections of the other modes (at the first fit's poses). Off: a uniform disc less a strip of
    /// the shaft's width, and clear eye markers as they are, which leaves the shading's and the sampling's parts —
    /// an error that alternates with the field parity (the eye's rotation 0.005° from field to field) and
    /// instrument markers biased by 10–20 µm (docs/validation.md, "The marker's image model").
    bool marker_image_model = true;
};

/// Bit flags of a tracking frame.
enum FrameFlag : std::uint32_t {
    kFrameOk = 0,
    kFrameTwoView = 1u << 0,        ///< a camera was missing: every marker from two views at most
    kFrameTooFewCameras = 1u << 1,  ///< fewer than two cameras: nothing triangulated, poses held
    kFrameNonFinite = 1u << 2,      ///< non-finite input was refused
};

/// Host-side timing of one frame (host clock, µs). The chain is sample → field end → received → poses ready.
struct FrameTiming {
    double sample_host_us = 0;       ///< the frame's instant (reference exposure mid-time)
    double field_end_host_us = 0;    ///< last pixel of the latest field the frame needed (0: a frame from a part
                                     ///< of a field still being read out, low-latency mode)
    double received_host_us = 0;     ///< the latest of those fields' last packets arrived
    double poses_ready_host_us = 0;  ///< poses computed (`now_host_us` passed to pop, + compute time)
    double compute_us = 0;           ///< wall time spent in the tracking stage for this frame
};

/// One tracking frame.
struct TrackingFrame {
    std::uint64_t index = 0;              ///< frames popped so far
    std::uint32_t reference_field = 0;    ///< field counter of the reference camera
    double time_device_us = 0;            ///< the frame's instant on the device clock
    FrameTiming timing;                   ///< latency chain
    std::uint32_t flags = kFrameOk;       ///< FrameFlag bits
    int camera_count = 0;                 ///< cameras configured
    int cameras_used = 0;                 ///< cameras that contributed images
    std::array<AlignedCamera, kMaxCameras> cameras{};  ///< per camera: how it was aligned to the frame time
    EyePose eye;                          ///< eye rotation about its fixed centre
    int instrument_count = 0;             ///< valid entries in `instruments` (= bodies.instrument_count)
    std::array<InstrumentPose, kMaxInstruments> instruments{};  ///< in BodySet order; rig and eye frames
    CorrespondenceResult markers;         ///< triangulated markers with covariance
    MarkerAssignment assignment;          ///< which body each marker was given to
    int images_in = 0;                    ///< marker images entering correspondence
    int images_dropped_sync = 0;          ///< images lost in time alignment (unpaired between fields)
    int markers_unassigned = 0;           ///< triangulated markers no body claimed
    /// Instruments not measured in this frame whose markers a camera sees whole (bit b: instrument b) — one camera
    /// alone, or two whose images do not triangulate to the body — placed from those images and the trocar
    /// (PoseOptions::single_view; SyncMode::Interpolate, Extrapolate and Nearest frames). For the refinement's
    /// occlusion hints only, which need the marker's image and the shaft's direction across it: from one view the
    /// depth along the line of sight is poorly determined (on `occlusion` seed 155 a withdrawn injection needle's
    /// tip 1–9 mm off), so the instrument stays reported held.
    std::uint8_t one_view_mask = 0;
    std::array<InstrumentPose, kMaxInstruments> one_view{};
};

/// The tracker (see the file comment).
class Tracker {
public:
    /// Checks the configuration; throws std::invalid_argument naming the camera or value at fault.
    explicit Tracker(TrackerConfig config);
    Tracker(const Tracker&) = delete;             ///< holds views into its own camera array
    Tracker& operator=(const Tracker&) = delete;  ///< holds views into its own camera array

    /// Device − host clock offset (µs) from the transport's ping/pong estimator.
    void set_clock_offset_us(double device_minus_host_us) { offset_us_ = device_minus_host_us; }
    /// Adds one FieldMarkers message received at `received_host_us`.
    void push(const protocol::FieldMarkers& msg, double received_host_us);
    /// Adds a pedal state (sets the instruments' opening from `opening_pedal_axis`).
    void push(const protocol::PedalState& pedal, double received_host_us);
    /// End of stream: frames still waiting for later fields (or for their fixed lag) are built with what there is.
    void finish() {
        sync_.finish();
        flush_pending_ = true;
    }
    /// A new stream segment (the device restarted, or the stream's time jumped back): forgets the fields,
    /// pending frames and pose history of the old one (pop them first: finish(), then pop until false). Keeps
    /// the configuration, the clock offset and the counters.
    void restart();
    /// Builds the next ready frame into `out`; `now_host_us` is the host time of the call (poses ready = now +
    /// compute time). Returns false when no frame is ready.
    bool pop(TrackingFrame& out, double now_host_us);

    /// The tracking stage alone on already aligned images (frame pixels): undistort, correspond, triangulate,
    /// fit. `out` keeps pose history across calls. Used by pop(), tests and benchmarks.
    void track_images(std::span<const CameraField> images, std::span<const bool> present, TrackingFrame& out);

    /// One camera's image of triangulated marker `k` in the frame last built by pop() or track_images(), as
    /// the tracker used it. Valid until the next frame is built; for truth-free checks (validation), never
    /// needed by the hot path.
    struct MarkerView {
        bool present = false;   ///< the camera gave the marker an image
        bool left_out = false;  ///< judged partly occluded: not used in the triangulation
        Eigen::Vector2d observed_px = Eigen::Vector2d::Zero();  ///< centroid as received (distorted frame px)
        /// The image the last triangulation used (distorted frame px): the observed centroid, moved by the
        /// shaft-occlusion correction where that applied.
        Eigen::Vector2d used_px = Eigen::Vector2d::Zero();
        Eigen::Vector2d used_xn = Eigen::Vector2d::Zero();  ///< `used_px` undistorted, normalised (z = 1)
    };
    /// Camera `c`'s image of marker `k` of `frame`, which must be the frame last built (see MarkerView).
    MarkerView marker_view(const TrackingFrame& frame, int k, int c) const;

    /// SyncMode::Async: the poses of the bodies being tracked predicted to `t_device_us` (a display time; the
    /// newest observation's time gives the filters' own estimate). Bodies not tracked are left as they are; returns
    /// false when none is tracked (or in the other modes). Does not change the filters.
    bool pose_at(double t_device_us, EyePose& eye, std::span<InstrumentPose> instruments) const;

    /// Cameras in use.
    std::span<const CameraGeometry> cameras() const { return cameras_; }
    /// The configuration.
    const TrackerConfig& config() const { return config_; }
    /// Images refused on input (bad class or coordinates).
    int rejected_images() const;
    /// Marker views whose centroid the eye's model moved back (TrackerConfig::eye_occlusion_correction) and that the
    /// poses then used: views re-triangulated in the sync modes, images fused in SyncMode::Async. How much of the
    /// result rests on the model (the eye's outline in front of a marker), counted since construction.
    std::uint64_t eye_model_views() const { return eye_model_views_; }
    /// Low-latency parts fused at their own time, before newer ones (AsyncOptions::time_order_parts), per body
    /// and part, counted since construction.
    std::uint64_t time_ordered_parts() const { return replayed_parts_; }
    /// Host time the oldest waiting fixed-lag frame falls due (AsyncOptions::report_delay_us; +∞ when none waits):
    /// a host loop whose next message comes later calls pop() at this time, as a timer would.
    double next_report_host_us() const;
    /// Body poses of fixed-lag frames smoothed by what was fused after their time (AsyncOptions::report_delay_us),
    /// counted since construction.
    std::uint64_t smoothed_poses() const { return smoothed_poses_; }

private:
    /// Each corrects markers' views from the first fit's poses and returns whether it moved any (the caller
    /// refits the bodies once).
    bool correct_shaft_occlusion(TrackingFrame& out);
    bool correct_eye_occlusion(TrackingFrame& out);
    // Instruments not measured now whose markers a camera sees whole: placed from the images and the trocar for the
    // hints (TrackingFrame::one_view, PoseOptions::single_view).
    void single_view_instruments(TrackingFrame& out);
    // How long an instrument may have been held for a single view to take it up again (frames: its last pose only
    // starts the fit), and how far off the line through the trocar's image a candidate image may lie (px).
    static constexpr int kSingleViewMaxHeldFrames = 50;
    static constexpr double kSingleViewLinePx = 3.0;
    /// Camera c's observation of image p with its centroid moved back by (dx_px, dv_px) (frame px, the share of the
    /// marker something hides) and σ grown by kEyeCorrectionRelError of that; false when it does not undistort.
    bool shifted_observation(int c, const ImagePoint& p, double dx_px, double dv_px, Observation& o) const;
    /// The views (bit c) in which another marker of m's colour that the poses put in view lies so near the image of
    /// m (radius r_mm, at X) that the two make one blob: m's image there is also the one nearest the other marker.
    /// Its centroid lies between them and places neither unless moved back: shift_px[c] is where the poses put the
    /// joined blob's centroid less m's visible part's (frame px; each marker weighted by its visible light). Eye
    /// marker `eye_marker` (−1: none) is m itself.
    std::uint8_t merged_views(const TrackingFrame& out, const MatchedMarker& m, const Eigen::Vector3d& X, double r_mm,
                              int eye_marker, std::array<Eigen::Vector2d, kMaxCameras>& shift_px) const;
    /// Two markers' images nearer than their radii and this (field px, along each axis) make one blob: the
    /// pipeline's 8-connected runs join across a one-pixel gap, and the marker's colour blurs past its edge.
    static constexpr double kMergeGapPx = 1.0;
    /// Other markers merged_views considers in one view's blob.
    static constexpr int kMaxJoined = 4;
    /// A view whose marker the eye hides beyond this share of its light is left out of the correction.
    static constexpr double kMinVisibleShare = 0.05;
    /// A marker judged occluded is taken for an eye marker predicted within this of its (biased) point.
    static constexpr double kOccludedEyeMarkerGateMm = 1.5;
    /// An image no marker took is taken as such a marker's view in a camera its match left out when it lies
    /// within this of where the fitted eye pose puts the marker's visible part, and no other image of the class lies
    /// within twice this (px).
    static constexpr double kAdoptGatePx = 1.5;
    /// A corrected view's centroid σ grows by this share of the correction's shift.
    static constexpr double kEyeCorrectionRelError = 0.2;
    bool pop_async(TrackingFrame& out, double now_host_us);
    /// Fuses images [first, f.count) of camera field `f` (a whole field, or the newest parts of an open one in
    /// low-latency mode); `last` when the field is complete. Returns the images a filter accepted.
    int fuse_field(const CameraField& f, int first, bool last, double t_us);  // at device time t_us
    /// Instrument b's tip depth past its trocar (mm) where its shaft passes through it (the trocar prior's test:
    /// the tip inside the eye, the line within trocar_gate_mm of the trocar), else −1; the trocar's rig point.
    double trocar_depth_mm(int b, Eigen::Vector3d* trocar_rig_mm) const;
    void set_trocar_pivot(int b);  // instrument b's agile model about its trocar (or none) from the newest poses
    // Parts in time order (AsyncOptions::time_order_parts): per body, the filter as it was before each recent
    // update time and the images (and trocar lines) applied at that time. A part older than the filter's state is
    // fused at its own time from the state before it, and the newer times' images are applied again after it.
    struct ReplayObs {
        std::int8_t camera = 0;
        std::int8_t marker = -1;  // −1: the trocar line
        bool shaft = false;       // the shaft's occlusion shift is modelled
        Eigen::Vector2d px = Eigen::Vector2d::Zero();
        double sigma_x_px = 0, sigma_y_px = 0;
        Eigen::Vector3d p_rig_mm = Eigen::Vector3d::Zero();  // the line's rig point
        double sigma_mm = 0;
    };
    struct ReplayEpoch {
        double t_us = 0;
        BodyFilter before;  // the filter before it was moved to t_us
        int n_obs = 0;
        std::array<ReplayObs, 2 * kMaxBodyMarkers + 2> obs{};
    };
    static constexpr int kReplayEpochs = 8;  // three cameras: about three update times a field period
    struct ReplayHistory {
        std::array<ReplayEpoch, kReplayEpochs> pool{};
        std::array<std::uint8_t, kReplayEpochs> order{};  // pool slots in time order, oldest first
        std::uint32_t free = (1u << kReplayEpochs) - 1;     // bit s: pool slot s unused
        int count = 0;
        int current = -1;  // the slot this part's images go to (−1: none, nothing recorded)
        int replay_from = 0;  // order index of the first newer time to apply again after this part
        /// A new time at order index `pos` with the filter `before` (the oldest time leaves when full); its slot.
        int insert(int pos, double t_us, const BodyFilter& before);
        void clear() {
            count = 0;
            free = (1u << kReplayEpochs) - 1;
            current = -1;
        }
    };
    void replay_begin(int b, double t_us);                  // a part at the filter's time or later
    bool replay_rewind(int b, double t_us);                 // an older one: false where the history is too short
    void replay_record(int b, const ReplayObs& o);
    // One image (or the trocar line, marker −1) into body b's filter: what fuse_field applies and a replay repeats.
    bool apply_point(BodyFilter& flt, int b, const ReplayObs& o, double age_us);
    void replay_record_newest(int b, const ReplayObs& o);   // at the filter's newest time
    void replay_finish(int b);                              // the newer times' images again
    std::unique_ptr<ReplayHistory[]> replay_;               // one per body, with time_order_parts
    std::uint64_t replayed_parts_ = 0;
    void acquire(const CameraField& f);
    void acquire_due_frame();  // the acquisition at acquire_due_us_ once the synchroniser's frame is ready
    static constexpr int kBodies = 1 + kMaxInstruments;  ///< eye, then the instruments
    // Fixed-lag reports (AsyncOptions::report_delay_us): a reference field's frame waits until the host clock is
    // report_delay_us past its exposure; its poses are then smoothed from the parts history's filter at its time.
    struct PendingFrame {
        CameraField field;  // as its newest accepted part left it
        bool last = false;
    };
    bool genlocked_fields_due(const PendingFrame& p) const;  // a genlocked rig's fields of p's time still to come
    static constexpr int kPending = 4;  // report_delay_us is under a field period: one or two wait at a time
    std::array<PendingFrame, kPending> pending_{};
    int pending_head_ = 0, pending_count_ = 0;
    std::uint32_t pending_last_reported_ = 0;
    bool pending_reported_any_ = false;
    bool flush_pending_ = false;  // finish(): the waiting frames go now
    std::uint64_t smoothed_poses_ = 0;
    void hold_frame(const CameraField& f, bool last);
    bool report_due(TrackingFrame& out, double now_host_us);
    /// `smooth`: a fixed-lag frame, each pose smoothed by what was fused after its time.
    void build_async_frame(const CameraField& f, TrackingFrame& out, const PendingFrame* smooth = nullptr);
    /// Which bodies a frame at T reports held (coasting on the prediction, one view, unsure, missed).
    void held_bodies(double T, std::array<bool, kBodies>& held) const;

    TrackerConfig config_;
    std::vector<CameraGeometry> cameras_;
    Correspondence correspondence_;
    FrameSync sync_;
    std::array<FieldAssembler, kMaxCameras> assemblers_{};
    double offset_us_ = 0.0;
    double opening_ = 0.0;
    std::uint64_t frames_ = 0;
    EyePose last_eye_;
    std::array<InstrumentPose, kMaxInstruments> last_instruments_{};
    // Frames since each instrument was last measured (single_view_instruments; large: never).
    std::array<int, kMaxInstruments> unmeasured_frames_ = make_unmeasured();
    std::array<InstrumentPose, kMaxInstruments> one_view_{};  // the last frame's TrackingFrame::one_view
    std::uint8_t one_view_mask_ = 0;
    static std::array<int, kMaxInstruments> make_unmeasured() {
        std::array<int, kMaxInstruments> a{};
        a.fill(1 << 20);
        return a;
    }
    // Per-frame scratch (kept as members: no allocation, no large stack frames).
    std::array<CameraField, kMaxCameras> aligned_{};
    std::array<CameraObservations, kMaxCameras> views_{};
    std::array<int, kMaxCameras> view_parity_{};  // each view's field parity (0 top, 1 bottom)
    std::array<double, kMaxCameras> view_parity_weight_{};  // that parity's weight in a blended view (CameraField)
    // Views the shaft-occlusion correction moved (bit c of marker k) and the normalised images it used.
    std::array<std::uint8_t, kMaxMarkersPerFrame> corrected_views_{};
    std::array<std::array<Eigen::Vector2d, kMaxCameras>, kMaxMarkersPerFrame> corrected_xn_{};
    int rejected_non_finite_ = 0;
    int rejected_before_restart_ = 0;

    // --- SyncMode::Async ---
    static constexpr int kQueue = 32;        ///< fields and low-latency parts waiting for pop()
    /// Images [first, field.count) of `field` to fuse; `last`: the field is complete.
    struct QueuedField {
        CameraField field;
        int first = 0;
        bool last = true;
        double fuse_us = 0;  // the time its images are fused at (device µs): the field's, or its first parts'
    };
    void enqueue(const CameraField& f, int first, bool last);
    std::array<QueuedField, kQueue> queue_{};
    int queue_head_ = 0, queue_count_ = 0;
    std::uint64_t eye_model_views_ = 0;
    std::array<BodyFilter, kBodies> filters_{};
    std::array<double, kBodies> last_good_us_{};
    std::array<double, kBodies> missed_us_{};  ///< the newest camera field that found the instrument missing
    /// The newest field of each camera that gave the body min_markers_good images (device µs).
    std::array<std::array<double, kMaxCameras>, kBodies> supported_us_{};
    std::array<int, kBodies> used_last_field_{};
    // When each body marker was last used in each camera (device µs), for the markers a frame reports.
    std::array<std::array<std::array<double, kMaxCameras>, kMaxBodyMarkers>, kBodies> seen_us_{};
    std::array<double, kMaxCameras> last_field_us_{};
    // Low-latency parts: per camera, the open field's counter and images already queued; the last complete
    // field's end, counter and the field period measured between two (the times of an open field).
    std::array<std::uint32_t, kMaxCameras> open_counter_{};
    std::array<int, kMaxCameras> open_queued_{};
    std::array<double, kMaxCameras> open_sample_us_{};  // the open field's time its parts were fused at
    std::array<double, kMaxCameras> done_end_us_{};
    std::array<std::uint32_t, kMaxCameras> done_counter_{};
    std::array<double, kMaxCameras> done_period_us_{};
    std::array<bool, kMaxCameras> have_done_{};
    // Images each body's filter accepted from each camera's current field so far (over its parts).
    std::array<std::array<int, kMaxCameras>, kBodies> field_used_{};
    std::array<std::array<int, kMaxCameras>, kBodies> prev_field_used_{};  // the same over that camera's field before
    /// Images of each body within the gate that its filter refused (NIS) in each camera's current field so far.
    std::array<std::array<int, kMaxCameras>, kBodies> field_refused_{};
    std::array<std::uint32_t, kMaxCameras> field_images_tried_{};  // bit i: image i was offered to a filter
    static_assert(kMaxMarkersPerCamera <= 32, "field_images_tried_ holds one bit per image");
    std::uint32_t ref_reported_counter_ = 0;  // the reference field a frame was last reported for
    bool ref_reported_ = false;
    std::array<std::uint32_t, kMaxCameras> last_field_counter_{};
    // Acquisition by triangulation: the last fit of each body (velocity from two in a row).
    TrackingFrame acquire_frame_{};
    std::array<AlignedCamera, kMaxCameras> acquire_cams_{};
    std::array<bool, kBodies> acquire_measured_{};
    std::array<double, kBodies> acquire_t_us_{};
    std::array<Eigen::Quaterniond, kBodies> acquire_R_{};
    std::array<Eigen::Vector3d, kBodies> acquire_t_mm_{};
    bool acquired_this_field_ = false;
    bool acquire_due_ = false;     // a reference field's acquisition waits for its frame (acquire_due_frame)
    double acquire_due_us_ = 0.0;  // that field's exposure time
    std::uint64_t async_frames_ = 0;
};

}  // namespace eyesim::tracking
