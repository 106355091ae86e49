// Wand calibration, step 1 and 2: the FPGA model's blobs over a recording, the wand's ordered views and the eye's
// still marker images.
#include "eyesim/calibration/wand.hpp"

#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/fpga/register_map.hpp"
#include "eyesim/rig/recording.hpp"

#include <Eigen/Eigenvalues>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <memory>

namespace eyesim::calibration {

const char* to_string(WandReject r) noexcept {
    switch (r) {
        case WandReject::kNone: return "accepted";
        case WandReject::kNoBlob: return "no_blob";
        case WandReject::kMissing: return "missing";
        case WandReject::kExtra: return "extra";
        case WandReject::kFlagged: return "flagged";
        case WandReject::kNotCollinear: return "not_collinear";
        case WandReject::kAmbiguous: return "ambiguous";
        case WandReject::kCount: break;
    }
    return "unknown";
}

RecordingBlobs detect_recording(rig::Recording& rec, int64_t max_fields, int wand_class, int wand_markers,
                                const BlobRefine& refine, const Progress& progress) {
    const int nc = rec.camera_count();
    RecordingBlobs out;
    out.fields = rec.common_field_count();
    if (max_fields >= 0) out.fields = std::min(out.fields, max_fields);
    out.blobs.assign(static_cast<size_t>(nc), std::vector<std::vector<Blob2D>>(static_cast<size_t>(out.fields)));
    for (int c = 0; c < nc; ++c) {
        out.first_field_parity.push_back(rec.cameras()[static_cast<size_t>(c)].first_field_parity);
        out.exposure_us.push_back(rec.cameras()[static_cast<size_t>(c)].exposure_us);
    }
    // One pipeline per camera with the reset register map, as the device powers up (and `eyesim fpga` runs it).
    const fpga::RegisterMap regs;
    std::vector<std::unique_ptr<fpga::Pipeline>> pipes;
    for (int c = 0; c < nc; ++c) {
        fpga::PipelineConfig cfg;
        cfg.camera = static_cast<uint8_t>(c);
        pipes.push_back(std::make_unique<fpga::Pipeline>(regs, cfg));
    }
    std::vector<uint8_t> field(static_cast<size_t>(rig::kFieldBytes));
    std::vector<fpga::Blob> blobs;
    blobs.reserve(fpga::kMaxBlobSlots);
    ProgressInfo info;
    info.phase = ProgressInfo::Phase::kDetect;
    info.total = out.fields;
    info.samples_per_camera.assign(static_cast<size_t>(nc), 0);
    for (int64_t i = 0; i < out.fields; ++i) {
        for (int c = 0; c < nc; ++c) {
            rec.read_field(c, i, field.data());
            const int parity = rec.field_parity(c, i);
            blobs.clear();
            fpga::Pipeline& p = *pipes[static_cast<size_t>(c)];
            p.set_sink([](void* ctx, const fpga::Blob& b) { static_cast<std::vector<fpga::Blob>*>(ctx)->push_back(b); },
                       &blobs);
            const fpga::PipelineStatus s = p.process_field(field.data(), rig::kFieldHeight, static_cast<uint32_t>(i),
                                                           static_cast<uint8_t>(parity));
            if (s != fpga::PipelineStatus::kOk)
                throw CalibrationError(fmt::format("{}: camera {} field {}: pipeline status {}", rec.dir(), c, i,
                                                   static_cast<int>(s)));
            if (refine) refine(field.data(), blobs);
            auto& dst = out.blobs[static_cast<size_t>(c)][static_cast<size_t>(i)];
            dst.reserve(blobs.size());
            int wand_blobs = 0;
            for (const fpga::Blob& b : blobs) {
                // Field (x, y) of parity p is frame (x, 2y + p) (rig/camera.hpp).
                dst.push_back({b.class_id, Eigen::Vector2d(b.cx_px(), 2.0 * b.cy_px() + parity), b.area_px, b.flags});
                wand_blobs += b.class_id == wand_class;
            }
            info.samples_per_camera[static_cast<size_t>(c)] += wand_blobs == wand_markers;
        }
        info.done = i + 1;
        if (progress && ((i + 1) % 25 == 0 || i + 1 == out.fields)) progress(info);
    }
    return out;
}

namespace {

constexpr uint8_t kBadFlags = fpga::kBlobTouchesLeft | fpga::kBlobTouchesRight | fpga::kBlobTouchesTop |
                              fpga::kBlobTouchesBottom | fpga::kBlobIncomplete | fpga::kBlobZeroWeight |
                              fpga::kBlobMerged | fpga::kBlobClippedByRoi;
/// Largest distance of a wand blob from the line through all of them, frame px (noise is ~0.05 px; intrinsics
/// from a checkerboard are good to a few tenths of a pixel at the image edge).
constexpr double kCollinearPx = 1.0;

/// Orders one camera's wand blobs; kNone and `view` filled when accepted.
WandReject order_view(const std::vector<const Blob2D*>& blobs, const rig::WandBody& wand, const rig::CameraModel& cam,
                      WandView& view) {
    const size_t n = wand.markers.size();
    for (const Blob2D* b : blobs)
        if (b->flags & kBadFlags) return WandReject::kFlagged;
    std::vector<Eigen::Vector2d> q;  // undistorted normalised
    for (const Blob2D* b : blobs) {
        const auto u = cam.undistort_to_normalized(b->frame_px);
        if (!u || u->squaredNorm() > cam.max_r2) return WandReject::kFlagged;
        q.push_back(*u);
    }
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (const auto& p : q) mean += p;
    mean /= static_cast<double>(n);
    Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
    for (const auto& p : q) cov += (p - mean) * (p - mean).transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(cov);
    const Eigen::Vector2d dir = es.eigenvectors().col(1);
    const Eigen::Vector2d normal(-dir.y(), dir.x());
    const double f = 0.5 * (cam.fx + cam.fy);
    for (const auto& p : q)
        if (std::fabs((p - mean).dot(normal)) * f > kCollinearPx) return WandReject::kNotCollinear;
    std::vector<size_t> idx(n);
    for (size_t i = 0; i < n; ++i) idx[i] = i;
    std::sort(idx.begin(), idx.end(), [&](size_t a, size_t b) { return (q[a] - mean).dot(dir) < (q[b] - mean).dot(dir); });
    if (n >= 3) {
        // Along a line the image gaps scale with 1 / (depth · depth), so gap_first / gap_last = (model ratio) ×
        // depth_last / depth_first. The ratio's log is ±log(model ratio) plus the log depth ratio; near 0 the
        // ends cannot be told apart (the rod would point along the line of sight, markers nearly overlapping).
        auto gap = [&](size_t a, size_t b) { return (q[idx[b]] - q[idx[a]]).norm(); };
        const double obs = std::log(gap(0, 1) / gap(n - 2, n - 1));
        const double model = std::log((wand.markers[1].distance_mm - wand.markers[0].distance_mm) /
                                      (wand.markers[n - 1].distance_mm - wand.markers[n - 2].distance_mm));
        if (!std::isfinite(obs) || std::fabs(obs) < 0.25 * std::fabs(model)) return WandReject::kAmbiguous;
        if ((obs < 0) != (model < 0)) std::reverse(idx.begin(), idx.end());
    }
    view.resize(n);
    for (size_t i = 0; i < n; ++i) view[i] = blobs[idx[i]]->frame_px;
    return WandReject::kNone;
}

}  // namespace

WandViews find_wand_views(const RecordingBlobs& blobs, const rig::WandBody& wand, const std::vector<rig::CameraModel>& cams) {
    if (!wand.present()) throw CalibrationError("bodies.json has no \"wand\"");
    if (cams.size() != blobs.blobs.size())
        throw CalibrationError(fmt::format("{} cameras of intrinsics for a recording of {} cameras", cams.size(),
                                           blobs.blobs.size()));
    const int cls = wand.markers.front().colour_class;
    for (const auto& m : wand.markers)
        if (m.colour_class != cls) throw CalibrationError("the wand's markers must share one colour class");
    WandViews out;
    out.views.resize(blobs.blobs.size());
    out.rejects.assign(blobs.blobs.size(), {});
    std::vector<const Blob2D*> mine;
    for (size_t c = 0; c < blobs.blobs.size(); ++c) {
        out.views[c].resize(blobs.blobs[c].size());
        for (size_t i = 0; i < blobs.blobs[c].size(); ++i) {
            mine.clear();
            for (const Blob2D& b : blobs.blobs[c][i])
                if (b.class_id == cls) mine.push_back(&b);
            WandReject r = WandReject::kNone;
            if (mine.empty()) r = WandReject::kNoBlob;
            else if (mine.size() < wand.markers.size()) r = WandReject::kMissing;
            else if (mine.size() > wand.markers.size()) r = WandReject::kExtra;
            else r = order_view(mine, wand, cams[c], out.views[c][i]);
            if (r != WandReject::kNone) out.views[c][i].clear();
            ++out.rejects[c][static_cast<size_t>(r)];
        }
    }
    return out;
}

EyeImages eye_images(const RecordingBlobs& blobs, int colour_class) {
    EyeImages out;
    out.px.resize(blobs.blobs.size());
    out.fields.resize(blobs.blobs.size());
    out.area_px.resize(blobs.blobs.size());
    constexpr double kSeedPx = 3.0, kStillPx = 0.3;
    for (size_t c = 0; c < blobs.blobs.size(); ++c) {
        // Seed clusters from every clean blob of the class (marker images are tens of pixels apart), then keep
        // each cluster's members within kStillPx of its median: the wand passing in front of a marker shifts or
        // hides its image in a few fields, and those are left out.
        std::vector<std::vector<Eigen::Vector2d>> members;
        std::vector<std::vector<double>> areas;
        std::vector<Eigen::Vector2d> seed;
        for (const auto& field : blobs.blobs[c])
            for (const Blob2D& b : field) {
                if (b.class_id != colour_class || (b.flags & kBadFlags)) continue;
                size_t k = 0;
                while (k < seed.size() && (seed[k] - b.frame_px).norm() > kSeedPx) ++k;
                if (k == seed.size()) {
                    seed.push_back(b.frame_px);
                    members.emplace_back();
                    areas.emplace_back();
                }
                members[k].push_back(b.frame_px);
                areas[k].push_back(static_cast<double>(b.area_px));
            }
        for (size_t mi = 0; mi < members.size(); ++mi) {
            const auto& m = members[mi];
            if (static_cast<int64_t>(m.size()) * 2 < blobs.fields) continue;
            std::vector<double> xs, ys;
            for (const auto& p : m) {
                xs.push_back(p.x());
                ys.push_back(p.y());
            }
            std::nth_element(xs.begin(), xs.begin() + static_cast<std::ptrdiff_t>(xs.size() / 2), xs.end());
            std::nth_element(ys.begin(), ys.begin() + static_cast<std::ptrdiff_t>(ys.size() / 2), ys.end());
            const Eigen::Vector2d med(xs[xs.size() / 2], ys[ys.size() / 2]);
            Eigen::Vector2d sum = Eigen::Vector2d::Zero();
            double area = 0;
            int64_t n = 0;
            for (size_t k = 0; k < m.size(); ++k)
                if ((m[k] - med).norm() <= kStillPx) {
                    sum += m[k];
                    area += areas[mi][k];
                    ++n;
                }
            if (n * 2 < blobs.fields) continue;
            out.px[c].push_back(sum / static_cast<double>(n));
            out.fields[c].push_back(n);
            out.area_px[c].push_back(area / static_cast<double>(n));
        }
    }
    return out;
}

EyeImages eye_images(rig::Recording& rec, int colour_class, int64_t fields, int64_t max_fields, const BlobRefine& refine) {
    const int nc = rec.camera_count();
    int64_t total = rec.common_field_count();
    if (max_fields >= 0) total = std::min(total, max_fields);
    const int64_t n = std::max<int64_t>(1, std::min(fields, total));
    RecordingBlobs sub;
    sub.fields = total > 0 ? n : 0;
    sub.blobs.assign(static_cast<size_t>(nc), std::vector<std::vector<Blob2D>>(static_cast<size_t>(sub.fields)));
    const fpga::RegisterMap regs;
    std::vector<uint8_t> field(static_cast<size_t>(rig::kFieldBytes));
    std::vector<fpga::Blob> blobs, mine;
    for (int c = 0; c < nc; ++c) {
        fpga::PipelineConfig cfg;
        cfg.camera = static_cast<uint8_t>(c);
        fpga::Pipeline p(regs, cfg);
        p.set_sink([](void* ctx, const fpga::Blob& b) { static_cast<std::vector<fpga::Blob>*>(ctx)->push_back(b); }, &blobs);
        for (int64_t k = 0; k < sub.fields; ++k) {
            // Pairs of consecutive fields: both parities alike (each samples other frame rows, and their centroid
            // biases differ).
            const int64_t pairs = std::max<int64_t>(1, n / 2);
            const int64_t i = std::min(total - 1, (k / 2) * total / pairs + (k % 2));
            rec.read_field(c, i, field.data());
            const int parity = rec.field_parity(c, i);
            blobs.clear();
            if (p.process_field(field.data(), rig::kFieldHeight, static_cast<uint32_t>(i), static_cast<uint8_t>(parity)) !=
                fpga::PipelineStatus::kOk)
                throw CalibrationError(fmt::format("{}: camera {} field {}: the pipeline refused it", rec.dir(), c, i));
            mine.clear();
            for (const fpga::Blob& b : blobs)
                if (b.class_id == colour_class) mine.push_back(b);
            if (refine) refine(field.data(), mine);
            for (const fpga::Blob& b : mine)
                sub.blobs[static_cast<size_t>(c)][static_cast<size_t>(k)].push_back(
                    {b.class_id, Eigen::Vector2d(b.cx_px(), 2.0 * b.cy_px() + parity), b.area_px, b.flags});
        }
    }
    return eye_images(sub, colour_class);
}

}  // namespace eyesim::calibration
