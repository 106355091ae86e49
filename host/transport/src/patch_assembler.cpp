#include "eyesim/transport/patch_assembler.hpp"

#include <cstring>

namespace eyesim::transport {

const AssembledPatch* PatchAssembler::add(const protocol::BlobPatch& b) noexcept {
    ++stats_.fragments;
    if (b.camera_id >= slots_.size()) return nullptr;  // not a decoded fragment
    Slot& s = slots_[b.camera_id];
    AssembledPatch& p = s.patch;
    const bool same = s.open && p.field_counter == b.field_counter && p.blob_index == b.blob_index &&
                      p.origin_x == b.origin_x && p.origin_y == b.origin_y && p.width_px == b.width_px &&
                      p.height_px == b.height_px;
    if (same && s.next_fragment != b.fragment_index) {  // a fragment of the patch in progress was lost
        s.open = false;
        ++stats_.incomplete;
        return nullptr;
    }
    if (!same) {
        if (s.open) ++stats_.incomplete;  // the patch in progress lost a fragment
        s.open = false;
        if (b.fragment_index != 0) {      // the start of this one was lost too
            ++stats_.incomplete;
            return nullptr;
        }
        s.open = true;
        s.next_fragment = 0;
        p.camera_id = b.camera_id;
        p.field_parity = b.field_parity;
        p.colour_class = b.colour_class;
        p.flags = b.flags;
        p.field_counter = b.field_counter;
        p.blob_index = b.blob_index;
        p.origin_x = b.origin_x;
        p.origin_y = b.origin_y;
        p.width_px = b.width_px;
        p.height_px = b.height_px;
        p.bytes = protocol::patch_bytes(b.width_px, b.height_px);
        p.samples = s.samples.data();
    }
    const std::size_t n = b.sample_bytes();
    const std::size_t first = static_cast<std::size_t>(b.fragment_index) * protocol::kPatchFragmentBytes;
    if (first + n > s.samples.size()) {  // a header the decoder would have refused
        s.open = false;
        ++stats_.incomplete;
        return nullptr;
    }
    std::memcpy(s.samples.data() + first, b.samples.data(), n);
    ++s.next_fragment;
    if (s.next_fragment < b.fragment_count) return nullptr;
    s.open = false;
    ++stats_.completed;
    return &p;
}

void PatchAssembler::reset() noexcept {
    for (Slot& s : slots_) {
        if (s.open) ++stats_.incomplete;
        s.open = false;
    }
}

}  // namespace eyesim::transport
