#include "eyesim/frame/precision.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace eyesim::frame {

namespace proto = eyesim::protocol;

std::uint64_t PrecisionStats::refused_total() const {
    std::uint64_t n = 0;
    for (std::uint64_t r : refused) n += r;
    return n;
}

bool patch_expected(const proto::Marker& m, std::uint8_t class_mask) {
    if (m.colour_class < 1 || m.colour_class > 4 || !((class_mask >> (m.colour_class - 1)) & 1)) return false;
    const int w = proto::kPatchFieldWidthPx, h = proto::kPatchFieldHeightPx;
    const int x0 = std::max(0, int(m.bbox_x0) - kPatchHaloPx), x1 = std::min(w - 1, int(m.bbox_x1) + kPatchHaloPx);
    const int y0 = std::max(0, int(m.bbox_y0) - kPatchHaloPx), y1 = std::min(h - 1, int(m.bbox_y1) + kPatchHaloPx);
    const int cols = (x1 | 1) - (x0 & ~1) + 1;  // whole UYVY pairs
    return cols <= int(proto::kPatchMaxWidthPx) && y1 - y0 + 1 <= int(proto::kPatchMaxHeightPx);
}

tracking::SphereFitConfig patch_fit_config(tracking::SphereFitConfig base) {
    base.margin_px = kPatchHaloPx;
    base.margin_lines = kPatchHaloPx;
    return base;
}

PatchRefiner::PatchRefiner(const tracking::SphereFitConfig& config, std::uint8_t class_mask, Emit emit)
    : config_(config),
      mask_(class_mask),
      emit_(std::move(emit)),
      assembler_(std::make_unique<transport::PatchAssembler>()),
      work_(std::make_unique<tracking::SphereFitWorkspace>()),
      field_(std::size_t(2) * proto::kPatchFieldWidthPx * proto::kPatchFieldHeightPx) {}

PrecisionStats PatchRefiner::stats() const {
    PrecisionStats s = stats_;
    s.incomplete = assembler_->stats().incomplete;
    return s;
}

void PatchRefiner::release_front(Camera& cam) {
    Held& h = cam.held[std::size_t(cam.head)];
    for (int k = 0; k < h.part.marker_count; ++k) stats_.missing_patch += (h.waiting >> k) & 1;
    emit_(h.part);
    cam.head = (cam.head + 1) % kMaxHeld;
    --cam.count;
}

void PatchRefiner::release_ready(Camera& cam) {
    while (cam.count > 0 && cam.held[std::size_t(cam.head)].waiting == 0) release_front(cam);
}

void PatchRefiner::on_markers(const proto::FieldMarkers& part) {
    if (part.camera_id >= cams_.size()) {  // not a camera the device has: nothing to wait for
        emit_(part);
        return;
    }
    Camera& cam = cams_[part.camera_id];
    if (cam.have_field && part.field_counter != cam.field) {
        // A new field: the previous one's patches would have come before it (after its markers, or per blob).
        while (cam.count > 0) release_front(cam);
    }
    if (!cam.have_field || part.field_counter != cam.field || part.part_index == 0) cam.next_blob = 0;
    cam.have_field = true;
    cam.field = part.field_counter;
    const std::uint32_t first = cam.next_blob;
    cam.next_blob += part.marker_count;
    std::uint16_t waiting = 0;
    for (int k = 0; k < part.marker_count; ++k)
        if (patch_expected(part.markers[std::size_t(k)], mask_)) waiting |= std::uint16_t(1u << k);
    if (waiting == 0 && cam.count == 0) {
        emit_(part);
        return;
    }
    if (cam.count == kMaxHeld) release_front(cam);
    Held& h = cam.held[std::size_t((cam.head + cam.count) % kMaxHeld)];
    h.part = part;
    h.first_blob = first;
    h.waiting = waiting;
    ++cam.count;
}

