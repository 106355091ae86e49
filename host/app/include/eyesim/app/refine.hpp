#pragma once
/// \file
/// Blob refinement (tracking/refine.hpp) applied to a field's blobs with the rig's marker colours, as
/// `eyesim fpga --refine` and `eyesim validate --refine` run it.

#include "eyesim/fpga/blob.hpp"
#include "eyesim/fpga/register_map.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/tracking/marker_prediction.hpp"
#include "eyesim/tracking/refine.hpp"
#include "eyesim/tracking/tracker.hpp"

#include <array>
#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <utility>
#include <vector>

namespace eyesim::app {

/// The fit's configuration with the rig's default marker colours (classes 1..4, sRGB as lit on the rig).
tracking::SphereFitConfig rig_sphere_fit_config();

/// rig_sphere_fit_config() for the streams of `rec`: subsampled or lossy video (its codec and chroma format, as
/// the decoder reports them) models the chroma with a larger σ (tracking::sphere_fit_config_for_source). Camera 0's
/// stream stands for all (the rig's cameras record alike).
tracking::SphereFitConfig recording_sphere_fit_config(const rig::Recording& rec);

/// Replaces blob centroids by the refinement stage's where it accepts the fit; counts refusals by reason.
class BlobRefiner {
public:
    BlobRefiner();
    /// With a given fit configuration (recording_sphere_fit_config()).
    explicit BlobRefiner(const tracking::SphereFitConfig& config);

    /// Refines `blobs` of `field` (UYVY, 720 × `height`) in place: centroids only, the blob set is unchanged.
    /// Returns how many were refined.
    /// With shaft hints set, `camera` names the field's camera.
    int refine(const uint8_t* field, int height, std::vector<fpga::Blob>& blobs, int camera = -1);

    /// Where the instruments are (nullptr: unknown): a blob the source knows as an instrument marker is fitted
    /// with its shaft left out (tracking::MarkerHint). The source must outlive the refiner's use of it.
    void set_hints(const tracking::MarkerHintSource* source) { hints_ = source; }
    /// Fits made with a shaft hint (accepted or not).
    int64_t hinted_fits() const { return hinted_fits_; }

    /// Blobs whose fit was refused, by tracking::FitRefusal.
    const std::array<int64_t, tracking::kFitRefusalCount>& refusals() const { return refusals_; }
    /// {"chi2": n, "implausible": n, …}: the refusals by name.
    nlohmann::json refusals_json() const;

