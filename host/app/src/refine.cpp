#include "eyesim/app/refine.hpp"

#include "eyesim/rig/bodies.hpp"

#include <cmath>

namespace eyesim::app {

tracking::SphereFitConfig rig_sphere_fit_config() {
    tracking::SphereFitConfig cfg;
    for (int c = 1; c <= 4; ++c) {
        const auto rgb = rig::marker_class_rgb(c);
        cfg.colour[static_cast<size_t>(c)] = tracking::MarkerColour::from_rgb(rgb[0], rgb[1], rgb[2]);
    }
    return cfg;
}

BlobRefiner::BlobRefiner() : config_(rig_sphere_fit_config()), work_(std::make_unique<tracking::SphereFitWorkspace>()) {}

int BlobRefiner::refine(const uint8_t* field, int height, std::vector<fpga::Blob>& blobs) {
    int refined = 0;
    for (fpga::Blob& b : blobs) {
        const tracking::SphereFitResult r = tracking::fit_sphere(field, height, tracking::blob_box(b), config_, *work_);
        if (!r.ok) {
            ++refusals_[static_cast<size_t>(r.refusal)];
            continue;
        }
        if (r.cx_px < 0 || r.cy_px < 0) continue;  // the wire's unsigned Q16 cannot hold it: keep the pipeline's
        b.cx_q16 = static_cast<uint32_t>(std::llround(r.cx_px * 65536.0));
        b.cy_q16 = static_cast<uint32_t>(std::llround(r.cy_px * 65536.0));
        ++refined;
    }
    return refined;
}

nlohmann::json BlobRefiner::refusals_json() const {
    nlohmann::json why = nlohmann::json::object();
    for (int r = 1; r < tracking::kFitRefusalCount; ++r)
        why[tracking::to_string(static_cast<tracking::FitRefusal>(r))] = refusals_[static_cast<size_t>(r)];
    return why;
}

}  // namespace eyesim::app