void PatchRefiner::on_patch(const proto::BlobPatch& fragment) {
    const transport::AssembledPatch* p = assembler_->add(fragment);
    if (p == nullptr) return;
    ++stats_.patches;
    if (p->camera_id >= cams_.size()) {
        ++stats_.unmatched;
        return;
    }
    Camera& cam = cams_[p->camera_id];
    for (int i = 0; i < cam.count; ++i) {
        Held& h = cam.held[std::size_t((cam.head + i) % kMaxHeld)];
        if (h.part.field_counter != p->field_counter || p->blob_index < h.first_blob ||
            p->blob_index >= h.first_blob + h.part.marker_count)
            continue;
        const int k = int(p->blob_index - h.first_blob);
        if (!((h.waiting >> k) & 1)) break;  // a second patch for the marker, or one not asked for
        h.waiting = std::uint16_t(h.waiting & ~(1u << k));
        refine(cam, h.part.markers[std::size_t(k)], *p);
        release_ready(cam);
        return;
    }
    ++stats_.unmatched;
}

void PatchRefiner::refine(const Camera& cam, proto::Marker& m, const transport::AssembledPatch& p) {
    // The patch at its field coordinates (the fit indexes the field); its bounds were checked by the codec.
    const std::size_t stride = std::size_t(2) * proto::kPatchFieldWidthPx;
    const std::size_t row_bytes = std::size_t(2) * p.width_px;
    for (int r = 0; r < p.height_px; ++r)
        std::memcpy(field_.data() + std::size_t(p.origin_y + r) * stride + std::size_t(2) * p.origin_x,
                    p.samples + std::size_t(r) * row_bytes, row_bytes);
    tracking::BlobBox box;
    box.class_id = m.colour_class;
    box.parity = p.field_parity & 1;
    box.x_min = m.bbox_x0;
    box.x_max = m.bbox_x1;
    box.y_min = m.bbox_y0;
    box.y_max = m.bbox_y1;
    box.cx_px = double(m.x_q16) / 65536.0;
    box.cy_px = double(m.y_q16) / 65536.0;
    // Another class's marker of the field overlapping or touching its box (tracking::BlobBox::foreign_overlap,
    // foreign_touch), among those held here: a neighbour emitted later, or already released, is not seen.
    for (int i = 0; i < cam.count && !box.foreign_overlap; ++i) {
        const Held& h = cam.held[std::size_t((cam.head + i) % kMaxHeld)];
        if (h.part.field_counter != p.field_counter) continue;
        for (int k = 0; k < h.part.marker_count; ++k) {
            const proto::Marker& o = h.part.markers[std::size_t(k)];
            tracking::BlobBox ob;
            ob.class_id = o.colour_class;
            ob.x_min = o.bbox_x0;
            ob.x_max = o.bbox_x1;
            ob.y_min = o.bbox_y0;
            ob.y_max = o.bbox_y1;
            box.foreign_touch = box.foreign_touch || tracking::foreign_touch(ob, box);
            if (tracking::foreign_overlap(ob, box)) {
                box.foreign_overlap = true;
                break;
            }
        }
    }
    // The fit reads only the box and its margin: it must lie inside the patch.
    const int fx0 = std::max(1, box.x_min - config_.margin_px);
    const int fx1 = std::min(int(proto::kPatchFieldWidthPx) - 2, box.x_max + config_.margin_px);
    const int fy0 = std::max(0, box.y_min - config_.margin_lines);
    const int fy1 = std::min(int(proto::kPatchFieldHeightPx) - 1, box.y_max + config_.margin_lines);
    const bool inside = fx0 >= int(p.origin_x) && fx1 < int(p.origin_x + p.width_px) && fy0 >= int(p.origin_y) &&
                        fy1 < int(p.origin_y + p.height_px);
    if (!inside) {
        ++stats_.refused[std::size_t(tracking::FitRefusal::kInput)];
        return;
    }
    bool hinted = false;
    const tracking::SphereFitResult r = tracking::MarkerHintSource::fit(
        hints_, field_.data(), int(proto::kPatchFieldHeightPx), box, p.camera_id, config_, *work_, hinted);
    stats_.hinted_fits += hinted;
    if (!r.ok || !(r.cx_px >= 0.0) || !(r.cy_px >= 0.0)) {  // the wire's unsigned Q16 cannot hold a negative
        ++stats_.refused[std::size_t(r.ok ? tracking::FitRefusal::kImplausible : r.refusal)];
        return;
    }
    m.x_q16 = std::uint32_t(std::llround(r.cx_px * 65536.0));
    m.y_q16 = std::uint32_t(std::llround(r.cy_px * 65536.0));
    ++stats_.refined;
}

void PatchRefiner::flush() {
    for (Camera& cam : cams_) {
        while (cam.count > 0) release_front(cam);
        cam.have_field = false;
    }
}

}  // namespace eyesim::frame
