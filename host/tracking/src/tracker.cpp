#include "eyesim/tracking/tracker.hpp"

#include "eyesim/tracking/marker_prediction.hpp"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace eyesim::tracking {

namespace {

constexpr double kNever = -1e300;  // a time before any field

double steady_us() {
    return std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

}  // namespace

namespace {

/// Classes whose every body marker is on the eye get a spherical-shell region (see ClassRegion); the occlusion
/// test gets the bodies' marker radius.
TrackerConfig with_eye_regions(TrackerConfig cfg) {
    const EyeModel& eye = cfg.bodies.eye;
    if (cfg.correspondence.marker_radius_mm <= 0.0) cfg.correspondence.marker_radius_mm = cfg.bodies.marker_radius_mm;
    for (int cls = 1; cls <= 4; ++cls) {
        bool on_instrument = false;
        for (int b = 0; b < cfg.bodies.instrument_count; ++b)
            for (int k = 0; k < cfg.bodies.instruments[std::size_t(b)].marker_count; ++k)
                if (cfg.bodies.instruments[std::size_t(b)].markers[std::size_t(k)].colour_class == cls)
                    on_instrument = true;
        double rmin = 1e300, rmax = -1e300;
        for (int k = 0; k < eye.marker_count; ++k)
            if (eye.markers[std::size_t(k)].colour_class == cls) {
                const double r = eye.markers[std::size_t(k)].pos_body_mm.norm();
                rmin = std::min(rmin, r);
                rmax = std::max(rmax, r);
            }
        ClassRegion& reg = cfg.correspondence.region[std::size_t(cls)];
        if (on_instrument || rmax < rmin || reg.enabled) continue;
        reg.enabled = true;
        reg.centre_rig_mm = eye.centre_rig_mm;
        reg.radius_mm = 0.5 * (rmin + rmax);
        reg.tolerance_mm = 0.5 * (rmax - rmin) + cfg.pose.eye_radius_tol_mm;
    }
    return cfg;
}

}  // namespace

Tracker::Tracker(TrackerConfig config)
    : config_(with_eye_regions(std::move(config))),
      cameras_(config_.cameras),
      correspondence_(cameras_, config_.correspondence),
      sync_(int(config_.cameras.size()), config_.sync) {
    if (cameras_.size() < 2 || cameras_.size() > std::size_t(kMaxCameras))
        throw std::invalid_argument("tracker: cameras: need 2.." + std::to_string(kMaxCameras) + ", got " +
                                    std::to_string(cameras_.size()));
    for (std::size_t i = 0; i < cameras_.size(); ++i)
        if (!cameras_[i].valid())
            throw std::invalid_argument("tracker: camera " + std::to_string(i) +
                                        ": invalid intrinsics, distortion or rotation");
    if (config_.timing.size() != cameras_.size())
        config_.timing.resize(cameras_.size());  // PAL defaults
    if (config_.sync.reference_camera < 0 || config_.sync.reference_camera >= int(cameras_.size()))
        throw std::invalid_argument("tracker: sync.reference_camera: " +
                                    std::to_string(config_.sync.reference_camera) + " is not a camera");
    if (!(config_.centroid_sigma_px > 0.0) || !std::isfinite(config_.centroid_sigma_px))
        throw std::invalid_argument("tracker: centroid_sigma_px: must be positive");
    if (!(config_.async.report_delay_us >= 0.0 && config_.async.report_delay_us <= AsyncOptions::kMaxReportDelayUs))
        throw std::invalid_argument("tracker: async.report_delay_us: must be 0.." +
                                    std::to_string(int(AsyncOptions::kMaxReportDelayUs)));
    // correspondence_ holds a span over cameras_, which is never resized after construction.
    const AsyncOptions& ao = config_.async;
    // Constant-velocity models steadiest first (motion_model_ladder); the acceleration model after them.
    double ang_psd[BodyFilter::kMaxModels], lin_psd[BodyFilter::kMaxModels];
    const int nm = motion_model_ladder(ao.motion_models, ao.steady_ang_accel_psd_rad2_s3, ao.ang_accel_psd_rad2_s3, ang_psd);
    motion_model_ladder(ao.motion_models, ao.steady_accel_psd_mm2_s3, ao.accel_psd_mm2_s3, lin_psd);
    // The acceleration model last, its white acceleration the steady model's (the jerk carries the rest).
    const bool ca = ao.acceleration_model;
    if (ca) {
        ang_psd[nm] = ao.steady_ang_accel_psd_rad2_s3;
        lin_psd[nm] = ao.steady_accel_psd_mm2_s3;
    }
    configure_eye_filter(filters_[0], ao, config_.bodies.eye.centre_rig_mm);
    const int n_models = ca ? nm + 1 : nm;
    for (int b = 0; b < config_.bodies.instrument_count; ++b) {
        const InstrumentModel& m = config_.bodies.instruments[std::size_t(b)];
        BodyFilter& f = filters_[std::size_t(1 + b)];
        f.configure_rigid(m.markers_on_axis() ? Eigen::Vector3d(m.axis_body.normalized()) : Eigen::Vector3d::Zero(),
                          ang_psd, lin_psd, n_models, ao.model_switch_per_s);
        if (ca)
            f.set_jerk(nm, ao.ang_jerk_psd_rad2_s5, ao.jerk_psd_mm2_s5, ao.ang_accel0_sigma_rad_s2, ao.accel0_sigma_mm_s2,
                       ao.accel_correlation_s);
    }
    // Allocated once here (≈ 120 KB a body), never in the fusion.
    if (config_.sync.mode == SyncMode::Async && ao.time_order_parts) {
        replay_ = std::make_unique<ReplayHistory[]>(kBodies);
        // Each snapshot configured as its body's filter (BodyFilter::assign_state copies only the state).
        for (int b = 0; b < kBodies; ++b)
            for (ReplayEpoch& e : replay_[std::size_t(b)].pool) e.before = filters_[std::size_t(b)];
    }
}

void Tracker::restart() {
    for (const FieldAssembler& a : assemblers_) rejected_before_restart_ += a.rejected_images();
    assemblers_.fill(FieldAssembler{});
    sync_ = FrameSync(int(cameras_.size()), config_.sync);
    last_eye_ = EyePose{};
    last_instruments_.fill(InstrumentPose{});
    unmeasured_frames_ = make_unmeasured();
    one_view_mask_ = 0;
    for (BodyFilter& f : filters_) f.reset();
    missed_us_.fill(kNever);
    for (auto& s : supported_us_) s.fill(kNever);
    queue_count_ = 0;
    acquire_measured_.fill(false);
    acquire_due_ = false;
    open_queued_.fill(0);
    have_done_.fill(false);
    done_period_us_.fill(0.0);
    ref_reported_ = false;
    pending_count_ = 0;
    pending_reported_any_ = false;
    flush_pending_ = false;
}

int Tracker::rejected_images() const {
    int n = rejected_non_finite_ + rejected_before_restart_;
    for (const FieldAssembler& a : assemblers_) n += a.rejected_images();
    return n;
}

void Tracker::push(const protocol::FieldMarkers& msg, double received_host_us) {
    if (msg.camera_id >= cameras_.size()) return;
    FieldAssembler& as = assemblers_[msg.camera_id];
    const int done = as.push(msg, received_host_us, config_.timing[msg.camera_id]);
    const std::size_t c = msg.camera_id;
    for (int i = 0; i < done; ++i) {
        const CameraField& f = as.completed(i);
        sync_.add(f);
        if (config_.sync.mode != SyncMode::Async) continue;
        // Parts already fused while the field was open are not fused again.
        const bool was_open = open_queued_[c] > 0 && open_counter_[c] == f.field_counter;
        enqueue(f, was_open ? std::min(open_queued_[c], f.count) : 0, true);
        // One time for all parts of a field: the one its first parts were fused at (predicted from the camera's
        // last field, within microseconds of the field's own), so that the closing part is not an older observation.
        if (was_open) queue_[std::size_t((queue_head_ + queue_count_ - 1) % kQueue)].fuse_us = open_sample_us_[c];
        if (open_counter_[c] == f.field_counter) open_queued_[c] = 0;
        if (!std::isfinite(f.field_end_device_us) || !(f.field_end_device_us > 0.0)) continue;
        if (have_done_[c]) {
            const std::uint32_t gap = f.field_counter - done_counter_[c];
            const double p = (f.field_end_device_us - done_end_us_[c]) / double(gap);
            const double nominal = config_.sync.field_period_us;
            if (gap >= 1 && gap <= 4 && p > 0.9 * nominal && p < 1.1 * nominal) done_period_us_[c] = p;
        }
        done_end_us_[c] = f.field_end_device_us;
        done_counter_[c] = f.field_counter;
        have_done_[c] = true;
    }
    // Low-latency mode: the open field's new images are fused now, at the field's exposure time predicted from
    // the camera's last complete field (its end and period; the part itself carries no field time).
    if (config_.sync.mode != SyncMode::Async || !as.open() || !(msg.flags & protocol::kFieldFlagLowLatency)) return;
    const CameraField& b = as.building();
    if (open_counter_[c] != b.field_counter) {
        open_counter_[c] = b.field_counter;
        open_queued_[c] = 0;
    }
    if (b.count <= open_queued_[c] || !have_done_[c]) return;
    const std::uint32_t gap = b.field_counter - done_counter_[c];
    if (gap < 1 || gap > 4) return;
    const double period = done_period_us_[c] > 0.0 ? done_period_us_[c] : config_.sync.field_period_us;
    enqueue(b, open_queued_[c], false);
    CameraField& q = queue_[std::size_t((queue_head_ + queue_count_ - 1) % kQueue)].field;
    q.field_end_device_us = done_end_us_[c] + double(gap) * period;
    q.sample_device_us = q.field_end_device_us - config_.timing[c].end_to_sample_us[std::size_t(b.parity & 1)];
    q.received_host_us = received_host_us;
    queue_[std::size_t((queue_head_ + queue_count_ - 1) % kQueue)].fuse_us = q.sample_device_us;
    open_sample_us_[c] = q.sample_device_us;
    open_queued_[c] = b.count;
}

void Tracker::enqueue(const CameraField& f, int first, bool last) {
    if (queue_count_ == kQueue) {  // consumer too slow: the oldest entry is dropped
        queue_head_ = (queue_head_ + 1) % kQueue;
        --queue_count_;
    }
    QueuedField& q = queue_[std::size_t((queue_head_ + queue_count_++) % kQueue)];
    q.field = f;
    q.first = first;
    q.last = last;
    q.fuse_us = f.sample_device_us;
}

void Tracker::push(const protocol::PedalState& pedal, double /*received_host_us*/) {
    const int axis = config_.opening_pedal_axis;
    if (axis >= 0 && axis < int(protocol::kPedalAxisCount)) opening_ = pedal.axes[std::size_t(axis)] / 65535.0;
}

bool Tracker::pop(TrackingFrame& out, double now_host_us) {
    if (config_.sync.mode == SyncMode::Async) return pop_async(out, now_host_us);
    double T = 0, end_dev = 0, recv_host = 0;
    std::uint32_t ref = 0;
    if (!sync_.pop(T, ref, out.cameras, aligned_, end_dev, recv_host)) return false;
    const double t0 = steady_us();
    std::array<bool, kMaxCameras> present{};
    for (int c = 0; c < int(cameras_.size()); ++c)
        present[std::size_t(c)] = out.cameras[std::size_t(c)].state != CameraSyncState::Missing;
    out.images_dropped_sync = 0;
    for (int c = 0; c < int(cameras_.size()); ++c) out.images_dropped_sync += out.cameras[std::size_t(c)].dropped_images;
    track_images(std::span<const CameraField>(aligned_.data(), cameras_.size()),
                 std::span<const bool>(present.data(), cameras_.size()), out);
    const double compute = steady_us() - t0;
    out.reference_field = ref;
    out.time_device_us = T;
    out.timing.sample_host_us = T - offset_us_;
    out.timing.field_end_host_us = end_dev - offset_us_;
    out.timing.received_host_us = recv_host;
    out.timing.compute_us = compute;
    out.timing.poses_ready_host_us = now_host_us + compute;
    return true;
}

void Tracker::track_images(std::span<const CameraField> images, std::span<const bool> present, TrackingFrame& out) {
    const int ncam = int(std::min({images.size(), present.size(), cameras_.size()}));
    out.index = frames_++;
    out.flags = kFrameOk;
    out.camera_count = int(cameras_.size());
    out.cameras_used = 0;
    out.images_in = 0;
    corrected_views_.fill(0);
    // Undistort every image (Newton to tolerance); refuse non-finite ones.
    for (int c = 0; c < int(cameras_.size()); ++c) {
        CameraObservations& v = views_[std::size_t(c)];
        v.present = c < ncam && present[std::size_t(c)];
        v.count = 0;
        if (!v.present) continue;
        ++out.cameras_used;
        const CameraField& f = images[std::size_t(c)];
        view_parity_[std::size_t(c)] = f.parity & 1;
        view_parity_weight_[std::size_t(c)] = f.parity_weight;
        for (int i = 0; i < f.count && v.count < kMaxMarkersPerCamera; ++i) {
            const FieldImage& im = f.images[std::size_t(i)];
            if (!im.frame_px.allFinite()) {
                out.flags |= kFrameNonFinite;
                ++rejected_non_finite_;
                continue;
            }
            const Undistorted u = undistort_pixel(cameras_[std::size_t(c)], im.frame_px, config_.undistort);
            if (!u.converged) continue;  // outside the invertible part of the lens model
            ImagePoint& p = v.points[std::size_t(v.count++)];
            p.colour_class = im.colour_class;
            p.flags = im.flags;
            p.px = im.frame_px;
            p.xn = u.xn;
            p.sigma_px = config_.centroid_sigma_px;
            p.area_px = im.area_px;
        }
        out.images_in += v.count;
    }
    if (out.cameras_used < int(cameras_.size())) out.flags |= kFrameTwoView;
    if (out.cameras_used < 2) out.flags |= kFrameTooFewCameras;
    correspondence_.solve(std::span<const CameraObservations>(views_.data(), cameras_.size()), out.markers);
    // Poses: the previous frame's are the hold values; the pedal sets the opening.
    out.instrument_count = config_.bodies.instrument_count;
    auto fit = [&] {
        for (int b = 0; b < out.instrument_count; ++b) out.instruments[std::size_t(b)].opening = opening_;
        fit_poses(config_.bodies, out.markers, config_.pose, last_eye_,
                  std::span<const InstrumentPose>(last_instruments_.data(), std::size_t(out.instrument_count)), out.eye,
                  std::span<InstrumentPose>(out.instruments.data(), std::size_t(out.instrument_count)), out.assignment);
    };
    fit();
    // Both corrections from the first fit's poses, then one refit (same history) with every corrected marker.
    bool corrected = config_.eye_occlusion_correction && correct_eye_occlusion(out);
    corrected = (config_.shaft_occlusion_correction && correct_shaft_occlusion(out)) || corrected;
    if (corrected) fit();
    single_view_instruments(out);
    last_eye_ = out.eye;
    for (int b = 0; b < out.instrument_count; ++b) {
        last_instruments_[std::size_t(b)] = out.instruments[std::size_t(b)];
        int& age = unmeasured_frames_[std::size_t(b)];
        age = out.instruments[std::size_t(b)].measured() ? 0 : std::min(age + 1, 1 << 20);
    }
    out.markers_unassigned = 0;
    for (int k = 0; k < out.markers.count; ++k)
        if (out.assignment.body[std::size_t(k)] < 0) ++out.markers_unassigned;
}

Tracker::MarkerView Tracker::marker_view(const TrackingFrame& frame, int k, int c) const {
    MarkerView v;
    if (k < 0 || k >= frame.markers.count || c < 0 || c >= int(cameras_.size())) return v;
    const MatchedMarker& m = frame.markers.markers[std::size_t(k)];
    const int i = m.image_index[std::size_t(c)];
    const CameraObservations& view = views_[std::size_t(c)];
    if (i < 0 || i >= view.count) return v;
    const ImagePoint& p = view.points[std::size_t(i)];
    v.present = true;
    v.left_out = (m.occluded_views & (1u << c)) != 0;
    v.observed_px = p.px;
    v.used_px = p.px;
    v.used_xn = p.xn;
    if (corrected_views_[std::size_t(k)] & (1u << c)) {
        const CameraGeometry& g = cameras_[std::size_t(c)];
        v.used_xn = corrected_xn_[std::size_t(k)][std::size_t(c)];
        const Eigen::Vector2d xd = distort_normalized(g, v.used_xn);
        v.used_px = {g.fx * xd.x() + g.cx, g.fy * xd.y() + g.cy};
    }
    return v;
}

namespace {

// Whether the eye's outline, seen from `o`, passes across the image of the sphere (X, r): the angle between the two
// centres within the eye's angular radius ± the sphere's. Elsewhere the eye hides all of it or none (the hint's
// tests are the exact ones; this spares them for most markers).
bool near_eye_outline(const Eigen::Vector3d& o, const Eigen::Vector3d& X, double r, const Eigen::Vector3d& E, double eye_r) {
    const Eigen::Vector3d a = X - o, b = E - o;
    const double da = a.norm(), db = b.norm();
    if (!(da > r) || !(db > eye_r)) return true;  // the camera inside either: the exact tests decide
    const double angle = std::acos(std::clamp(a.dot(b) / (da * db), -1.0, 1.0));
    return std::fabs(angle - std::asin(eye_r / db)) <= 1.05 * std::asin(r / da);
}

// The eye's part in hiding the sphere (X, r_mm) from camera g, the eye's sphere (E, eye_r) in front: where the
// pipeline's centroid of what is left lies, less the sphere's centre (frame px, on a field of `parity`), and that
// part's share of the light (hinted_centroid_offset with the shaded sphere less the eye and, with shaft_radius_mm
// > 0, the shaft along axis_rig the marker is threaded on). False where the eye's outline does not cross the image.
bool eye_hidden_hint(const CameraGeometry& g, const Eigen::Vector3d& X, double r_mm, const Eigen::Vector3d& E,
                     double eye_r, const Eigen::Vector3d& axis_rig, double shaft_radius_mm, MarkerHint& hint) {
    return near_eye_outline(g.centre_rig_mm(), X, r_mm, E, eye_r) &&
           (shaft_radius_mm > 0.0 ? predict_shaft_eye_hint(g, X, r_mm, axis_rig, shaft_radius_mm, E, eye_r, hint)
                                  : predict_eye_hint(g, X, r_mm, E, eye_r, hint));
}

bool eye_hidden_offset(const SphereFitConfig& shading, const CameraGeometry& g, const Eigen::Vector3d& X, double r_mm,
                       const Eigen::Vector3d& E, double eye_r, const Eigen::Vector3d& axis_rig, double shaft_radius_mm,
                       int parity, double& dx_px, double& dv_px, double& visible) {
    MarkerHint hint;
    return eye_hidden_hint(g, X, r_mm, E, eye_r, axis_rig, shaft_radius_mm, hint) &&
           hinted_centroid_offset(shading, hint, parity, dx_px, dv_px, visible);
}

// The same for a marker the eye does not hide: the shaded sphere (X, r_mm), less the shaft along axis_rig it is
// threaded on where shaft_radius_mm > 0. Perspective, shading and the field's sampling move its centroid by hundredths
// of a pixel, and the last alternates with the parity (a field's lines are two frame rows apart); the shaft by tenths.
bool image_model_hint(const CameraGeometry& g, const Eigen::Vector3d& X, double r_mm, const Eigen::Vector3d& axis_rig,
                      double shaft_radius_mm, MarkerHint& hint) {
    return shaft_radius_mm > 0.0 ? predict_shaft_hint(g, X, r_mm, axis_rig, shaft_radius_mm, hint)
                                 : predict_clear_hint(g, X, r_mm, hint);
}

bool image_model_offset(const SphereFitConfig& shading, const CameraGeometry& g, const Eigen::Vector3d& X, double r_mm,
                        const Eigen::Vector3d& axis_rig, double shaft_radius_mm, int parity, double& dx_px,
                        double& dv_px, double& visible) {
    MarkerHint hint;
    return image_model_hint(g, X, r_mm, axis_rig, shaft_radius_mm, hint) &&
           hinted_centroid_offset(shading, hint, parity, dx_px, dv_px, visible);
}

// hinted_centroid_offset on a view blended from two fields of opposite parity (interpolate, extrapolate): the two
// parities' offsets mixed by the blend's weights (CameraField::parity_weight; 1: one field), the field of `parity`
// deciding where the other's fails. The hint, the marker's image at the pose, is the same for both.
bool mixed_centroid_offset(const SphereFitConfig& shading, const MarkerHint& hint, int parity, double weight,
                           double& dx_px, double& dv_px, double& visible) {
    if (!hinted_centroid_offset(shading, hint, parity, dx_px, dv_px, visible)) return false;
    double dx2 = 0, dv2 = 0, visible2 = 0;
    if (weight == 1.0 || !hinted_centroid_offset(shading, hint, parity ^ 1, dx2, dv2, visible2)) return true;
    dx_px = weight * dx_px + (1.0 - weight) * dx2;
    dv_px = weight * dv_px + (1.0 - weight) * dv2;
    visible = weight * visible + (1.0 - weight) * visible2;
    return true;
}

// Whether the eye's sphere (E, eye_r) lies across the line of sight from o to X, in front of X.
bool behind_eye(const Eigen::Vector3d& o, const Eigen::Vector3d& X, const Eigen::Vector3d& E, double eye_r) {
    const Eigen::Vector3d d = X - o, w = o - E;
    const double a = d.squaredNorm(), b = d.dot(w), c = w.squaredNorm() - eye_r * eye_r;
    const double disc = b * b - a * c;
    if (!(a > 0.0) || disc < 0.0) return false;
    const double t = (-b - std::sqrt(disc)) / a;  // where the line first meets the sphere
    return t > 0.0 && t < 1.0;
}

using ImagesUsed = std::array<std::array<bool, kMaxMarkersPerCamera>, kMaxCameras>;

// Images some marker of `markers` took, per camera; with `assigned`, only the markers some body claimed.
ImagesUsed images_used(const CorrespondenceResult& markers, int ncam, const MarkerAssignment* assigned = nullptr) {
    ImagesUsed used{};
    for (int k = 0; k < markers.count; ++k)
        for (int c = 0; c < ncam; ++c) {
            if (assigned && assigned->body[std::size_t(k)] < 0) break;
            const int i = markers.markers[std::size_t(k)].image_index[std::size_t(c)];
            if (i >= 0 && i < kMaxMarkersPerCamera) used[std::size_t(c)][std::size_t(i)] = true;
        }
    return used;
}

// The one image of class `cls` in view v that no marker took within `gate_px` of where a marker at X shows its
// visible part (its projection, moved by (dx, dv) full-frame px where the eye hides part of it), none other within
// twice that; −1 when there is none or more than one.
int unused_image_near(const CameraGeometry& g, const CameraObservations& v, const std::array<bool, kMaxMarkersPerCamera>& used,
                      std::uint8_t cls, const Eigen::Vector3d& X, double dx, double dv, double gate_px) {
    Eigen::Vector2d px;
    if (!v.present || !project_point(g, X, px)) return -1;
    px += Eigen::Vector2d(dx, dv);
    int near = 0, found = -1;
    for (int j = 0; j < v.count; ++j) {
        const ImagePoint& q = v.points[std::size_t(j)];
        if (q.colour_class != cls || used[std::size_t(j)]) continue;
        const double d = (q.px - px).norm();
        if (d < 2.0 * gate_px) ++near;
        if (d < gate_px) found = j;
    }
    return near == 1 ? found : -1;
}

// The images `adopted` (−1: none) become m's views in their cameras, and taken.
void take_adopted(MatchedMarker& m, const std::array<std::int8_t, kMaxCameras>& adopted, ImagesUsed& used, int ncam) {
    for (int c = 0; c < ncam; ++c) {
        const int i = adopted[std::size_t(c)];
        if (i < 0) continue;
        m.image_index[std::size_t(c)] = std::int8_t(i);
        used[std::size_t(c)][std::size_t(i)] = true;
    }
}

// The views of `m` that have an image and are not among the `n` cameras of `used`.
std::uint8_t views_left_out(const MatchedMarker& m, const std::array<int, kMaxCameras>& used, int n, int ncam) {
    std::uint8_t out = 0;
    for (int c = 0; c < ncam; ++c) {
        bool in = false;
        for (int v = 0; v < n; ++v) in = in || used[std::size_t(v)] == c;
        if (m.image_index[std::size_t(c)] >= 0 && !in) out = std::uint8_t(out | (1u << c));
    }
    return out;
}

}  // namespace

void Tracker::single_view_instruments(TrackingFrame& out) {
    const std::uint8_t before = one_view_mask_;
    one_view_mask_ = 0;
    out.one_view_mask = 0;
    const PoseOptions& opt = config_.pose;
    if (!opt.single_view || !opt.trocar_constraint || !out.eye.measured()) return;
    bool any_held = false;  // the usual frame: every instrument measured, nothing to place
    for (int b = 0; b < out.instrument_count; ++b) any_held = any_held || !out.instruments[std::size_t(b)].measured();
    if (!any_held) return;
    const int ncam = int(cameras_.size());
    // Images a body's marker took; those of markers no body claimed are free (a codec's bias on small blobs can put
    // the triangulated points of a distant instrument beyond the assignment's distance tolerance).
    const ImagesUsed used = images_used(out.markers, ncam, &out.assignment);
    const Eigen::Matrix3d Re = out.eye.rotation_eye_to_rig.toRotationMatrix();
    for (int b = 0; b < out.instrument_count; ++b) {
        const InstrumentModel& model = config_.bodies.instruments[std::size_t(b)];
        const int nm = model.marker_count;
        // The fit starts from the last frame's one-view pose, else from the last measured one (a held pose keeps
        // its values) up to kSingleViewMaxHeldFrames old.
        const bool chained = (before >> b) & 1u;
        const InstrumentPose& last = chained ? one_view_[std::size_t(b)] : last_instruments_[std::size_t(b)];
        if (out.instruments[std::size_t(b)].measured() || !model.has_trocar || nm < 3 || nm > kMaxBodyMarkers ||
            (!chained && unmeasured_frames_[std::size_t(b)] > kSingleViewMaxHeldFrames))
            continue;
        const Eigen::Vector3d trocar = Re * model.trocar_eye_mm + out.eye.centre_rig_mm;
        const Eigen::Vector3d a_body = model.axis_body.normalized();
        // Markers in the order of their distance from the tip: their images lie on the shaft's image line through
        // the trocar's image, in that order from it (the trocar lies on the tip's side of every marker, the tip
        // inside the eye or withdrawn).
        std::array<int, kMaxBodyMarkers> order{};
        for (int i = 0; i < nm; ++i) order[std::size_t(i)] = i;
        std::sort(order.begin(), order.begin() + nm, [&](int x, int y) {
            return (model.markers[std::size_t(x)].pos_body_mm - model.tip_body_mm).dot(a_body) <
                   (model.markers[std::size_t(y)].pos_body_mm - model.tip_body_mm).dot(a_body);
        });
        // Per camera the one combination that fits (another one in the same camera nearly as well is an ambiguity:
        // none from that camera), then one fit over every such camera's images.
        std::array<ShaftImage, kMaxShaftImages> joint{};
        std::size_t n_joint = 0;
        InstrumentPose best;
        double best_rms = HUGE_VAL;
        for (int c = 0; c < ncam; ++c) {
            InstrumentPose cam_best;
            double cam_rms = HUGE_VAL, second_rms = HUGE_VAL;
            std::array<int, kMaxBodyMarkers> cam_pick{};
            const CameraObservations& v = views_[std::size_t(c)];
            const CameraGeometry& g = cameras_[std::size_t(c)];
            const Eigen::Vector3d tc = g.R_cam_rig * trocar + g.t_cam_rig_mm;
            if (!v.present || !(tc.z() > 0.0)) continue;
            const Eigen::Vector2d pt = tc.head<2>() / tc.z();  // the trocar's image (undistorted, normalised)
            const double f = g.mean_focal_px();
            // Candidates per marker: unused images of its class.
            std::array<std::array<int, kMaxImagesPerClass>, kMaxBodyMarkers> cand{};
            std::array<int, kMaxBodyMarkers> nc{};
            bool any_missing = false;
            for (int i = 0; i < nm; ++i) {
                const std::uint8_t cls = model.markers[std::size_t(order[std::size_t(i)])].colour_class;
                for (int j = 0; j < v.count && nc[std::size_t(i)] < kMaxImagesPerClass; ++j)
                    if (v.points[std::size_t(j)].colour_class == cls && !used[std::size_t(c)][std::size_t(j)])
                        cand[std::size_t(i)][std::size_t(nc[std::size_t(i)]++)] = j;
                any_missing = any_missing || nc[std::size_t(i)] == 0;
            }
            if (any_missing) continue;
            // Every combination (one image per marker, odometer order) that lies on a line through the trocar's
            // image, in the markers' order from it, is fitted.
            std::array<int, kMaxBodyMarkers> pick{};
            for (bool more = true; more;) {
                std::array<Eigen::Vector2d, kMaxBodyMarkers> xn{};
                std::array<int, kMaxBodyMarkers> img{};  // the combination's image per marker
                bool distinct = true;
                for (int i = 0; i < nm; ++i) {
                    const int j = cand[std::size_t(i)][std::size_t(pick[std::size_t(i)])];
                    for (int k = 0; k < i; ++k) distinct = distinct && img[std::size_t(k)] != j;
                    img[std::size_t(i)] = j;
                    xn[std::size_t(i)] = v.points[std::size_t(j)].xn;
                }
                // Next combination.
                more = false;
                for (int i = 0; i < nm && !more; ++i) {
                    if (++pick[std::size_t(i)] < nc[std::size_t(i)]) more = true;
                    else pick[std::size_t(i)] = 0;
                }
                if (!distinct) continue;
                const Eigen::Vector2d dir = (xn[std::size_t(nm - 1)] - pt).normalized();
                bool on_line = dir.allFinite();
                double along = 0.0;
                for (int i = 0; i < nm && on_line; ++i) {
                    const Eigen::Vector2d q = xn[std::size_t(i)] - pt;
                    const double t = q.dot(dir);
                    on_line = std::abs(q.x() * dir.y() - q.y() * dir.x()) * f <= kSingleViewLinePx && t > along;
                    along = t;
                }
                if (!on_line) continue;
                InstrumentPose fitted = last;
                double rms = 0.0;
                if (!fit_instrument_one_view(g, model, trocar, std::span<const Eigen::Vector2d>(xn.data(), std::size_t(nm)),
                                             std::span<const int>(order.data(), std::size_t(nm)), last, fitted, rms))
                    continue;
                if (rms < cam_rms) {
                    second_rms = cam_rms;
                    cam_rms = rms;
                    cam_best = fitted;
                    cam_pick = img;
                } else {
                    second_rms = std::min(second_rms, rms);
                }
            }
            if (!(cam_rms <= opt.single_view_max_rms_px) || second_rms <= opt.single_view_max_rms_px) continue;
            for (int i = 0; i < nm; ++i)
                joint[n_joint++] = ShaftImage{&g, v.points[std::size_t(cam_pick[std::size_t(i)])].xn, order[std::size_t(i)]};
            if (cam_rms < best_rms) {
                best_rms = cam_rms;
                best = cam_best;
            }
        }
        if (n_joint == 0) continue;
        if (n_joint > std::size_t(nm)) {  // two cameras or more: one fit over all (they must agree)
            InstrumentPose both = best;
            double rms = 0.0;
            if (!fit_instrument_images(std::span<const ShaftImage>(joint.data(), n_joint), model, trocar, best, both,
                                       rms) ||
                !(rms <= opt.single_view_max_rms_px))
                continue;
            best = both;
        }
        instrument_in_eye(model, out.eye, best);
        out.one_view[std::size_t(b)] = best;
        out.one_view_mask = std::uint8_t(out.one_view_mask | (1u << b));
        one_view_[std::size_t(b)] = best;
    }
    one_view_mask_ = out.one_view_mask;
}

bool Tracker::shifted_observation(int c, const ImagePoint& p, double dx_px, double dv_px, Observation& o) const {
    const CameraGeometry& g = cameras_[std::size_t(c)];
    Eigen::Vector2d xn = p.xn;
    if (dx_px != 0.0 || dv_px != 0.0) {
        const Undistorted u = undistort_pixel(g, p.px - Eigen::Vector2d(dx_px, dv_px), config_.undistort);
        if (!u.converged) return false;
        xn = u.xn;
    }
    const Eigen::Vector2d xd = distort_normalized(g, xn);
    // The correction is as good as the eye's outline is placed: its error grows with the shift.
    o = Observation{c, Eigen::Vector2d(g.fx * xd.x() + g.cx, g.fy * xd.y() + g.cy), xn,
                    p.sigma_px + kEyeCorrectionRelError * std::hypot(dx_px, dv_px)};
    return true;
}

std::uint8_t Tracker::merged_views(const TrackingFrame& out, const MatchedMarker& m, const Eigen::Vector3d& X, double r_mm,
                                   int eye_marker, std::array<Eigen::Vector2d, kMaxCameras>& shift_px) const {
    const BodySet& bodies = config_.bodies;
    const std::uint8_t cls = m.colour_class;
    const SphereFitConfig shading;
    const bool eye_known = out.eye.measured() && bodies.eye.radius_mm > 0.0;
    const Eigen::Matrix3d R = out.eye.rotation_eye_to_rig.toRotationMatrix();
    std::uint8_t merged = 0;
    for (int c = 0; c < int(cameras_.size()); ++c) {
        shift_px[std::size_t(c)].setZero();
        const int i = m.image_index[std::size_t(c)];
        if (i < 0) continue;
        const CameraObservations& v = views_[std::size_t(c)];
        const CameraGeometry& g = cameras_[std::size_t(c)];
        const Eigen::Vector3d o = g.centre_rig_mm();
        // Where a marker's visible part shows (frame px; `off`: its shift from the projection where the eye hides
        // part of it) and its weight in a joined blob (its light: the visible share of a disc of its image's
        // radius); false where the eye hides it.
        auto seen = [&](const Eigen::Vector3d& Y, double rb_mm, Eigen::Vector2d& at, Eigen::Vector2d& off, double& w) {
            const double z = (g.R_cam_rig * Y + g.t_cam_rig_mm).z();
            if (!(z > 0.0) || !project_point(g, Y, at)) return false;
            double ox = 0, ov = 0, visible = 1.0;
            off.setZero();
            if (eye_known && eye_hidden_offset(shading, g, Y, rb_mm, out.eye.centre_rig_mm, bodies.eye.radius_mm,
                                               Eigen::Vector3d::Zero(), 0.0, view_parity_[std::size_t(c)], ox, ov, visible)) {
                if (visible < kMinVisibleShare) return false;
                off = Eigen::Vector2d(ox, ov);
                at += off;
            } else if (eye_known && behind_eye(o, Y, out.eye.centre_rig_mm, bodies.eye.radius_mm)) {
                return false;
            }
            const double r_px = g.fx * rb_mm / z;
            w = visible * r_px * r_px;
            return true;
        };
        // Another marker Y of radius rb joins this one's blob where the two discs (field px: a field line is two
        // frame lines) come within kMergeGapPx and this view's image is also the one of the colour nearest Y. The
        // cheap tests first: most markers have no other of their colour near.
        Eigen::Vector2d pa;
        const double za = (g.R_cam_rig * X + g.t_cam_rig_mm).z();
        if (!(za > 0.0) || !project_point(g, X, pa)) continue;
        std::array<Eigen::Vector3d, kMaxJoined> near_mm;
        std::array<double, kMaxJoined> near_r_mm{};
        int n_near = 0;
        const Eigen::Vector3d to_x = X - o;
        const double dist_x = to_x.norm();
        auto join = [&](const Eigen::Vector3d& Y, double rb_mm) {
            // Far apart as the camera sees them (the sine of the angle between the two lines of sight beyond the
            // radii's and a few pixels'): no projection needed. Most pairs end here.
            const Eigen::Vector3d to_y = Y - o;
            const double dist_y = to_y.norm();
            if (to_x.cross(to_y).norm() > dist_x * dist_y * (r_mm / dist_x + rb_mm / dist_y + 4.0 * kMergeGapPx / g.fx))
                return;
            Eigen::Vector2d pb;
            const double zb = (g.R_cam_rig * Y + g.t_cam_rig_mm).z();
            if (n_near == kMaxJoined || !(zb > 0.0) || !project_point(g, Y, pb)) return;
            const double rx = g.fx * (r_mm / za + rb_mm / zb) + kMergeGapPx;
            const double ry = 0.5 * g.fy * (r_mm / za + rb_mm / zb) + kMergeGapPx;
            const Eigen::Vector2d d = pa - pb;
            if (std::pow(d.x() / rx, 2) + std::pow(0.5 * d.y() / ry, 2) >= 1.0) return;
            int nearest = -1;
            double best = 1e300;
            for (int j = 0; j < v.count; ++j) {
                const ImagePoint& q = v.points[std::size_t(j)];
                const double e = (q.px - pb).squaredNorm();
                if (q.colour_class == cls && e < best) {
                    best = e;
                    nearest = j;
                }
            }
            if (nearest != i) return;
            near_mm[std::size_t(n_near)] = Y;
            near_r_mm[std::size_t(n_near++)] = rb_mm;
        };
        if (eye_known)
            for (int j = 0; j < bodies.eye.marker_count; ++j) {
                const BodyMarker& bm = bodies.eye.markers[std::size_t(j)];
                if (j != eye_marker && bm.colour_class == cls)
                    join(out.eye.centre_rig_mm + R * bm.pos_body_mm, bm.radius_mm > 0.0 ? bm.radius_mm : bodies.marker_radius_mm);
            }
        for (int b = 0; b < out.instrument_count; ++b) {
            const InstrumentModel& model = bodies.instruments[std::size_t(b)];
            const InstrumentPose& pose = out.instruments[std::size_t(b)];
            if (!pose.measured()) continue;
            for (int j = 0; j < model.marker_count; ++j) {
                const BodyMarker& bm = model.markers[std::size_t(j)];
                if (bm.colour_class == cls)
                    join(pose.tip_rig_mm + pose.rotation_body_to_rig * (bm.pos_body_mm - model.tip_body_mm),
                         bm.radius_mm > 0.0 ? bm.radius_mm : bodies.marker_radius_mm);
            }
        }
        if (n_near == 0) continue;
        // The joined ones the eye leaves in view; where they are, less this marker's visible part.
        Eigen::Vector2d at_a, off_a, at, off;
        double wa = 0, w = 0;
        if (!seen(X, r_mm, at_a, off_a, wa)) continue;
        Eigen::Vector2d sum = Eigen::Vector2d::Zero();
        double wsum = wa;
        for (int k = 0; k < n_near; ++k) {
            if (!seen(near_mm[std::size_t(k)], near_r_mm[std::size_t(k)], at, off, w)) continue;
            sum += w * (at - at_a);
            wsum += w;
            merged = std::uint8_t(merged | (1u << c));
        }
        // The joined blob's centroid less the marker's projection: its visible part's offset and the neighbours' pull.
        shift_px[std::size_t(c)] = off_a + sum / wsum;
    }
    return merged;
}

bool Tracker::correct_eye_occlusion(TrackingFrame& out) {
    const BodySet& bodies = config_.bodies;
    if (!out.eye.measured() || !(bodies.eye.radius_mm > 0.0)) return false;
    const Eigen::Matrix3d R = out.eye.rotation_eye_to_rig.toRotationMatrix();
    const SphereFitConfig shading;  // the marker's shading model: ambient + diffuse·cos
    bool changed = false;
    std::array<Observation, kMaxCameras> obs;
    std::array<int, kMaxCameras> obs_view{};
    std::array<std::uint8_t, kMaxCameras> moved{};
    // Eye markers the fit took; a marker judged occluded was left out of it and is taken as the eye marker of
    // its class predicted nearest it, if the fit took none there.
    std::array<bool, kMaxBodyMarkers> taken{};
    for (int k = 0; k < out.markers.count; ++k) {
        const int mi = out.assignment.marker[std::size_t(k)];
        if (out.assignment.body[std::size_t(k)] == 0 && mi >= 0 && mi < bodies.eye.marker_count) taken[std::size_t(mi)] = true;
    }
    // Images no marker took: a view the correspondence could not pair (the marker's other views mostly hidden,
    // their centroids off its epipolar lines) may still be the marker's clean view.
    ImagesUsed image_used = images_used(out.markers, int(cameras_.size()));
    for (int k = 0; k < out.markers.count; ++k) {
        MatchedMarker& m = out.markers.markers[std::size_t(k)];
        int mi = out.assignment.body[std::size_t(k)] == 0 ? out.assignment.marker[std::size_t(k)] : -1;
        if (out.assignment.body[std::size_t(k)] < 0 && m.occluded && m.point.usable()) {
            double best = kOccludedEyeMarkerGateMm;
            for (int i = 0; i < bodies.eye.marker_count; ++i) {
                const BodyMarker& bm = bodies.eye.markers[std::size_t(i)];
                if (taken[std::size_t(i)] || bm.colour_class != m.colour_class) continue;
                const double d = (out.eye.centre_rig_mm + R * bm.pos_body_mm - m.point.X_rig_mm).norm();
                if (d < best) {
                    best = d;
                    mi = i;
                }
            }
        }
        if (mi < 0 || mi >= bodies.eye.marker_count) continue;
        const BodyMarker& bm = bodies.eye.markers[std::size_t(mi)];
        const double radius_mm = bm.radius_mm > 0.0 ? bm.radius_mm : bodies.marker_radius_mm;
        if (!(radius_mm > 0.0)) continue;
        // Where the fitted pose puts the marker: its image's occlusion depends on the geometry, not on the
        // biased point triangulated from the visible parts.
        const Eigen::Vector3d X = out.eye.centre_rig_mm + R * bm.pos_body_mm;
        // A view whose blob holds another marker of the colour too places neither (sweep seed 31, 10 s: in camera 1
        // an eye marker 74 % behind the eye's outline joined with its neighbour 4 px away; the larger blob also
        // made the clean views look small, and they were judged occluded beside it). It is left out, and the views
        // judged occluded only beside it are judged again from the others.
        std::array<Eigen::Vector2d, kMaxCameras> merge_shift;
        const std::uint8_t merged = merged_views(out, m, X, radius_mm, mi, merge_shift);
        std::uint8_t relieved = 0;
        if (merged != 0 && (m.occluded_views & ~merged) != 0) {
            std::array<std::int8_t, kMaxCameras> apart = m.image_index;
            for (std::size_t c = 0; c < apart.size(); ++c)
                if (merged & (1u << c)) apart[c] = -1;
            int clean = 0;
            const std::uint8_t still = correspondence_.occluded_views(
                std::span<const CameraObservations>(views_.data(), cameras_.size()), apart, X, int(cameras_.size()), clean);
            for (int c = 0; c < int(cameras_.size()); ++c) {
                const int i = apart[std::size_t(c)];
                // Judged again only where the blob's area is known (the judgement keeps the others as they were).
                if (i >= 0 && (m.occluded_views & ~still & (1u << c)) &&
                    correspondence_.area_ratio(views_[std::size_t(c)].points[std::size_t(i)], c, X) > 0.0)
                    relieved = std::uint8_t(relieved | (1u << c));
            }
        }
        int n = 0, hidden = 0, clear_moved = 0;
        std::array<std::int8_t, kMaxCameras> adopted;
        adopted.fill(-1);
        for (int c = 0; c < int(cameras_.size()); ++c) {
            int i = m.image_index[std::size_t(c)];
            if (i < 0 && !m.occluded) continue;
            if (merged & (1u << c)) continue;
            const CameraGeometry& g = cameras_[std::size_t(c)];
            double dx = 0, dv = 0, visible = 1.0;
            const int parity = view_parity_[std::size_t(c)];
            const double weight = view_parity_weight_[std::size_t(c)];
            MarkerHint hint;
            const bool eye_hides = eye_hidden_hint(g, X, radius_mm, out.eye.centre_rig_mm, bodies.eye.radius_mm,
                                                   Eigen::Vector3d::Zero(), 0.0, hint) &&
                                   mixed_centroid_offset(shading, hint, parity, weight, dx, dv, visible);
            // A view the eye does not hide: the sphere's own image model (TrackerConfig::marker_image_model).
            const bool modelled = !eye_hides && config_.marker_image_model &&
                                  image_model_hint(g, X, radius_mm, Eigen::Vector3d::Zero(), 0.0, hint) &&
                                  mixed_centroid_offset(shading, hint, parity, weight, dx, dv, visible);
            if (!eye_hides && !modelled) dx = dv = 0.0, visible = 1.0;
            if (i < 0 && m.occluded) {  // the unused image where the pose puts the marker's visible part
                i = unused_image_near(g, views_[std::size_t(c)], image_used[std::size_t(c)], m.colour_class, X,
                                      eye_hides ? dx : 0.0, eye_hides ? dv : 0.0, kAdoptGatePx);
                adopted[std::size_t(c)] = std::int8_t(i);
            }
            if (i < 0) continue;
            const ImagePoint& p = views_[std::size_t(c)].points[std::size_t(i)];
            // A view judged occluded that the eye does not hide has something else across it: it stays out. One
            // the eye hides almost whole has too little left to place it.
            if (eye_hides ? visible < kMinVisibleShare : (m.occluded_views & ~relieved & (1u << c)) != 0) continue;
            if (!shifted_observation(c, p, dx, dv, obs[std::size_t(n)])) continue;
            hidden += eye_hides;
            clear_moved += modelled;
            moved[std::size_t(n)] = eye_hides || modelled;
            obs_view[std::size_t(n++)] = c;
        }
        // Too few views apart from the joined ones: a joined view is moved back by its neighbours' predicted share
        // of the blob (sweep seed 44: an eye marker whole in camera 0, joined in camera 1, 95 % hidden in camera 2).
        for (int c = 0; c < int(cameras_.size()) && n < 2; ++c) {
            if (!(merged & (1u << c))) continue;  // a joined view has an image, and the eye leaves enough of it
            const Eigen::Vector2d& shift = merge_shift[std::size_t(c)];
            const ImagePoint& p = views_[std::size_t(c)].points[std::size_t(m.image_index[std::size_t(c)])];
            if (!shifted_observation(c, p, shift.x(), shift.y(), obs[std::size_t(n)])) continue;
            moved[std::size_t(n)] = 1;
            obs_view[std::size_t(n++)] = c;
        }
        // A marker judged occluded keeps its flag unless the eye's model or a joined blob placed it.
        if ((hidden == 0 && merged == 0 && (clear_moved == 0 || m.occluded)) || n < 2) continue;
        const TriangulatedPoint tp = triangulate(cameras_, std::span<const Observation>(obs.data(), std::size_t(n)),
                                                 config_.correspondence.triangulation);
        if (!tp.usable()) continue;
        take_adopted(m, adopted, image_used, int(cameras_.size()));
        m.point = tp;
        m.occluded = false;
        taken[std::size_t(mi)] = true;
        m.occluded_views = views_left_out(m, obs_view, n, int(cameras_.size()));
        eye_model_views_ += std::uint64_t(hidden);
        for (int v = 0; v < n; ++v) {
            if (!moved[std::size_t(v)]) continue;
            const int c = obs_view[std::size_t(v)];
            corrected_views_[std::size_t(k)] |= std::uint8_t(1u << c);
            corrected_xn_[std::size_t(k)][std::size_t(c)] = obs[std::size_t(v)].xn;
        }
        changed = true;
    }
    return changed;
}

bool Tracker::correct_shaft_occlusion(TrackingFrame& out) {
    const BodySet& bodies = config_.bodies;
    const double R = bodies.marker_radius_mm;
    if (!(R > 0.0)) return false;
    const SphereFitConfig shading;  // the marker's shading model, as correct_eye_occlusion
    bool changed = false;
    std::array<Observation, kMaxCameras> obs;
    std::array<int, kMaxCameras> obs_view{};
    const int ncam = int(cameras_.size());
    const bool eye_measured = config_.eye_occlusion_correction && out.eye.measured() && bodies.eye.radius_mm > 0.0;
    ImagesUsed image_used = images_used(out.markers, ncam);
    auto predicted = [&](int b, int mi) {
        const InstrumentModel& model = bodies.instruments[std::size_t(b - 1)];
        const InstrumentPose& pose = out.instruments[std::size_t(b - 1)];
        return Eigen::Vector3d(pose.tip_rig_mm +
                               pose.rotation_body_to_rig * (model.markers[std::size_t(mi)].pos_body_mm - model.tip_body_mm));
    };
    // Instrument markers the fit took; a marker judged occluded that no body took is taken as the instrument
    // marker of its class the poses put nearest it (within kOccludedEyeMarkerGateMm), if the fit took none there,
    // and corrected for the eye below (sweep seed 26, 10 s: a light-pipe marker 70-90 % behind the eye in two
    // cameras, paired from those two, 0.8 mm off, unassigned, its clean third view unused).
    std::array<std::array<bool, kMaxBodyMarkers>, kMaxInstruments + 1> taken{};
    for (int k = 0; k < out.markers.count; ++k) {
        const int b = out.assignment.body[std::size_t(k)], mi = out.assignment.marker[std::size_t(k)];
        if (b >= 1 && b <= out.instrument_count && mi >= 0 && mi < kMaxBodyMarkers) taken[std::size_t(b)][std::size_t(mi)] = true;
    }
    for (int k = 0; k < out.markers.count; ++k) {
        MatchedMarker& m = out.markers.markers[std::size_t(k)];
        int body = out.assignment.body[std::size_t(k)], mi = out.assignment.marker[std::size_t(k)];
        const bool unassigned = body < 0 && m.occluded && m.point.usable() && eye_measured;
        if (unassigned) {
            double best = kOccludedEyeMarkerGateMm;
            for (int b = 1; b <= out.instrument_count; ++b) {
                const InstrumentModel& model = bodies.instruments[std::size_t(b - 1)];
                if (!out.instruments[std::size_t(b - 1)].measured()) continue;
                for (int i = 0; i < model.marker_count; ++i) {
                    if (taken[std::size_t(b)][std::size_t(i)] || model.markers[std::size_t(i)].colour_class != m.colour_class) continue;
                    const double d = (predicted(b, i) - m.point.X_rig_mm).norm();
                    if (d < best) {
                        best = d;
                        body = b;
                        mi = i;
                    }
                }
            }
        }
        if (body < 1) continue;
        const InstrumentModel& model = bodies.instruments[std::size_t(body - 1)];
        const InstrumentPose& pose = out.instruments[std::size_t(body - 1)];
        if (!pose.measured() || !(model.shaft_radius_mm > 0.0)) continue;
        const Eigen::Vector3d a = pose.axis_rig;
        // Where the pose puts the marker, for the eye's part in hiding it (as correct_eye_occlusion).
        const bool eye_known = eye_measured && mi >= 0 && mi < model.marker_count;
        const Eigen::Vector3d Xp = eye_known ? predicted(body, mi) : m.point.X_rig_mm;
        // A marker taken above was placed from its hidden views: the pose's point places the shaft instead.
        const Eigen::Vector3d X = unassigned ? Xp : m.point.X_rig_mm;
        int n = 0, eye_views = 0;
        std::array<std::int8_t, kMaxCameras> adopted;
        adopted.fill(-1);
        for (int c = 0; c < ncam; ++c) {
            int i = m.image_index[std::size_t(c)];
            if (i < 0 && !unassigned) continue;
            const CameraGeometry& g = cameras_[std::size_t(c)];
            // The eye hides part of it in this view (a marker seen past the eye's outline): the shaded sphere less
            // the eye and the shaft gives the shift, in a view judged occluded too.
            double dx = 0, dv = 0, visible = 0;
            const int parity = view_parity_[std::size_t(c)];
            const double weight = view_parity_weight_[std::size_t(c)];
            MarkerHint hint;
            const bool eye_hides = eye_known &&
                                   eye_hidden_hint(g, Xp, R, out.eye.centre_rig_mm, bodies.eye.radius_mm, a,
                                                   model.shaft_radius_mm, hint) &&
                                   mixed_centroid_offset(shading, hint, parity, weight, dx, dv, visible);
            if (i < 0 && unassigned) {  // the unused image where the pose puts the marker's visible part
                i = unused_image_near(g, views_[std::size_t(c)], image_used[std::size_t(c)], m.colour_class, Xp,
                                      eye_hides ? dx : 0.0, eye_hides ? dv : 0.0, kAdoptGatePx);
                adopted[std::size_t(c)] = std::int8_t(i);
            }
            if (i < 0) continue;
            const ImagePoint& p = views_[std::size_t(c)].points[std::size_t(i)];
            if (eye_hides) {
                if (visible < kMinVisibleShare || !shifted_observation(c, p, dx, dv, obs[std::size_t(n)])) continue;
                obs_view[std::size_t(n++)] = c;
                ++eye_views;
                continue;
            }
            if (m.occluded_views & (1u << c)) continue;
            // The marker's image model (TrackerConfig::marker_image_model): the shaded sphere less the shaft, sampled
            // on the field's lines; the strip below where it does not place the marker.
            if (config_.marker_image_model && image_model_hint(g, X, R, a, model.shaft_radius_mm, hint) &&
                mixed_centroid_offset(shading, hint, parity, weight, dx, dv, visible)) {
                if (visible < kMinVisibleShare || !shifted_observation(c, p, dx, dv, obs[std::size_t(n)])) continue;
                obs_view[std::size_t(n++)] = c;
                continue;
            }
            const Eigen::Vector3d Xc = g.R_cam_rig * X + g.t_cam_rig_mm;
            const Eigen::Vector3d v = (g.centre_rig_mm() - X).normalized();  // towards the camera
            const Eigen::Vector3d e = a.dot(v) > 0.0 ? a : Eigen::Vector3d(-a);  // the half-shaft in front
            const double sin_t = (e - e.dot(v) * v).norm();
            Eigen::Vector2d xn = p.xn;
            if (sin_t > 1e-3 && Xc.z() > 0.0) {
                const Eigen::Vector3d Xe = g.R_cam_rig * (X + e) + g.t_cam_rig_mm;
                const Eigen::Vector2d u =
                    (Eigen::Vector2d(Xe.x() / Xe.z(), Xe.y() / Xe.z()) - Eigen::Vector2d(Xc.x() / Xc.z(), Xc.y() / Xc.z()))
                        .normalized();
                const double rho = R / Xc.z();
                const double shift = strip_centroid_shift(rho, model.shaft_radius_mm / Xc.z(), rho * sin_t);
                if (u.allFinite()) xn -= shift * u;  // observed = true + shift·u
            }
            const Eigen::Vector2d xd = distort_normalized(g, xn);
            obs_view[std::size_t(n)] = c;
            obs[std::size_t(n++)] = Observation{c, Eigen::Vector2d(g.fx * xd.x() + g.cx, g.fy * xd.y() + g.cy), xn,
                                                p.sigma_px};
        }
        if (n < 2 || (unassigned && eye_views == 0)) continue;
        const TriangulatedPoint tp = triangulate(cameras_, std::span<const Observation>(obs.data(), std::size_t(n)),
                                                 config_.correspondence.triangulation);
        if (tp.usable()) {
            take_adopted(m, adopted, image_used, ncam);
            if (unassigned) taken[std::size_t(body)][std::size_t(mi)] = true;
            m.point = tp;
            changed = true;
            eye_model_views_ += std::uint64_t(eye_views);
            if (eye_views > 0) {  // what hid it is modelled: no longer biased
                m.occluded = false;
                m.occluded_views = views_left_out(m, obs_view, n, int(cameras_.size()));
            }
            for (int v = 0; v < n; ++v) {
                const int c = obs_view[std::size_t(v)];
                corrected_views_[std::size_t(k)] |= std::uint8_t(1u << c);
                corrected_xn_[std::size_t(k)][std::size_t(c)] = obs[std::size_t(v)].xn;
            }
        }
    }
    return changed;
}

// ---------------------------------------------------------------------------------------------------------------
// SyncMode::Async: per-body filters updated by one camera field at a time
// ---------------------------------------------------------------------------------------------------------------

namespace {

void eye_from_filter(const EyeModel& model, const Eigen::Quaterniond& R, EyePose& eye) {
    eye.rotation_eye_to_rig = R;
    eye.centre_rig_mm = model.centre_rig_mm;
    eye.fit_rms_mm = 0.0;
    eye.flags = kPoseOk;
}

void instrument_from_filter(const InstrumentModel& model, const Eigen::Quaterniond& R, const Eigen::Vector3d& t,
                            bool no_roll, InstrumentPose& pose) {
    pose.tip_rig_mm = R * model.tip_body_mm + t;
    pose.axis_rig = (R * model.axis_body).normalized();
    pose.rotation_body_to_rig = R;
    pose.fit_rms_mm = 0.0;
    pose.flags = no_roll ? kPoseNoRoll : kPoseOk;
}

}  // namespace

bool Tracker::pop_async(TrackingFrame& out, double now_host_us) {
    while (queue_count_ > 0) {
        const QueuedField& q = queue_[std::size_t(queue_head_)];
        const CameraField& f = q.field;
        queue_head_ = (queue_head_ + 1) % kQueue;
        --queue_count_;
        const double t0 = steady_us();
        const int accepted = fuse_field(f, q.first, q.last, q.fuse_us);
        // Frames are reported at the reference camera's fields (where the rig's truth is sampled); every other
        // field has already corrected the filters in between. In low-latency mode each part of the reference
        // field that corrected a filter gives a frame at once (the pose at the field's time, as far as its
        // image is read out); the complete field gives one more only if it brought something new.
        const bool lag = config_.async.report_delay_us > 0.0;
        if (f.camera != config_.sync.reference_camera || !std::isfinite(f.sample_device_us)) {
            if (q.last && acquire_due_) acquire_due_frame();
            if (lag && report_due(out, now_host_us)) return true;
            continue;
        }
        bool report = accepted > 0;
        if (q.last) {
            acquire(f);
            report = report || acquired_this_field_ ||
                     !(ref_reported_ && ref_reported_counter_ == f.field_counter);
        } else {
            acquired_this_field_ = false;
        }
        if (!report) {
            if (lag && report_due(out, now_host_us)) return true;
            continue;
        }
        ref_reported_ = true;
        ref_reported_counter_ = f.field_counter;
        if (lag) {
            hold_frame(f, q.last);
            if (report_due(out, now_host_us)) return true;
            continue;
        }
        build_async_frame(f, out);
        const double compute = steady_us() - t0;
        out.timing.sample_host_us = f.sample_device_us - offset_us_;
        // A frame from a part of a field still being read out has no field end yet (0).
        out.timing.field_end_host_us = q.last ? f.field_end_device_us - offset_us_ : 0.0;
        out.timing.received_host_us = f.received_host_us;
        out.timing.compute_us = compute;
        out.timing.poses_ready_host_us = now_host_us + compute;
        return true;
    }
    return config_.async.report_delay_us > 0.0 && report_due(out, now_host_us);
}

void Tracker::hold_frame(const CameraField& f, bool last) {
    if (pending_reported_any_ && pending_last_reported_ == f.field_counter) return;  // its frame already went
    PendingFrame* p = nullptr;
    if (pending_count_ > 0) {
        PendingFrame& tail = pending_[std::size_t((pending_head_ + pending_count_ - 1) % kPending)];
        if (tail.field.field_counter == f.field_counter) p = &tail;
    }
    if (!p) {
        if (pending_count_ == kPending) {  // no part came for a whole queue's worth: the oldest is dropped
            pending_head_ = (pending_head_ + 1) % kPending;
            --pending_count_;
        }
        p = &pending_[std::size_t((pending_head_ + pending_count_++) % kPending)];
    }
    p->field = f;
    p->last = last;
}

double Tracker::next_report_host_us() const {
    if (pending_count_ == 0) return std::numeric_limits<double>::infinity();
    const PendingFrame& p = pending_[std::size_t(pending_head_)];
    const double due = p.field.sample_device_us - offset_us_ + config_.async.report_delay_us;
    if (!genlocked_fields_due(p)) return due;
    // Waits for them, but gives a lost one up half a period after the reference field's end.
    return std::max(due, p.field.field_end_device_us - offset_us_ + 0.5 * config_.sync.field_period_us);
}

bool Tracker::genlocked_fields_due(const PendingFrame& p) const {
    // A genlocked rig: every camera's fields exposed with the reference camera's. Its frame's time has no other
    // camera's field after it, so a frame reported before its own fields are in holds only the fields a period
    // older (1 s `sweep` with `synth --synchronised`, whole fields: the light pipe, which camera 0 does not see,
    // held in 49 of 50 frames; held-out 2 s `sweep`: tip 28.3 µm, 22.7 waiting). Such a frame waits for them; an
    // unsynchronised rig, or one only partly genlocked, never waits. The synchroniser holds every complete field.
    const double T = p.field.sample_device_us;
    if (!std::isfinite(T) || !std::isfinite(p.field.field_end_device_us) || cameras_.size() < 2) return false;
    bool waiting = false;
    for (int c = 0; c < int(cameras_.size()); ++c) {
        if (sync_.has_field_at(c, T)) continue;   // its field of this time is in
        if (!sync_.field_due(c, T)) return false;  // not genlocked
        waiting = true;
    }
    return waiting;
}

bool Tracker::report_due(TrackingFrame& out, double now_host_us) {
    if (pending_count_ == 0) return false;
    const PendingFrame& p = pending_[std::size_t(pending_head_)];
    const double sample_host_us = p.field.sample_device_us - offset_us_;
    if (!flush_pending_ && now_host_us < next_report_host_us()) return false;
    const double t0 = steady_us();
    build_async_frame(p.field, out, &p);
    const double compute = steady_us() - t0;
    out.timing.sample_host_us = sample_host_us;
    out.timing.field_end_host_us = p.last ? p.field.field_end_device_us - offset_us_ : 0.0;
    out.timing.received_host_us = p.field.received_host_us;
    out.timing.compute_us = compute;
    out.timing.poses_ready_host_us = now_host_us + compute;
    pending_last_reported_ = p.field.field_counter;
    pending_reported_any_ = true;
    pending_head_ = (pending_head_ + 1) % kPending;
    --pending_count_;
    return true;
}

double Tracker::trocar_depth_mm(int b, Eigen::Vector3d* trocar_rig_mm) const {
    const InstrumentModel& m = config_.bodies.instruments[std::size_t(b - 1)];
    const BodyFilter& flt = filters_[std::size_t(b)];
    if (!config_.pose.trocar_constraint || !m.has_trocar || !filters_[0].tracking()) return -1.0;
    const Eigen::Vector3d p = filters_[0].to_rig(m.trocar_eye_mm);
    const Eigen::Vector3d a = (flt.rotation() * m.axis_body).normalized();
    const Eigen::Vector3d d = p - flt.to_rig(m.tip_body_mm);
    const double depth = d.dot(a);
    if (!(depth > 0.0) || !((d - depth * a).norm() < config_.pose.trocar_gate_mm)) return -1.0;
    if (trocar_rig_mm) *trocar_rig_mm = p;
    return depth;
}

void Tracker::set_trocar_pivot(int b) {
    const InstrumentModel& m = config_.bodies.instruments[std::size_t(b - 1)];
    const Eigen::Vector3d axis = m.axis_body.normalized();
    const double depth_mm = trocar_depth_mm(b, nullptr);
    // The agile model: the last constant-velocity one (motion_model_ladder).
    filters_[std::size_t(b)].set_pivot(std::clamp(config_.async.motion_models, 1, 3) - 1, depth_mm > 0.0,
                                       m.tip_body_mm + depth_mm * axis, axis, config_.async.pivot_across_fraction);
}

int Tracker::fuse_field(const CameraField& f, int first, bool last, double T) {
    const int c = f.camera;
    if (c < 0 || c >= int(cameras_.size()) || !std::isfinite(T)) return 0;
    const CameraGeometry& g = cameras_[std::size_t(c)];
    const AsyncOptions& ao = config_.async;
    const BodySet& bodies = config_.bodies;
    last_field_us_[std::size_t(c)] = T;
    last_field_counter_[std::size_t(c)] = f.field_counter;
    const int nb = 1 + bodies.instrument_count;
    auto body_markers = [&](int b) -> std::pair<const BodyMarker*, int> {
        if (b == 0) return {bodies.eye.markers.data(), bodies.eye.marker_count};
        const InstrumentModel& m = bodies.instruments[std::size_t(b - 1)];
        return {m.markers.data(), m.marker_count};
    };
    // Association: each predicted marker takes the nearest image of its class within the gate unless a second
    // image is nearly as near; an image wanted by two predicted markers at nearly the same distance (two markers
    // merged in this view) goes to neither.
    std::array<double, kBodies> age_us{};
    std::uint32_t& tried = field_images_tried_[std::size_t(c)];  // images of this field a filter was offered
    if (first == 0) tried = 0;
    std::array<std::array<std::int8_t, kMaxBodyMarkers>, kBodies> cand{};
    std::array<float, kMaxMarkersPerCamera> claim_d{}, claim_d2{};
    std::array<std::int16_t, kMaxMarkersPerCamera> claim_by{};
    claim_d.fill(1e30f);
    claim_d2.fill(1e30f);
    claim_by.fill(-1);
    for (int b = 0; b < nb; ++b) {
        cand[std::size_t(b)].fill(-1);
        used_last_field_[std::size_t(b)] = 0;
        BodyFilter& flt = filters_[std::size_t(b)];
        // A filter that went without images for this long is not trusted to find them again: re-acquire.
        if (flt.tracking() && T - last_good_us_[std::size_t(b)] > ao.lost_after_us) flt.reset();
        if (replay_) replay_[std::size_t(b)].current = -1;
        if (!flt.tracking()) {
            if (replay_) replay_[std::size_t(b)].clear();
            continue;
        }
        // A field older than the filter's state (low-latency parts of cameras whose fields overlap arrive out
        // of time order) is fused at its own time (time_order_parts, below), or else as an aged observation.
        // Its images are associated here against the pose carried back to its time.
        age_us[std::size_t(b)] = std::max(0.0, flt.time_us() - T);
        if (b > 0 && ao.pivot_model) set_trocar_pivot(b);
        if (age_us[std::size_t(b)] == 0.0) {
            if (replay_) replay_begin(b, T);
            flt.predict_to(T);
        }
        const auto [ms, mc] = body_markers(b);
        for (int k = 0; k < mc; ++k) {
            Eigen::Vector2d px;
            if (!flt.predict_pixel(g, ms[k].pos_body_mm, px, age_us[std::size_t(b)])) continue;
            double d1 = 1e30, d2 = 1e30;
            int i1 = -1;
            // Over every image of the field so far (earlier parts included, so that ambiguity is judged as on a
            // whole field): an image an earlier part left unused (two predicted markers wanted it while the other
            // one's image was not read out yet) is taken now.
            for (int i = 0; i < f.count; ++i) {
                const FieldImage& im = f.images[std::size_t(i)];
                if (im.colour_class != ms[k].colour_class || !im.frame_px.allFinite()) continue;
                const double d = (im.frame_px - px).norm();
                if (d < d1) {
                    d2 = d1;
                    d1 = d;
                    i1 = i;
                } else if (d < d2) {
                    d2 = d;
                }
            }
            if (i1 < 0 || d1 > ao.gate_px || (d2 < ao.gate_px && d2 < ao.ambiguity_ratio * d1)) continue;
            if (!(tried & (1u << i1))) cand[std::size_t(b)][std::size_t(k)] = std::int8_t(i1);
            const float d = float(d1);
            if (d < claim_d[std::size_t(i1)]) {
                claim_d2[std::size_t(i1)] = claim_d[std::size_t(i1)];
                claim_d[std::size_t(i1)] = d;
                claim_by[std::size_t(i1)] = std::int16_t(b * kMaxBodyMarkers + k);
            } else {
                claim_d2[std::size_t(i1)] = std::min(claim_d2[std::size_t(i1)], d);
            }
        }
    }
    const double Rm = bodies.marker_radius_mm;
    const bool eye_model = config_.eye_occlusion_correction && bodies.eye.radius_mm > 0.0;
    const Eigen::Vector3d& eye_centre = bodies.eye.centre_rig_mm;
    const SphereFitConfig shading;  // the marker's shading model, as correct_eye_occlusion
    const double trocar_sigma_mm =
        config_.pose.trocar_sigma_mm * std::sqrt(double(cameras_.size()));  // applied once per camera field
    int accepted = 0;
    for (int b = 0; b < nb; ++b) {
        BodyFilter& flt = filters_[std::size_t(b)];
        int& field_used = field_used_[std::size_t(b)][std::size_t(c)];
        int& field_refused = field_refused_[std::size_t(b)][std::size_t(c)];
        if (first == 0) {  // a new field of this camera
            prev_field_used_[std::size_t(b)][std::size_t(c)] = field_used;
            field_used = 0;
            field_refused = 0;
        }
        if (!flt.tracking()) continue;
        const auto [ms, mc] = body_markers(b);
        const InstrumentModel* model = b > 0 ? &bodies.instruments[std::size_t(b - 1)] : nullptr;
        int used = 0;
        bool rewound = false;
        for (int k = 0; k < mc; ++k) {
            const int i = cand[std::size_t(b)][std::size_t(k)];
            if (i < 0 || claim_by[std::size_t(i)] != b * kMaxBodyMarkers + k ||
                claim_d2[std::size_t(i)] < float(ao.ambiguity_ratio) * claim_d[std::size_t(i)])
                continue;
            tried |= 1u << i;
            // An older part with an image for this body: the filter goes back to its time (once per part).
            if (replay_ && age_us[std::size_t(b)] > 0.0 && !rewound) {
                rewound = true;
                if (replay_rewind(b, T)) age_us[std::size_t(b)] = 0.0;
            }
            const FieldImage& im = f.images[std::size_t(i)];
            const Eigen::Vector3d X = flt.to_rig(ms[k].pos_body_mm);
            const double z = (g.R_cam_rig * X + g.t_cam_rig_mm).z();
            // The eye's outline across the marker's image (an eye marker at the limb, an instrument marker seen past
            // the eye): the visible part's centroid, off the centre by up to a radius, is moved back by the shaded
            // sphere less the eye (and the shaft) at the predicted pose, as the sync chain's correct_eye_occlusion.
            double ex_px = 0, ev_px = 0, visible = 1.0;
            bool eye_hides = false;
            const double r_mm = ms[k].radius_mm > 0.0 ? ms[k].radius_mm : Rm;
            const bool shaft = model && model->shaft_radius_mm > 0.0;
            if (eye_model) {
                eye_hides = r_mm > 0.0 &&
                            eye_hidden_offset(shading, g, X, r_mm, eye_centre, bodies.eye.radius_mm,
                                              shaft ? Eigen::Vector3d(flt.rotation() * model->axis_body.normalized())
                                                    : Eigen::Vector3d::Zero(),
                                              shaft ? model->shaft_radius_mm : 0.0, f.parity & 1, ex_px, ev_px, visible);
            }
            // Elsewhere the marker's image model at the predicted pose (TrackerConfig::marker_image_model): the
            // shaded sphere less its shaft, sampled on the field's lines.
            bool modelled = false;
            if (!eye_hides && config_.marker_image_model && r_mm > 0.0) {
                const bool strip = shaft && config_.shaft_occlusion_correction;
                modelled = image_model_offset(shading, g, X, r_mm,
                                              strip ? Eigen::Vector3d(flt.rotation() * model->axis_body.normalized())
                                                    : Eigen::Vector3d::Zero(),
                                              strip ? model->shaft_radius_mm : 0.0, f.parity & 1, ex_px, ev_px, visible);
                if (!modelled) ex_px = ev_px = 0.0, visible = 1.0;
            }
            if (eye_hides) {
                if (visible < kMinVisibleShare) continue;  // too little left to place it
            } else if (Rm > 0.0 && im.area_px > 0.0f && z > 0.0) {
                // A partly hidden marker (another instrument): its centroid is biased, leave it out.
                const double r = Rm / z;
                const double expected = 3.141592653589793 * (g.fx * r) * (g.fy * r) * 0.5;  // field pixels
                if (double(im.area_px) < ao.min_area_ratio * expected) continue;
            }
            if (modelled && visible < kMinVisibleShare) continue;  // its shaft hides almost all of it
            // Moved back by the eye's model, the image's σ grows with the shift: the correction is as good as the
            // outline is placed. The marker's own image model keeps the σ, as the strip shift did: its shift, the
            // shaft's, is placed by the pose within hundredths of a pixel, and a σ grown with it let the gate pass
            // images of an instrument pulled out of the eye that a miss should hold (`occlusion` seed 171: tip 26 ->
            // 99 um). The models hold the shaft, so the strip shift (apply_point) is not added again; it stays where
            // no model placed the marker.
            const bool moved = eye_hides || modelled;
            const Eigen::Vector2d px = moved ? Eigen::Vector2d(im.frame_px - Eigen::Vector2d(ex_px, ev_px)) : im.frame_px;
            const double grow_px = eye_hides ? kEyeCorrectionRelError * std::hypot(ex_px, ev_px) : 0.0;
            ReplayObs o;
            o.camera = std::int8_t(c);
            o.marker = std::int8_t(k);
            o.shaft = !(moved || !model || !config_.shaft_occlusion_correction || !(model->shaft_radius_mm > 0.0));
            o.px = o.shaft ? im.frame_px : px;
            o.sigma_x_px = ao.sigma_x_px + (o.shaft ? 0.0 : grow_px);
            o.sigma_y_px = ao.sigma_y_px + (o.shaft ? 0.0 : grow_px);
            const bool ok = apply_point(flt, b, o, age_us[std::size_t(b)]);
            if (replay_) replay_record(b, o);
            if (!ok) {
                ++field_refused;
                continue;
            }
            eye_model_views_ += eye_hides;
            ++used;
            seen_us_[std::size_t(b)][std::size_t(k)][std::size_t(c)] = T;
        }
        accepted += used;
        field_used += used;
        // The newer parts again after an older one (the filter back at its newest time).
        if (rewound && age_us[std::size_t(b)] == 0.0) replay_finish(b);
        // The trocar prior once per field (at its last part), when the field gave the instrument an image. The
        // instrument always passes through its trocar, so the line is applied to the newest state, not at the
        // field's time (at the field's time, on held-out `surgery` and `fast` 2 s seeds 85-89, the tip was 7-13 %
        // worse: the newer images then carry the state away from the line), and kept with that newest time's
        // images for a replay.
        Eigen::Vector3d p;
        if (last && model && field_used > 0 && trocar_depth_mm(b, &p) > 0.0) {
            flt.update_line_through(model->tip_body_mm, model->axis_body.normalized(), p, trocar_sigma_mm);
            if (replay_) {
                ReplayObs o;
                o.p_rig_mm = p;
                o.sigma_mm = trocar_sigma_mm;
                replay_record_newest(b, o);
            }
        }
        used_last_field_[std::size_t(b)] = field_used;
        // One camera alone leaves an instrument's depth to the motion model: a filter fed only by it drifts (by
        // centimetres within 0.1 s when the other views are occluded) while its images still fit. It supports the
        // body only while another camera has seen one of its markers within about a field period. The eye turns
        // about a known centre, which one view determines.
        // After a miss (hold_on_miss, below) only another camera's image since the miss counts: an instrument
        // pulled along its shaft can move nearly along one camera's line of sight, whose images then still fit the
        // prediction that is a millimetre or more behind (`occlusion` seed 269: one camera's images rejected, the
        // next camera's accepted, the frame reported measured 1.5 mm behind the needle).
        const bool missed = missed_us_[std::size_t(b)] > last_good_us_[std::size_t(b)];
        bool other_view = b == 0;
        for (int c2 = 0; c2 < int(cameras_.size()) && !other_view; ++c2) {
            if (c2 == c) continue;
            for (int k = 0; k < mc && !other_view; ++k) {
                const double seen = seen_us_[std::size_t(b)][std::size_t(k)][std::size_t(c2)];
                other_view = T - seen <= ao.other_view_fields * config_.sync.field_period_us &&
                             !(missed && seen <= missed_us_[std::size_t(b)]);
            }
        }
        // An instrument's field in which the filter refused any image inside the gate (normalised innovation above
        // nis_gate) is a miss as well, and supports nothing, though it took others: at the onset of a fast push or
        // pull, the images taken each pull the filter part of the way, and the frame went out measured a millimetre
        // behind (`occlusion` seed 275 with the refinement stage: one of camera 0's three images refused, two taken,
        // the tip 1.05 mm off).
        const bool consistent = b == 0 || !ao.hold_on_miss || field_refused == 0;
        if (!consistent) missed_us_[std::size_t(b)] = std::max(missed_us_[std::size_t(b)], T);
        if (field_used >= ao.min_markers_good && consistent)
            supported_us_[std::size_t(b)][std::size_t(c)] = std::max(supported_us_[std::size_t(b)][std::size_t(c)], T);
        if (field_used >= ao.min_markers_good && other_view && consistent)
            last_good_us_[std::size_t(b)] = std::max(last_good_us_[std::size_t(b)], T);
        if (T - last_good_us_[std::size_t(b)] > ao.lost_after_us || flt.position_sigma_mm() > ao.max_position_sigma_mm ||
            !flt.translation().allFinite() || !flt.rotation().coeffs().allFinite())
            flt.reset();
    }
    // An instrument that a camera's field before supported (min_markers_good images) and whose whole field now
    // shows none of the two or more markers the filter puts in that image has gone from where the filter puts it:
    // its pose is reported held (not measured) until a field supports it again. An instrument pulled out of the
    // eye, or pushed in, at up to a metre a second leaves the 6 px gate within a field, and the prediction from the
    // last supporting field, up to 0.75 of a period old, was reported as measured 1–2 mm off (`occlusion`). Only a
    // change counts: a camera that has not seen the body for a while (behind the eye, another instrument) would
    // otherwise hold it at every one of its fields (docs/tracking.md, "Acquisition and loss").
    // With low-latency parts this is decided at each part, over the markers the readout has passed: images arrive in
    // the order their blobs complete, so a marker predicted more than two gates above the lowest image of the field
    // so far would have been among them. Decided only at the field's last part, the parts before it reported the
    // prediction as measured, up to 1.6 mm off for a field (`occlusion`, an instrument pushed into the eye).
    if (ao.hold_on_miss) {
        double read_px = std::numeric_limits<double>::infinity();
        if (!last) {
            read_px = -read_px;
            for (int i = 0; i < f.count; ++i) read_px = std::max(read_px, f.images[std::size_t(i)].frame_px.y());
            read_px -= 2.0 * ao.gate_px;
        }
        for (int b = 1; b < nb; ++b) {
            const BodyFilter& flt = filters_[std::size_t(b)];
            if (!flt.tracking() || field_used_[std::size_t(b)][std::size_t(c)] > 0 ||
                prev_field_used_[std::size_t(b)][std::size_t(c)] < ao.min_markers_good)
                continue;
            const auto [ms, mc] = body_markers(b);
            int in_view = 0;
            for (int k = 0; k < mc; ++k) {
                Eigen::Vector2d px;
                if (!flt.predict_pixel(g, ms[k].pos_body_mm, px, std::max(0.0, flt.time_us() - T))) continue;
                // Inside the image (its extent taken as twice the principal point), clear of its edge.
                constexpr double kMarginPx = 8.0;
                in_view += px.x() > kMarginPx && px.y() > kMarginPx && px.x() < 2.0 * g.cx - kMarginPx &&
                           px.y() < 2.0 * g.cy - kMarginPx && px.y() < read_px;
            }
            if (in_view >= 2) missed_us_[std::size_t(b)] = std::max(missed_us_[std::size_t(b)], T);
        }
    }
    return accepted;
}

bool Tracker::apply_point(BodyFilter& flt, int b, const ReplayObs& o, double age_us) {
    const BodySet& bodies = config_.bodies;
    const InstrumentModel* model = b > 0 ? &bodies.instruments[std::size_t(b - 1)] : nullptr;
    if (o.marker < 0) {
        if (!model) return false;
        flt.update_line_through(model->tip_body_mm, model->axis_body.normalized(), o.p_rig_mm, o.sigma_mm);
        return true;
    }
    const CameraGeometry& g = cameras_[std::size_t(o.camera)];
    const Eigen::Vector3d& pos = model ? model->markers[std::size_t(o.marker)].pos_body_mm
                                       : bodies.eye.markers[std::size_t(o.marker)].pos_body_mm;
    const double nis_gate = config_.async.nis_gate;
    if (!o.shaft || !model)
        return flt.update_point(g, pos, o.px, o.sigma_x_px, o.sigma_y_px, nis_gate,
                                [](const Eigen::Quaterniond&, const Eigen::Vector3d&, const Eigen::Vector3d&) {
                                    return Eigen::Vector2d::Zero().eval();
                                },
                                nullptr, age_us);
    const Eigen::Vector3d axis_body = model->axis_body.normalized();
    const double shaft_r = model->shaft_radius_mm, Rm = bodies.marker_radius_mm;
    return flt.update_point(g, pos, o.px, o.sigma_x_px, o.sigma_y_px, nis_gate,
                            [&](const Eigen::Quaterniond& R, const Eigen::Vector3d&, const Eigen::Vector3d& Xr) {
                                return shaft_occlusion_shift(g, Xr, R * axis_body, Rm, shaft_r);
                            },
                            nullptr, age_us);
}

void Tracker::replay_begin(int b, double t_us) {
    ReplayHistory& h = replay_[std::size_t(b)];
    const BodyFilter& flt = filters_[std::size_t(b)];
    if (h.count > 0) {
        const int newest = h.order[std::size_t(h.count - 1)];
        if (h.pool[std::size_t(newest)].t_us == t_us) {  // another part of the same field: the same time
            h.current = newest;
            return;
        }
    }
    h.current = h.insert(h.count, t_us, flt);
    h.replay_from = h.count;
}

int Tracker::ReplayHistory::insert(int pos, double t_us, const BodyFilter& before) {
    if (count == kReplayEpochs) {  // the oldest time leaves the history (pos > 0: it is older than the new one)
        free |= 1u << order[0];
        std::copy(order.begin() + 1, order.begin() + count, order.begin());
        --count;
        --pos;
    }
    const int slot = std::countr_zero(free);
    free &= ~(1u << slot);
    ReplayEpoch& e = pool[std::size_t(slot)];
    e.t_us = t_us;
    e.before.assign_state(before);
    e.n_obs = 0;
    std::copy_backward(order.begin() + pos, order.begin() + count, order.begin() + count + 1);
    order[std::size_t(pos)] = std::uint8_t(slot);
    ++count;
    return slot;
}

bool Tracker::replay_rewind(int b, double t_us) {
    ReplayHistory& h = replay_[std::size_t(b)];
    BodyFilter& flt = filters_[std::size_t(b)];
    // The first recorded time at or after the part's.
    int pos = 0;
    while (pos < h.count && h.pool[std::size_t(h.order[std::size_t(pos)])].t_us < t_us) ++pos;
    if (pos == h.count) return false;
    ReplayEpoch& at = h.pool[std::size_t(h.order[std::size_t(pos)])];
    if (!at.before.tracking() || at.before.time_us() > t_us) return false;  // the history begins after it
    const bool same_time = at.t_us == t_us;
    if (!same_time && h.count == kReplayEpochs && pos == 0) return false;  // no room before the oldest
    ++replayed_parts_;
    if (same_time) {
        // A later part of a field already fused: this part's images after that field's. The filter as it was
        // after them is the next time's `before` (there is one: else the field's time were the newest and the
        // part not older); without it, that field's images are applied again.
        if (pos + 1 < h.count) {
            flt.assign_state(h.pool[std::size_t(h.order[std::size_t(pos + 1)])].before);
        } else {
            flt.assign_state(at.before);
            flt.predict_to(t_us);
            for (int k = 0; k < at.n_obs; ++k) apply_point(flt, b, at.obs[std::size_t(k)], 0.0);
        }
        h.current = h.order[std::size_t(pos)];
        h.replay_from = pos + 1;
        return true;
    }
    flt.assign_state(at.before);
    const bool evicts = h.count == kReplayEpochs;
    h.current = h.insert(pos, t_us, flt);
    h.replay_from = (evicts ? pos - 1 : pos) + 1;
    flt.predict_to(t_us);
    return true;
}

void Tracker::replay_record(int b, const ReplayObs& o) {
    ReplayHistory& h = replay_[std::size_t(b)];
    if (h.current < 0) return;
    ReplayEpoch& e = h.pool[std::size_t(h.current)];
    if (e.n_obs == int(e.obs.size())) return;  // more than a field's images of one body: not held (never seen)
    e.obs[std::size_t(e.n_obs++)] = o;
}

void Tracker::replay_record_newest(int b, const ReplayObs& o) {
    ReplayHistory& h = replay_[std::size_t(b)];
    if (h.count == 0 || filters_[std::size_t(b)].time_us() != h.pool[std::size_t(h.order[std::size_t(h.count - 1)])].t_us)
        return;  // the filter is not at a time the history holds (an older part fused aged): not kept
    h.current = h.order[std::size_t(h.count - 1)];
    replay_record(b, o);
}

void Tracker::replay_finish(int b) {
    ReplayHistory& h = replay_[std::size_t(b)];
    BodyFilter& flt = filters_[std::size_t(b)];
    for (int j = h.replay_from; j < h.count; ++j) {
        ReplayEpoch& e = h.pool[std::size_t(h.order[std::size_t(j)])];
        e.before.assign_state(flt);
        flt.predict_to(e.t_us);
        for (int k = 0; k < e.n_obs; ++k) apply_point(flt, b, e.obs[std::size_t(k)], 0.0);
    }
    h.current = -1;
}

void Tracker::acquire(const CameraField& f) {
    acquired_this_field_ = false;
    acquire_due_ = true;
    acquire_due_us_ = f.sample_device_us;
    acquire_due_frame();
}

void Tracker::acquire_due_frame() {
    const int nb = 1 + config_.bodies.instrument_count;
    bool any_lost = false;
    for (int b = 0; b < nb; ++b) any_lost = any_lost || !filters_[std::size_t(b)].tracking();
    if (!any_lost) {
        acquire_due_ = false;
        return;
    }
    // The synchroniser's frame at this field (other cameras extrapolated to its time). Not ready yet where
    // another camera's field exposed with it is still to come (a genlocked rig): tried again as fields complete.
    double T = 0, end_dev = 0, recv_host = 0;
    std::uint32_t ref = 0;
    bool got = false;
    while (sync_.pop(T, ref, acquire_cams_, aligned_, end_dev, recv_host)) {
        got = true;
        if (T > acquire_due_us_ - 1.0) break;
    }
    if (!got || !(T > acquire_due_us_ - 1.0)) return;  // only older frames were ready
    acquire_due_ = false;
    if (std::abs(T - acquire_due_us_) > 1.0) return;
    // History for the fit: bodies being tracked at their filtered pose (they keep their markers), lost ones at
    // their last acquisition fit if it was the previous frame.
    const BodySet& bodies = config_.bodies;
    const double period = config_.sync.field_period_us;
    if (filters_[0].tracking()) {
        eye_from_filter(bodies.eye, filters_[0].rotation(), last_eye_);
        last_eye_.markers_used = used_last_field_[0];
    } else if (!(acquire_measured_[0] && T - acquire_t_us_[0] < 2.5 * period)) {
        last_eye_ = EyePose{};
    }
    for (int b = 1; b < nb; ++b) {
        const InstrumentModel& m = bodies.instruments[std::size_t(b - 1)];
        InstrumentPose& p = last_instruments_[std::size_t(b - 1)];
        const BodyFilter& flt = filters_[std::size_t(b)];
        if (flt.tracking()) {
            instrument_from_filter(m, flt.rotation(), flt.translation(), m.markers_on_axis(), p);
            instrument_in_eye(m, last_eye_, p);
        } else if (!(acquire_measured_[std::size_t(b)] && T - acquire_t_us_[std::size_t(b)] < 2.5 * period)) {
            p = InstrumentPose{};
        }
    }
    std::array<bool, kMaxCameras> present{};
    for (int c = 0; c < int(cameras_.size()); ++c)
        present[std::size_t(c)] = acquire_cams_[std::size_t(c)].state != CameraSyncState::Missing;
    track_images(std::span<const CameraField>(aligned_.data(), cameras_.size()),
                 std::span<const bool>(present.data(), cameras_.size()), acquire_frame_);
    acquired_this_field_ = true;
    for (int b = 0; b < nb; ++b) {
        BodyFilter& flt = filters_[std::size_t(b)];
        if (flt.tracking()) continue;
        Eigen::Quaterniond R;
        Eigen::Vector3d t;
        bool measured = false;
        Eigen::Vector3d roll_axis = Eigen::Vector3d::Zero();
        if (b == 0) {
            measured = acquire_frame_.eye.measured();
            R = acquire_frame_.eye.rotation_eye_to_rig;
            t = bodies.eye.centre_rig_mm;
        } else {
            const InstrumentModel& m = bodies.instruments[std::size_t(b - 1)];
            const InstrumentPose& p = acquire_frame_.instruments[std::size_t(b - 1)];
            measured = p.measured();
            R = p.rotation_body_to_rig;
            t = p.tip_rig_mm - R * m.tip_body_mm;
            if (m.markers_on_axis()) roll_axis = p.axis_rig;
        }
        const double dt_us = T - acquire_t_us_[std::size_t(b)];
        const bool two_fits = measured && acquire_measured_[std::size_t(b)] && dt_us > 1.0 && dt_us < 2.5 * period;
        const bool eye_at_rest = b == 0 && measured && config_.async.eye_filter_from_one_fit;
        if (two_fits || eye_at_rest) {
            // The eye from one fit, at rest (AsyncOptions::eye_filter_from_one_fit); else two fits in a row: start
            // with their velocity.
            Eigen::Vector3d w = Eigen::Vector3d::Zero(), v = Eigen::Vector3d::Zero();
            if (!eye_at_rest) {
                const double dt = dt_us * 1e-6;
                const Eigen::AngleAxisd d(R * acquire_R_[std::size_t(b)].conjugate());
                w = d.axis() * d.angle() / dt;
                if (!roll_axis.isZero()) w -= w.dot(roll_axis) * roll_axis;  // no roll rate where roll is not seen
                v = (t - acquire_t_mm_[std::size_t(b)]) / dt;
            }
            flt.init(T, R, t, w, v, 2e-3, 0.05, 0.3, 10.0);
            if (replay_) replay_[std::size_t(b)].clear();
            last_good_us_[std::size_t(b)] = T;
            missed_us_[std::size_t(b)] = kNever;
            for (auto& m : seen_us_[std::size_t(b)]) m.fill(kNever);
            // The cameras whose images the fit triangulated (min_markers_good of the body's) support it now.
            std::array<int, kMaxCameras> images{};
            for (int k = 0; k < acquire_frame_.markers.count; ++k)
                if (acquire_frame_.assignment.body[std::size_t(k)] == b)
                    for (int c = 0; c < int(cameras_.size()); ++c)
                        images[std::size_t(c)] += acquire_frame_.markers.markers[std::size_t(k)].image_index[std::size_t(c)] >= 0;
            for (int c = 0; c < int(cameras_.size()); ++c)
                if (images[std::size_t(c)] >= config_.async.min_markers_good) supported_us_[std::size_t(b)][std::size_t(c)] = T;
        }
        acquire_measured_[std::size_t(b)] = measured;
        acquire_t_us_[std::size_t(b)] = T;
        acquire_R_[std::size_t(b)] = R;
        acquire_t_mm_[std::size_t(b)] = t;
    }
}

void Tracker::held_bodies(double T, std::array<bool, kBodies>& held) const {
    const AsyncOptions& ao = config_.async;
    const int ncam = int(cameras_.size());
    // An instrument needs two cameras that each gave it min_markers_good images lately (AsyncOptions::two_view_support).
    const auto one_view = [&](int b) {
        if (b == 0 || !ao.two_view_support) return false;
        int views = 0;
        for (int c = 0; c < ncam; ++c)
            views += T - supported_us_[std::size_t(b)][std::size_t(c)] <= ao.other_view_fields * config_.sync.field_period_us;
        return views < 2;
    };
    // A tracked body that no field supported lately is coasting on its prediction: held.
    for (int b = 0; b < 1 + config_.bodies.instrument_count; ++b)
        held[std::size_t(b)] =
            T - last_good_us_[std::size_t(b)] > ao.held_after_fields * config_.sync.field_period_us ||
            missed_us_[std::size_t(b)] > last_good_us_[std::size_t(b)] || one_view(b) ||
            (b > 0 && filters_[std::size_t(b)].position_sigma_mm() > ao.held_position_sigma_mm);
}

void Tracker::build_async_frame(const CameraField& f, TrackingFrame& out, const PendingFrame* smooth) {
    const BodySet& bodies = config_.bodies;
    const AsyncOptions& ao = config_.async;
    const double T = f.sample_device_us;
    const int ncam = int(cameras_.size());
    const int nb = 1 + bodies.instrument_count;
    out.index = async_frames_++;
    out.one_view_mask = 0;
    out.reference_field = f.field_counter;
    out.time_device_us = T;
    out.flags = kFrameOk;
    out.camera_count = ncam;
    out.cameras_used = 0;
    for (int c = 0; c < kMaxCameras; ++c) {
        AlignedCamera& ac = out.cameras[std::size_t(c)];
        ac = AlignedCamera{};
        if (c >= ncam || !(T - last_field_us_[std::size_t(c)] < 1.5 * config_.sync.field_period_us)) continue;
        ac.state = CameraSyncState::Direct;
        ac.dt_us = last_field_us_[std::size_t(c)] - T;
        ac.field_a = ac.field_b = last_field_counter_[std::size_t(c)];
        ++out.cameras_used;
    }
    if (out.cameras_used < ncam) out.flags |= kFrameTwoView;
    if (out.cameras_used < 2) out.flags |= kFrameTooFewCameras;
    out.images_in = f.count;
    out.images_dropped_sync = 0;
    out.markers.count = 0;
    out.markers.unmatched_images = 0;
    out.markers.rejected_hypotheses = 0;
    out.assignment.body.fill(-1);
    out.assignment.marker.fill(-1);
    out.markers_unassigned = 0;
    // Once per body: the pose flags and the markers below both read it. A fixed-lag frame's are decided when it is
    // reported: a miss that a later part found (an instrument pulled out just after T) holds it too. Decided as
    // its newest part left them instead, 6 more of 2,000 instrument frames went out measured on held-out 2 s
    // `occlusion` recordings and the worst 3D error over all markers rose from 25 to 54 um (docs/validation.md,
    // "Fixed-lag frames").
    std::array<bool, kBodies> coasting{};
    held_bodies(T, coasting);
    // Each filter's pose at the frame's time (a state that a later camera's part already moved on is carried back).
    std::array<Eigen::Quaterniond, kBodies> R_at;
    std::array<Eigen::Vector3d, kBodies> t_at;
    for (int b = 0; b < nb; ++b) {
        const BodyFilter& flt = filters_[std::size_t(b)];
        if (!flt.tracking()) continue;
        // A fixed-lag frame: the filter as it was at T is the parts history's `before` of the first time after T
        // (all images up to T fused), smoothed by the state now (BodyFilter::smoothed_pose_at).
        const BodyFilter* then = nullptr;
        if (smooth && replay_) {
            const ReplayHistory& h = replay_[std::size_t(b)];
            for (int i = 0; i < h.count; ++i) {
                const ReplayEpoch& e = h.pool[std::size_t(h.order[std::size_t(i)])];
                if (e.t_us <= T) continue;
                if (e.before.tracking() && e.before.time_us() <= T) then = &e.before;
                break;
            }
        }
        if (then) {
            flt.smoothed_pose_at(*then, T, R_at[std::size_t(b)], t_at[std::size_t(b)]);
            ++smoothed_poses_;
        } else
            flt.pose_at(T, R_at[std::size_t(b)], t_at[std::size_t(b)]);
    }
    // Eye.
    if (filters_[0].tracking()) {
        eye_from_filter(bodies.eye, R_at[0], out.eye);
        out.eye.markers_used = used_last_field_[0];
        if (coasting[0]) out.eye.flags |= kPoseHeld;
    } else if (acquired_this_field_ && acquire_frame_.eye.measured()) {
        out.eye = acquire_frame_.eye;
    } else {
        out.eye.centre_rig_mm = bodies.eye.centre_rig_mm;
        out.eye.flags = kPoseTooFewMarkers | kPoseHeld;
    }
    out.instrument_count = bodies.instrument_count;
    for (int b = 1; b < nb; ++b) {
        const InstrumentModel& m = bodies.instruments[std::size_t(b - 1)];
        InstrumentPose& p = out.instruments[std::size_t(b - 1)];
        const BodyFilter& flt = filters_[std::size_t(b)];
        if (flt.tracking()) {
            instrument_from_filter(m, R_at[std::size_t(b)], t_at[std::size_t(b)], m.markers_on_axis(), p);
            p.markers_used = used_last_field_[std::size_t(b)];
            if (coasting[std::size_t(b)]) p.flags |= kPoseHeld;
        } else if (acquired_this_field_ && acquire_frame_.instruments[std::size_t(b - 1)].measured()) {
            p = acquire_frame_.instruments[std::size_t(b - 1)];
            if (ao.hold_acquisition_fit) p.flags |= kPoseHeld;  // AsyncOptions::hold_acquisition_fit
        } else {
            p.flags = kPoseTooFewMarkers | kPoseHeld;
        }
        p.opening = opening_;
        instrument_in_eye(m, out.eye, p);
    }
    // Markers: those of a tracked body seen by two cameras lately, where the filter puts them; a body acquired
    // from this frame's triangulation brings its triangulated markers (an instrument's only where its fit is not
    // held).
    for (int b = 0; b < nb; ++b) {
        const BodyFilter& flt = filters_[std::size_t(b)];
        const int mc = b == 0 ? bodies.eye.marker_count : bodies.instruments[std::size_t(b - 1)].marker_count;
        const BodyMarker* ms = b == 0 ? bodies.eye.markers.data() : bodies.instruments[std::size_t(b - 1)].markers.data();
        if (flt.tracking() && !coasting[std::size_t(b)]) {  // a held body's markers are where its prediction puts them: left out
            for (int k = 0; k < mc && out.markers.count < kMaxMarkersPerFrame; ++k) {
                int views = 0;
                for (int c = 0; c < ncam; ++c)
                    if (T - seen_us_[std::size_t(b)][std::size_t(k)][std::size_t(c)] <= ao.marker_recent_us) ++views;
                if (views < 2) continue;
                MatchedMarker& mk = out.markers.markers[std::size_t(out.markers.count)];
                mk = MatchedMarker{};
                mk.colour_class = ms[k].colour_class;
                mk.point.X_rig_mm = R_at[std::size_t(b)] * ms[k].pos_body_mm + t_at[std::size_t(b)];
                mk.point.cov_mm2 = flt.covariance().block<3, 3>(3, 3);
                mk.point.views = views;
                mk.image_index.fill(-1);
                out.assignment.body[std::size_t(out.markers.count)] = std::int8_t(b);
                out.assignment.marker[std::size_t(out.markers.count)] = std::int8_t(k);
                ++out.markers.count;
            }
        } else if (acquired_this_field_ && !(b > 0 && ao.hold_acquisition_fit)) {
            for (int k = 0; k < acquire_frame_.markers.count && out.markers.count < kMaxMarkersPerFrame; ++k) {
                if (acquire_frame_.assignment.body[std::size_t(k)] != b) continue;
                MatchedMarker& mk = out.markers.markers[std::size_t(out.markers.count)];
                mk = acquire_frame_.markers.markers[std::size_t(k)];
                mk.image_index.fill(-1);
                out.assignment.body[std::size_t(out.markers.count)] = std::int8_t(b);
                out.assignment.marker[std::size_t(out.markers.count)] = acquire_frame_.assignment.marker[std::size_t(k)];
                ++out.markers.count;
            }
        }
    }
}

bool Tracker::pose_at(double t_device_us, EyePose& eye, std::span<InstrumentPose> instruments) const {
    if (config_.sync.mode != SyncMode::Async) return false;
    const BodySet& bodies = config_.bodies;
    bool any = false;
    Eigen::Quaterniond R;
    Eigen::Vector3d t;
    if (filters_[0].tracking()) {
        filters_[0].display_pose_at(t_device_us, R, t);
        eye_from_filter(bodies.eye, R, eye);
        any = true;
    }
    for (int b = 0; b < bodies.instrument_count && b < int(instruments.size()); ++b) {
        const BodyFilter& flt = filters_[std::size_t(1 + b)];
        if (!flt.tracking()) continue;
        const InstrumentModel& m = bodies.instruments[std::size_t(b)];
        flt.display_pose_at(t_device_us, R, t);
        instrument_from_filter(m, R, t, m.markers_on_axis(), instruments[std::size_t(b)]);
        instrument_in_eye(m, eye, instruments[std::size_t(b)]);
        any = true;
    }
    return any;
}

}  // namespace eyesim::tracking
