#include "eyesim/fpga/patch_capture.hpp"

#include <cstring>

namespace eyesim::fpga {

PatchRect patch_rect(int x_min, int y_min, int x_max, int y_max, int field_lines) {
    constexpr int kWidth = static_cast<int>(kActivePixelsPerLine);
    PatchRect r;
    r.x0 = x_min - kPatchHaloPx;
    r.x1 = x_max + kPatchHaloPx;
    r.y0 = y_min - kPatchHaloPx;
    r.y1 = y_max + kPatchHaloPx;
    r.clipped = r.x0 < 0 || r.y0 < 0 || r.x1 > kWidth - 1 || r.y1 > field_lines - 1;
    r.x0 = r.x0 < 0 ? 0 : r.x0 & ~1;               // whole UYVY pairs: start on an even column ...
    r.x1 = r.x1 > kWidth - 1 ? kWidth - 1 : r.x1 | 1;  // ... end on an odd one (719 is odd)
    r.y0 = r.y0 < 0 ? 0 : r.y0;
    r.y1 = r.y1 > field_lines - 1 ? field_lines - 1 : r.y1;
    return r;
}

void PatchCapture::begin_field(const PipelineParams& params, uint32_t field_counter, uint8_t parity) {
    enable_ = params.patch_enable;
    field_ = field_counter;
    parity_ = parity;
    in_field_ = true;
    last_line_ = -1;
    n_pending_ = 0;  // end_field cut them all; a field begun without it loses them (counted there)
    line_y_.fill(-1);
}

void PatchCapture::push_line(const uint8_t* uyvy_line, int y) {
    if (!in_field_ || uyvy_line == nullptr || y <= last_line_ || y < 0) return;
    const int slot = y % kPatchLineBuffers;
    std::memcpy(lines_[static_cast<size_t>(slot)].data(), uyvy_line, lines_[0].size());
    line_y_[static_cast<size_t>(slot)] = y;
    last_line_ = y;
    // Cut every pending patch whose last line this is (or earlier, when lines were skipped); keep the rest.
    int kept = 0;
    for (int i = 0; i < n_pending_; ++i) {
        const Pending& p = pending_[static_cast<size_t>(i)];
        if (p.rect.y1 <= y) cut(p, p.rect.y1);
        else pending_[static_cast<size_t>(kept++)] = p;
    }
    n_pending_ = kept;
}

bool PatchCapture::add_blob(const Blob& blob, uint16_t position) {
    if (!in_field_ || blob.class_id < 1 || blob.class_id > kNumClasses || !(enable_ & (1u << (blob.class_id - 1)))) {
        ++stats_.disabled;
        return false;
    }
    const PatchRect r = patch_rect(blob.x_min, blob.y_min, blob.x_max, blob.y_max);
    if (r.width() > protocol::kPatchMaxWidthPx || r.height() > kPatchLineBuffers) {
        ++stats_.too_large;
        return false;
    }
    const Pending p{r, blob.class_id, position};
    if (r.y1 <= last_line_) {  // its lines are all in (a blob completed at the field's end)
        cut(p, r.y1);
        return true;
    }
    if (n_pending_ >= kMaxPendingPatches) {
        ++stats_.dropped;
        return false;
    }
    pending_[static_cast<size_t>(n_pending_++)] = p;
    return true;
}

void PatchCapture::end_field() {
    if (!in_field_) return;
    for (int i = 0; i < n_pending_; ++i) {
        Pending p = pending_[static_cast<size_t>(i)];
        if (last_line_ < p.rect.y0) {  // the field ended before the patch began: nothing to send
            ++stats_.dropped;
            continue;
        }
        p.rect.clipped = true;  // the field ended early, inside the halo
        cut(p, last_line_);
    }
    n_pending_ = 0;
    in_field_ = false;
}

void PatchCapture::cut(const Pending& p, int last_line) {
    const int y1 = last_line < p.rect.y1 ? last_line : p.rect.y1;
    Patch& o = out_;
    o.camera = camera_;
    o.parity = parity_;
    o.class_id = p.class_id;
    o.flags = p.rect.clipped || y1 < p.rect.y1 ? protocol::kPatchFlagClipped : 0;
    o.field_counter = field_;
    o.blob_index = p.position;
    o.origin_x = static_cast<uint16_t>(p.rect.x0);
    o.origin_y = static_cast<uint16_t>(p.rect.y0);
    o.width_px = static_cast<uint16_t>(p.rect.width());
    o.height_px = static_cast<uint16_t>(y1 - p.rect.y0 + 1);
    const size_t row_bytes = 2u * o.width_px;
    for (int y = p.rect.y0; y <= y1; ++y) {
        const size_t slot = static_cast<size_t>(y % kPatchLineBuffers);
        if (line_y_[slot] != y) {  // a skipped line, or one already overwritten: the patch is not whole
            ++stats_.dropped;
            return;
        }
        std::memcpy(o.samples.data() + static_cast<size_t>(y - p.rect.y0) * row_bytes,
                    lines_[slot].data() + 2u * static_cast<size_t>(p.rect.x0), row_bytes);
    }
    ++stats_.captured;
    if (sink_ != nullptr) sink_(sink_ctx_, o);
}

}  // namespace eyesim::fpga