    /// How refine() ended for each blob of the last field it was given: "fitted", "hinted" (fitted with a hint's
    /// occluders left out), the refusal's name (tracking::to_string), or "kept" (a fit the wire's unsigned
    /// coordinates cannot hold), in the blobs' order.
    const std::vector<const char*>& last_outcomes() const { return outcomes_; }
    /// Whether the poses gave each blob of the last field a hint (MarkerHintSource: what hides part of its marker),
    /// whatever the outcome, in the blobs' order: a refused fit with one failed on the pose's model, one without on
    /// the whole sphere's.
    const std::vector<std::uint8_t>& last_hinted() const { return hinted_; }

private:
    tracking::SphereFitConfig config_;
    std::unique_ptr<tracking::SphereFitWorkspace> work_;  // ≈ 250 KiB, allocated once
    std::array<int64_t, tracking::kFitRefusalCount> refusals_{};
    const tracking::MarkerHintSource* hints_ = nullptr;
    int64_t hinted_fits_ = 0;
    std::vector<tracking::BlobBox> boxes_;  // the field's blobs as the fit takes them (reused)
    std::vector<const char*> outcomes_;     // per blob of the last field (reused)
    std::vector<std::uint8_t> hinted_;      // per blob of the last field (reused)
};

/// Hints for a recording's first fields, for the offline tools. A field's hints come from the poses of the fields
/// before it, so the fields before a tracker's first pose (two on the rig) would be fitted without them; on lossy
/// video their partly hidden markers were then 4–17× the error of later fields' (DVCPRO25 `sweep`, seeds 1–8).
/// A tool that reads a recording may look ahead: this opens `dir` a second time, runs the model (`maps`, cameras
/// `cams`), the refinement without hints (`fit`) and a tracker (`tracker`) over its first fields until the tracker
/// gives a pose, at most `max_fields`, and updates `hints` with those poses, which then stand for the first fields
/// of the tool's own pass. The live chain cannot look ahead: it fits them plain. Returns the fields read;
/// `hints.ready()` says whether a pose was found. Throws rig::RigError, Error as FpgaModelRun does.
int64_t prime_marker_hints(const std::string& dir, const std::vector<int>& cams,
                           const std::vector<fpga::RegisterMap>& maps, const tracking::SphereFitConfig& fit,
                           tracking::TrackerConfig tracker, int64_t max_fields, tracking::MarkerHintSource& hints);

/// Longest gap between two one-view placements, and furthest from the newer one, that HintMotion moves an
/// instrument over at their velocity (three fields).
inline constexpr double kOneViewMotionMaxUs = 60000.0;

/// The instruments' hints moved to each field's own time. The hint tracker's newest frame is about 1.7 fields older
/// than the next field to be fitted (the frames of the interpolating tracker wait for the other cameras), and on
/// `sweep` an instrument marker moves about 0.6 px a field: the pose's prediction then refused good fits of
/// slivers on lossy video. A second tracker, asynchronous (per-body filters with velocities), gets the same
/// messages; before a field is fitted, each instrument pose of the hint tracker's frame is moved by the motion its
/// filter predicts from that frame's time to the field's exposure time. The eye's hint stays the frame's: it moves
/// a tenth of that, and its predicted motion moved the fits of eye markers 90 % behind the eye's outline more
/// than it placed them (raw `sweep` seed 91: 0.0229 → 0.0241 px over all blobs). An instrument the hint tracker
/// only placed from one camera's view (tracking::TrackingFrame::one_view: no two cameras triangulate it, so the
/// motion tracker does not follow it) moves on at the velocity of its last two placements, within
/// kOneViewMotionMaxUs: withdrawn along its trocar it crossed 2.5 px a field while its hint, a frame old, held it
/// 1.3–2.5 px behind (`occlusion` seed 184). For lossy sources only
/// (hint_motion_for): their fits lean on the pose (tracking::SphereFitConfig::prediction_gate_visible,
/// restart_from_prediction); on raw and lossless fields, whose fits start from an accurate pipeline centroid and take
/// only the occluders from the hint, `fast` lost by it (raw seeds 125–130: +1 … +22 %). Fixed storage after
/// construction.
class HintMotion {
public:
    /// `config`: the hint tracker's; the motion tracker runs it with SyncMode::Async.
    explicit HintMotion(tracking::TrackerConfig config);
    /// One message, as the hint tracker gets it (feed_hint_tracker).
    void push(const protocol::FieldMarkers& msg, double received_us);
    /// Replaces the instrument poses `hints` holds from `frame` (the hint tracker's newest) by those poses moved to
    /// the exposure time of camera `camera`'s field of `parity` whose cycle 0 is at device time `field_start_us`.
    /// Returns false (hints unchanged) where the motion tracker has no pose to move them by.
    bool move_to_field(const tracking::TrackingFrame& frame, int camera, int parity, uint64_t field_start_us,
                       tracking::MarkerHintSource& hints);

private:
    tracking::Tracker tracker_;
    tracking::TrackingFrame frame_;
    std::array<tracking::InstrumentPose, tracking::kMaxInstruments> at_frame_{}, at_field_{}, moved_{};
    double frame_pose_us_ = 0;    // the frame time at_frame_ holds the poses of
    bool frame_pose_ok_ = false;  // at_frame_ is valid for it
    // Per instrument its last two one-view placements of consecutive frames (frame times; n: how many hold one).
    struct OneViewTrack {
        tracking::InstrumentPose prev, last;
        double prev_us = 0, last_us = 0;
        int n = 0;
    };
    std::array<OneViewTrack, tracking::kMaxInstruments> one_view_{};
    void follow_one_view(const tracking::TrackingFrame& frame, int n);
    bool move_one_view(int body, double field_us, tracking::InstrumentPose& out) const;
};

/// Whether the fits of `fit` (recording_sphere_fit_config) take their hints moved to the field's time (HintMotion):
/// a lossy or subsampled source's, whose refused fits start again from the pose.
inline bool hint_motion_for(const tracking::SphereFitConfig& fit) {
    return fit.restart_from_prediction || fit.prediction_gate_visible > 0.0;
}

/// One field's messages (`msgs`: device-ready time in µs, message) into the hint tracker in the order the device has
/// them ready, each frame it gives into `hints`; `msgs` is left empty. With `motion`, it gets them too.
void feed_hint_tracker(std::vector<std::pair<double, protocol::FieldMarkers>>& msgs, tracking::Tracker& tracker,
                       tracking::TrackingFrame& frame, tracking::MarkerHintSource& hints, HintMotion* motion = nullptr);

/// Fields prime_marker_hints() reads at most: a rig's tracker gives its first pose after two.
inline constexpr int64_t kMaxPrimingFields = 8;

}  // namespace eyesim::app
