#pragma once
/// \file
/// Precision mode on the host: each camera field's FieldMarkers parts are held until the BlobPatch of every marker
/// that should have one has arrived (docs/protocol.md section 4.7), then each such marker's centroid is replaced
/// by the sphere fit on its patch (tracking::fit_sphere) where the fit accepts; where it refuses, the pipeline's
/// centroid stands. A part whose patches do not all come is released when the camera's next field begins (or at
/// the end of the stream), its missing patches counted.
///
/// The fit reads the patch at its field coordinates: each patch is copied into one field-sized buffer allocated
/// at construction (the fit's margin is the patch's 2-px halo, so it reads nothing outside the patch). No heap in
/// the per-field path.

#include "eyesim/protocol/messages.hpp"
#include "eyesim/tracking/marker_prediction.hpp"
#include "eyesim/tracking/refine.hpp"
#include "eyesim/transport/patch_assembler.hpp"

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

namespace eyesim::frame {

/// Precision mode counters.
struct PrecisionStats {
    std::uint64_t patches = 0;        ///< whole patches received
    std::uint64_t refined = 0;        ///< markers whose centroid is the fit on their patch
    std::array<std::uint64_t, tracking::kFitRefusalCount> refused{};  ///< fits refused, by FitRefusal (0 unused)
    std::uint64_t missing_patch = 0;  ///< markers that should have had a patch and whose patch never came
    std::uint64_t unmatched = 0;      ///< patches whose marker was not held (already released, or never seen)
    std::uint64_t incomplete = 0;     ///< patches lost in transit (a fragment missing)
    std::uint64_t hinted_fits = 0;     ///< fits made with the instrument's shaft left out (a pose was at hand)
    /// Sum of refused[].
    std::uint64_t refused_total() const;
};

/// The patch capture's halo (columns and field lines beside the box): the fit's margin in precision mode.
inline constexpr int kPatchHaloPx = 2;

/// Whether the device sends a patch for `m` with PATCH_ENABLE `class_mask`: an enabled class and a box whose
/// patch (box + halo, clipped to the field, widened to whole UYVY pairs) fits protocol::kPatchMax{Width,Height}Px.
bool patch_expected(const protocol::Marker& m, std::uint8_t class_mask);

/// The fit configuration for patches: `base` with the margin set to the patch's halo.
tracking::SphereFitConfig patch_fit_config(tracking::SphereFitConfig base);

/// Holds FieldMarkers parts until their patches are in, refines their markers, and hands them on in order.
class PatchRefiner {
public:
    /// Called with every part, refined, in the order the parts arrived per camera.
    using Emit = std::function<void(const protocol::FieldMarkers&)>;

    /// `config`: the fit (its margin must be at most the patch halo: patch_fit_config); `class_mask`: the
    /// PATCH_ENABLE bits the device was given (bit c-1: class c).
    PatchRefiner(const tracking::SphereFitConfig& config, std::uint8_t class_mask, Emit emit);

    /// A FieldMarkers part: emitted now when none of its markers waits for a patch and nothing is held before it.
    void on_markers(const protocol::FieldMarkers& part);
    /// A BlobPatch fragment: when it completes a patch, its marker is refined; parts whose patches are all in
    /// are emitted.
    void on_patch(const protocol::BlobPatch& fragment);
    /// Emits every part still held (end of stream, link dropped); their missing patches are counted.
    void flush();

    /// Where the instruments are (nullptr: unknown): a marker the source knows as an instrument's is fitted with
    /// its shaft left out (tracking::MarkerHint). The source must outlive the refiner's use of it.
    void set_hints(const tracking::MarkerHintSource* source) { hints_ = source; }

    /// Counters.
    PrecisionStats stats() const;
    /// The class mask.
    std::uint8_t class_mask() const { return mask_; }

private:
    struct Held {
        protocol::FieldMarkers part;
        std::uint32_t first_blob = 0;  // blob_index of part.markers[0]
        std::uint16_t waiting = 0;     // bit k: markers[k] waits for its patch
    };
    static constexpr int kMaxHeld = 16;  // parts held per camera (a field of up to 224 markers)
    struct Camera {
        std::array<Held, kMaxHeld> held{};
        int head = 0, count = 0;
        bool have_field = false;
        std::uint32_t field = 0;        // field_counter of the newest part
        std::uint32_t next_blob = 0;    // blob_index of the next part's first marker
    };
    void release_ready(Camera& cam);
    void release_front(Camera& cam);
    void refine(const Camera& cam, protocol::Marker& m, const transport::AssembledPatch& p);

    tracking::SphereFitConfig config_;
    std::uint8_t mask_;
    Emit emit_;
    std::array<Camera, protocol::kCameraCount> cams_{};
    std::unique_ptr<transport::PatchAssembler> assembler_;
    std::unique_ptr<tracking::SphereFitWorkspace> work_;
    std::vector<std::uint8_t> field_;  // one UYVY field; only the current patch's area is meaningful
    PrecisionStats stats_;
    const tracking::MarkerHintSource* hints_ = nullptr;
};

}  // namespace eyesim::frame
