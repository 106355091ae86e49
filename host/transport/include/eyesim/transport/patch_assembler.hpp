#pragma once
/// \file
/// Host side of precision mode: re-assembles the BlobPatch fragments of the device stream (docs/protocol.md
/// section 4.7) into whole patches, one in progress per camera (the device sends a patch's fragments back to back).
/// A patch missing a fragment (lost frame, bad CRC) is dropped and counted; no heap, fixed storage.
///
/// \code
///   PatchAssembler patches;
///   parser.parse(bytes, [&](const protocol::DecodedFrame& f) {
///       if (const auto* b = std::get_if<protocol::BlobPatch>(&f.message))
///           if (const AssembledPatch* p = patches.add(*b)) use(*p);   // valid until the camera's next patch
///   });
/// \endcode

#include "eyesim/protocol/messages.hpp"

#include <array>
#include <cstddef>
#include <cstdint>

namespace eyesim::transport {

/// One whole patch: the field's UYVY samples (Cb Y Cr Y per pixel pair) of [origin_x, origin_x + width_px) ×
/// [origin_y, origin_y + height_px), row by row, and the Marker it belongs to (camera, field, blob_index).
struct AssembledPatch {
    std::uint8_t camera_id = 0;       ///< camera 0..2
    std::uint8_t field_parity = 0;    ///< 0 top, 1 bottom field
    std::uint8_t colour_class = 0;    ///< 1..4
    std::uint8_t flags = 0;           ///< protocol::kPatchFlag* (clipped at the field's edge)
    std::uint32_t field_counter = 0;  ///< the field's FieldMarkers field_counter
    std::uint16_t blob_index = 0;     ///< the Marker's position in the field's FieldMarkers (over all parts)
    std::uint16_t origin_x = 0;       ///< first column, field px (even)
    std::uint16_t origin_y = 0;       ///< first field row
    std::uint16_t width_px = 0;       ///< columns (even)
    std::uint16_t height_px = 0;      ///< field rows
    const std::uint8_t* samples = nullptr;  ///< 2 · width_px · height_px bytes, row stride 2 · width_px
    std::size_t bytes = 0;            ///< sample bytes

    /// Luma of patch pixel (column c, row r), 0 ≤ c < width_px, 0 ≤ r < height_px.
    std::uint8_t y(int c, int r) const { return samples[2 * (r * width_px + c) + 1]; }
    /// Cb of the pixel pair holding column c (co-sited with its even pixel).
    std::uint8_t cb(int c, int r) const { return samples[2 * (r * width_px + (c & ~1))]; }
    /// Cr of the pixel pair holding column c.
    std::uint8_t cr(int c, int r) const { return samples[2 * (r * width_px + (c & ~1)) + 2]; }
};

/// Counters since construction.
struct PatchAssemblerStats {
    std::uint64_t fragments = 0;   ///< BlobPatch fragments given to add()
    std::uint64_t completed = 0;   ///< whole patches delivered
    std::uint64_t incomplete = 0;  ///< patches dropped because a fragment was missing or out of order
};

/// Re-assembles BlobPatch fragments; one patch in progress per camera.
class PatchAssembler {
public:
    /// Adds one fragment (as decoded: valid by the protocol's checks). Returns the whole patch when this was its
    /// last fragment, else nullptr. The pointer and its samples stay valid until the next add() for that camera.
    const AssembledPatch* add(const protocol::BlobPatch& fragment) noexcept;

    /// Forgets the patches in progress (a new connection); they count as incomplete.
    void reset() noexcept;

    /// Counters.
    const PatchAssemblerStats& stats() const noexcept { return stats_; }

private:
    struct Slot {
        bool open = false;
        std::uint8_t next_fragment = 0;
        AssembledPatch patch;
        std::array<std::uint8_t, protocol::kPatchMaxBytes> samples{};
    };
    std::array<Slot, protocol::kCameraCount> slots_{};
    PatchAssemblerStats stats_{};
};

}  // namespace eyesim::transport
