#pragma once
/// \file
/// From FieldMarkers messages to time-aligned camera observations. The three cameras are not synchronised
/// (each has its own field phase), so a tracking frame is defined at the exposure mid-time T of a reference
/// camera's field and every other camera's 2D marker images are brought to T:
/// - Interpolate (default): interpolation between that camera's fields just before and just after T (markers
///   paired by class and mutual nearest neighbour), linear, bent by the field before them where the image's
///   acceleration stands out of the noise (SyncOptions::curvature); waits for the field after T (≤ one field period).
/// - Extrapolate: constant-velocity prediction from the camera's last two fields before T (no waiting; error
///   grows with acceleration).
/// - Nearest: the camera's field nearest to T, uncorrected, if within `max_skew_us` (else the camera is missing).
/// A camera with no usable field is missing for that frame (two-view tracking); images that cannot be paired
/// across the two fields are dropped and counted.

#include "eyesim/tracking/correspondence.hpp"

#include "eyesim/protocol/messages.hpp"

#include <array>
#include <cstdint>
#include <string_view>

namespace eyesim::tracking {

/// Field timing of one camera: the delay from its exposure mid-time to the field end stamped by the device.
struct CameraTiming {
    std::array<double, 2> end_to_sample_us{19838.5 + 2000.0, 19870.5 + 2000.0};  ///< per parity (top, bottom)
};

/// One marker image of an assembled field, in full-frame pixels.
struct FieldImage {
    std::uint8_t colour_class = 0;                 ///< 1..4
    std::uint8_t flags = 0;                        ///< protocol marker flags
    Eigen::Vector2d frame_px = Eigen::Vector2d::Zero();  ///< (x, 2·y_field + parity)
    float area_px = 0.0f;                          ///< blob area, field pixels
};

/// One camera field assembled from its FieldMarkers parts.
struct CameraField {
    int camera = 0;                   ///< camera id
    std::uint32_t field_counter = 0;  ///< device field number
    int parity = 0;                   ///< 0 top, 1 bottom
    /// A field brought to another time by two of its camera's fields (interpolate, extrapolate): the weight of the
    /// field of `parity` in the blend, 1 − it the other's (of the other parity where the two are consecutive). A
    /// centroid's offset from the marker's centre that depends on the parity mixes by the same weights.
    double parity_weight = 1.0;
    double field_end_device_us = 0;   ///< device time of the field's last active pixel
    double sample_device_us = 0;      ///< exposure mid-time (device clock): the field's instant
    double received_host_us = 0;      ///< host time the field's last part arrived
    bool blobs_dropped = false;       ///< the device reported dropped blobs
    bool incomplete = false;          ///< a part was lost (next field started before the last part)
    int count = 0;                    ///< valid entries in `images`
    int overflow = 0;                 ///< images beyond kMaxMarkersPerCamera (dropped)
    std::array<FieldImage, kMaxMarkersPerCamera> images{};  ///< the first `count` are valid
};

/// How other cameras are brought to the reference time.
/// Async: no common time at all: each body's filter (async_fusion.hpp) is updated by every camera field at its
/// own exposure time as soon as it is assembled; the frame synchroniser (as Extrapolate) only serves to
/// (re)acquire a body by triangulation.
enum class SyncMode : std::uint8_t { Interpolate, Extrapolate, Nearest, Async };

/// The mode named `name` ("interpolate", "extrapolate", "nearest", "async": the command lines' --sync); throws
/// std::invalid_argument for any other name.
SyncMode sync_mode_from_name(std::string_view name);

/// Options of the synchroniser.
struct SyncOptions {
    SyncMode mode = SyncMode::Interpolate;  ///< see the file comment
    int reference_camera = 0;               ///< frames are at this camera's field times
    double field_period_us = 20000.0;       ///< PAL field period
    double max_gap_us = 30000.0;            ///< two fields further apart than this are not interpolated
    double max_skew_us = 1000.0;            ///< a single field this close to T is used as it is
    double pair_gate_px = 25.0;             ///< largest image motion between a camera's consecutive fields
    double max_wait_us = 45000.0;           ///< give up waiting for a camera's next field after this (device time)
    /// Interpolate: where the camera's two fields before the pair also have the image, the pair's straight line is
    /// bent by the image's acceleration: c, the mean of the second divided differences over the four fields (it
    /// cancels a centroid bias that alternates with the field parity), times (T − t0)(T − t1), shrunk by
    /// c²/(c² + var c) with var c from `curvature_sigma_px` (1σ centroid noise, frame px). A fast turn loses the
    /// line's c·h²/4 lag (`fast`: 3D over all markers 40–50 → 24–32 µm); slow motion keeps the line. Uses only
    /// fields already received: no extra wait.
    bool curvature = true;
    double curvature_sigma_px = 0.05;
};

/// Assembles one camera's FieldMarkers parts into CameraFields (kFieldFlagMoreFollows chains). Allocation-free.
class FieldAssembler {
public:
    /// Adds one message; returns how many fields it completed (0, 1 or 2: a message of a new field while parts
    /// of an older one are pending completes the older one, flagged incomplete). Read them with completed(i).
    int push(const protocol::FieldMarkers& msg, double received_host_us, const CameraTiming& timing);
    /// Completed field i (0 ≤ i < the last push's return value).
    const CameraField& completed(int i) const { return done_[std::size_t(i)]; }
    /// Images refused so far: colour class outside 1..4 or non-finite coordinates.
    int rejected_images() const { return rejected_; }
    /// True while a field's parts are arriving (low-latency mode: its images so far are in building()).
    bool open() const { return active_; }
    /// The open field (valid while open(); its times are not known until the field's last part).
    const CameraField& building() const { return building_; }

private:
    void start(const protocol::FieldMarkers& msg);
    void append(const protocol::FieldMarkers& msg, double received_host_us);
    void finish(const CameraTiming& timing, bool incomplete, int slot);

