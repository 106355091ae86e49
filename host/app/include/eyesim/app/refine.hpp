#pragma once
/// \file
/// Blob refinement (tracking/refine.hpp) applied to a field's blobs with the rig's marker colours, as
/// `eyesim fpga --refine` and `eyesim validate --refine` run it.

#include "eyesim/fpga/blob.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/tracking/marker_prediction.hpp"
#include "eyesim/tracking/refine.hpp"

#include <array>
#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>
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

private:
    tracking::SphereFitConfig config_;
    std::unique_ptr<tracking::SphereFitWorkspace> work_;  // ≈ 156 KiB, allocated once
    std::array<int64_t, tracking::kFitRefusalCount> refusals_{};
    const tracking::MarkerHintSource* hints_ = nullptr;
    int64_t hinted_fits_ = 0;
    std::vector<tracking::BlobBox> boxes_;  // the field's blobs as the fit takes them (reused)
};

}  // namespace eyesim::app
