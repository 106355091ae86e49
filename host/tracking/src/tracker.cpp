#include "eyesim/tracking/tracker.hpp"

#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

namespace eyesim::tracking {

namespace {

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
    // correspondence_ holds a span over cameras_, which is never resized after construction.
}

void Tracker::restart() {
    for (const FieldAssembler& a : assemblers_) rejected_before_restart_ += a.rejected_images();
    assemblers_.fill(FieldAssembler{});
    sync_ = FrameSync(int(cameras_.size()), config_.sync);
    last_eye_ = EyePose{};
    last_instruments_.fill(InstrumentPose{});
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
    for (int i = 0; i < done; ++i) sync_.add(as.completed(i));
}

void Tracker::push(const protocol::PedalState& pedal, double /*received_host_us*/) {
    const int axis = config_.opening_pedal_axis;
    if (axis >= 0 && axis < int(protocol::kPedalAxisCount)) opening_ = pedal.axes[std::size_t(axis)] / 65535.0;
}

bool Tracker::pop(TrackingFrame& out, double now_host_us) {
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
    for (int b = 0; b < out.instrument_count; ++b) out.instruments[std::size_t(b)].opening = opening_;
    fit_poses(config_.bodies, out.markers, config_.pose, last_eye_,
              std::span<const InstrumentPose>(last_instruments_.data(), std::size_t(out.instrument_count)), out.eye,
              std::span<InstrumentPose>(out.instruments.data(), std::size_t(out.instrument_count)), out.assignment);
    if (config_.shaft_occlusion_correction) correct_shaft_occlusion(out);
    last_eye_ = out.eye;
    for (int b = 0; b < out.instrument_count; ++b) last_instruments_[std::size_t(b)] = out.instruments[std::size_t(b)];
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

/// Centroid shift (normalised image units, along the projected half-shaft) of a uniform disk of radius rho from
/// which a strip of half-width w, starting at t0 from the centre and running to the rim, is hidden.
double strip_centroid_shift(double rho, double w, double t0) {
    if (!(t0 < rho) || !(w > 0.0)) return 0.0;
    constexpr int kSteps = 16;
    const double dt = (rho - t0) / kSteps;
    double area = 0.0, moment = 0.0;
    for (int k = 0; k < kSteps; ++k) {
        const double t = t0 + (k + 0.5) * dt;
        const double half = std::min(w, std::sqrt(std::max(0.0, rho * rho - t * t)));
        area += 2.0 * half * dt;
        moment += t * 2.0 * half * dt;
    }
    const double disk = 3.141592653589793 * rho * rho;
    return -moment / std::max(disk - area, 1e-3 * disk);
}

}  // namespace

void Tracker::correct_shaft_occlusion(TrackingFrame& out) {
    const BodySet& bodies = config_.bodies;
    const double R = bodies.marker_radius_mm;
    if (!(R > 0.0)) return;
    bool changed = false;
    std::array<Observation, kMaxCameras> obs;
    std::array<int, kMaxCameras> obs_view{};
    for (int k = 0; k < out.markers.count; ++k) {
        const int body = out.assignment.body[std::size_t(k)];
        if (body < 1) continue;
        const InstrumentModel& model = bodies.instruments[std::size_t(body - 1)];
        const InstrumentPose& pose = out.instruments[std::size_t(body - 1)];
        if (!pose.measured() || !(model.shaft_radius_mm > 0.0)) continue;
        MatchedMarker& m = out.markers.markers[std::size_t(k)];
        const Eigen::Vector3d X = m.point.X_rig_mm;
        const Eigen::Vector3d a = pose.axis_rig;
        int n = 0;
        for (int c = 0; c < int(cameras_.size()); ++c) {
            const int i = m.image_index[std::size_t(c)];
            if (i < 0 || (m.occluded_views & (1u << c))) continue;
            const CameraGeometry& g = cameras_[std::size_t(c)];
            const ImagePoint& p = views_[std::size_t(c)].points[std::size_t(i)];
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
        if (n < 2) continue;
        const TriangulatedPoint tp = triangulate(cameras_, std::span<const Observation>(obs.data(), std::size_t(n)),
                                                 config_.correspondence.triangulation);
        if (tp.usable()) {
            m.point = tp;
            changed = true;
            for (int v = 0; v < n; ++v) {
                const int c = obs_view[std::size_t(v)];
                corrected_views_[std::size_t(k)] |= std::uint8_t(1u << c);
                corrected_xn_[std::size_t(k)][std::size_t(c)] = obs[std::size_t(v)].xn;
            }
        }
    }
    if (!changed) return;
    // Refit every body with the corrected markers (same history as the first fit).
    for (int b = 0; b < out.instrument_count; ++b) out.instruments[std::size_t(b)].opening = opening_;
    fit_poses(bodies, out.markers, config_.pose, last_eye_,
              std::span<const InstrumentPose>(last_instruments_.data(), std::size_t(out.instrument_count)), out.eye,
              std::span<InstrumentPose>(out.instruments.data(), std::size_t(out.instrument_count)), out.assignment);
}

}  // namespace eyesim::tracking