    CameraField building_{};
    std::array<CameraField, 2> done_{};
    bool active_ = false;
    std::uint16_t next_part_ = 0;
    double latest_complete_us_ = 0;
    int rejected_ = 0;
};

/// Per-camera status of one aligned frame.
enum class CameraSyncState : std::uint8_t { Missing, Direct, Interpolated, Extrapolated };

/// One camera's fields brought to a frame time.
struct AlignedCamera {
    CameraSyncState state = CameraSyncState::Missing;  ///< how the images were obtained
    double dt_us = 0.0;            ///< (nearest used field time) − T
    std::uint32_t field_a = 0;     ///< field counters used
    std::uint32_t field_b = 0;     ///< second field (interpolation/extrapolation)
    int dropped_images = 0;        ///< images that could not be paired across the two fields
};

/// Brings cameras to a common time. Keeps the last few fields per camera; emits frames in time order.
class FrameSync {
public:
    /// Fields remembered per camera.
    static constexpr int kHistory = 6;
    /// Frames waiting for later fields.
    static constexpr int kMaxPending = 8;

    /// `camera_count` cameras (≤ kMaxCameras).
    FrameSync(int camera_count, const SyncOptions& opt);

    /// Adds a complete field.
    void add(const CameraField& f);
    /// True when the oldest pending frame can be built (all cameras decided, or waiting timed out).
    bool ready() const;
    /// End of stream: pending frames are built with what there is.
    void finish() { finished_ = true; }
    /// Builds the oldest ready frame: its time (device clock), the reference field, per-camera state, and images
    /// in full-frame pixels (not yet undistorted). Returns false when none is ready.
    bool pop(double& frame_device_us, std::uint32_t& reference_field, std::array<AlignedCamera, kMaxCameras>& cams,
             std::array<CameraField, kMaxCameras>& images, double& latest_end_device_us,
             double& latest_received_host_us);
    /// The options in use.
    const SyncOptions& options() const { return opt_; }
    /// Camera `cam` has a complete field exposed within max_skew_us of T.
    bool has_field_at(int cam, double T) const;
    /// Camera `cam`'s field exposed within max_skew_us of T is still to come: none at or after T is in, and its
    /// field clock (its newest field and period, the nominal one across a lost field) puts one there — a genlocked
    /// rig's, which ends with the reference camera's field and arrives just after it. A free-running camera whose
    /// newest field is lost is not due: its next field falls elsewhere.
    bool field_due(int cam, double T) const;

private:
    struct Ring {
        std::array<CameraField, kHistory> f{};
        int count = 0;   ///< valid entries (most recent at (head − 1) mod kHistory)
        int head = 0;
        double latest_sample_us = -1e300;
    };
    const CameraField* at(int cam, int age) const;  ///< age 0 = newest
    bool decided(int cam, double T) const;
    void align(int cam, double T, AlignedCamera& ac, CameraField& out, double& end_us, double& recv_us) const;

    int n_;
    SyncOptions opt_;
    std::array<Ring, kMaxCameras> rings_{};
    struct Pending { double T; std::uint32_t ref_field; double end_us; };  // end_us: the reference field's end
    std::array<Pending, kMaxPending> pending_{};
    int pending_count_ = 0;
    bool have_ref_ = false;
    std::uint32_t last_ref_counter_ = 0;
    double last_ref_T_ = 0;
    double newest_device_us_ = -1e300;
    bool finished_ = false;
};

}  // namespace eyesim::tracking
