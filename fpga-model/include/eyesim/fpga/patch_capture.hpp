#pragma once
/// \file
/// Precision mode's patch capture: for every blob of a class enabled in PATCH_ENABLE, the field's UYVY samples of
/// its bounding box grown by a kPatchHaloPx halo (columns and field rows), clipped to the field and widened to whole
/// UYVY pixel pairs, cut out while the field streams through. Line buffers only: the capture keeps the last
/// kPatchLineBuffers lines (32 × 720 px × 16 bits = 46 080 bytes of block RAM) and never the field.
///
/// A blob is known only once it is complete (the line after its last one), and its patch needs kPatchHaloPx lines
/// below it, so a patch is cut when line y_max + 2 arrives (or at the field end); its first line, y_min − 2, must
/// still be in the buffer then. The buffer therefore bounds the patch height: height ≤ kPatchLineBuffers lines
/// (a box ≤ 28 lines tall). Wider than protocol::kPatchMaxWidthPx or taller than that, a blob gets no patch
/// (counted in PatchCaptureStats::too_large; its marker is sent as always).
///
/// Usage, line by line beside the Pipeline (the capture must see each line before the pipeline does, so a blob the
/// pipeline completes on line y finds line y in the buffer):
/// \code
///   pipe.begin_field(n, parity);
///   cap.begin_field(pipe.params(), camera, n, parity);
///   for each line y: cap.push_line(line, y); pipe.push_line(line, y);   // sink: cap.add_blob(blob, position)
///   pipe.end_field(); cap.end_field();                                 // patches leave through the patch sink
/// \endcode
/// No heap, no exceptions; every call bounded (a patch is at most 32 rows of 128 bytes).

#include "eyesim/fpga/blob.hpp"
#include "eyesim/fpga/register_map.hpp"
#include "eyesim/fpga/timing.hpp"
#include "eyesim/protocol/messages.hpp"

#include <array>
#include <cstddef>
#include <cstdint>

namespace eyesim::fpga {

/// Halo around a blob's bounding box, px, in columns and in field rows.
inline constexpr int kPatchHaloPx = 2;
/// Lines the patch capture buffers (= the tallest patch, protocol::kPatchMaxHeightPx).
inline constexpr int kPatchLineBuffers = protocol::kPatchMaxHeightPx;
/// Blobs waiting for the halo lines below them at once; more are dropped (PatchCaptureStats::dropped).
inline constexpr int kMaxPendingPatches = 64;
/// Field rows a patch may reach (PAL field).
inline constexpr int kPatchFieldLines = protocol::kPatchFieldHeightPx;

/// One captured patch: the field's bytes of [origin_x, origin_x + width_px) × [origin_y, origin_y + height_px),
/// row by row (UYVY: Cb Y Cr Y per pixel pair).
struct Patch {
    uint8_t camera = 0;           ///< camera id
    uint8_t parity = 0;           ///< field parity
    uint8_t class_id = 0;         ///< colour class 1..4
    uint8_t flags = 0;            ///< protocol::kPatchFlag* bits (clipped)
    uint32_t field_counter = 0;   ///< field of the blob
    uint16_t blob_index = 0;      ///< position of the blob's marker in the field's FieldMarkers
    uint16_t origin_x = 0;        ///< first column (even)
    uint16_t origin_y = 0;        ///< first field row
    uint16_t width_px = 0;        ///< columns (even)
    uint16_t height_px = 0;       ///< field rows
    std::array<uint8_t, protocol::kPatchMaxBytes> samples{};  ///< the first bytes() are valid

    /// Valid sample bytes: 2 · width_px · height_px.
    size_t bytes() const { return protocol::patch_bytes(width_px, height_px); }
};

/// The rectangle a blob's patch covers (before the size limits), as add_blob computes it.
struct PatchRect {
    int x0 = 0, y0 = 0, x1 = 0, y1 = 0;  ///< inclusive; x0 even, x1 odd
    bool clipped = false;                ///< the halo reached the field's edge
    int width() const { return x1 - x0 + 1; }
    int height() const { return y1 - y0 + 1; }
};

/// The patch rectangle of a bounding box: grown by kPatchHaloPx, clipped to 720 × `field_lines`, x0 rounded down
/// to even and x1 up to odd.
PatchRect patch_rect(int x_min, int y_min, int x_max, int y_max, int field_lines = kPatchFieldLines);

/// Counters since construction.
struct PatchCaptureStats {
    uint64_t captured = 0;   ///< patches delivered
    uint64_t disabled = 0;   ///< blobs of a class without PATCH_ENABLE (no patch wanted)
    uint64_t too_large = 0;  ///< blobs whose patch exceeds 64 px × kPatchLineBuffers lines: no patch
    uint64_t dropped = 0;    ///< patches lost: pending table full, or their lines no longer buffered
};

/// Called once per captured patch (the reference is valid during the call only).
using PatchSink = void (*)(void* context, const Patch& patch);

/// The patch capture of one camera.
class PatchCapture {
public:
    /// A capture for camera `camera` delivering into `sink` (required for patches to leave).
    explicit PatchCapture(uint8_t camera = 0) : camera_(camera) {}

    /// Sets the sink called for each patch.
    void set_sink(PatchSink sink, void* context) {
        sink_ = sink;
        sink_ctx_ = context;
    }

    /// Starts a field with the classes params.patch_enable selects (sampled here: changes apply per field).
    void begin_field(const PipelineParams& params, uint32_t field_counter, uint8_t parity);

    /// Buffers active line y (720 UYVY px, strictly increasing y) and cuts the patches whose last line it is.
    void push_line(const uint8_t* uyvy_line, int y);

    /// A completed blob, `position` its marker's place in the field's FieldMarkers. Cut at once when its last
    /// patch line is already buffered, else when that line arrives. False when no patch will come (class not
    /// enabled, too large, table full).
    bool add_blob(const Blob& blob, uint16_t position);

    /// Ends the field: cuts the pending patches down to the last buffered line (marked clipped).
    void end_field();

    /// Counters.
    const PatchCaptureStats& stats() const { return stats_; }

    /// Patches waiting for lines.
    int pending() const { return n_pending_; }

private:
    struct Pending {
        PatchRect rect;
        uint8_t class_id;
        uint16_t position;
    };
    void cut(const Pending& p, int last_line);

    uint8_t camera_ = 0;
    uint8_t enable_ = 0;
    uint32_t field_ = 0;
    uint8_t parity_ = 0;
    bool in_field_ = false;
    int last_line_ = -1;
    std::array<std::array<uint8_t, 2 * kActivePixelsPerLine>, kPatchLineBuffers> lines_{};  // line y at y % 32
    std::array<int, kPatchLineBuffers> line_y_{};  // which field line each buffer holds (-1: none)
    std::array<Pending, kMaxPendingPatches> pending_{};
    int n_pending_ = 0;
    Patch out_{};
    PatchSink sink_ = nullptr;
    void* sink_ctx_ = nullptr;
    PatchCaptureStats stats_{};
};

}  // namespace eyesim::fpga
