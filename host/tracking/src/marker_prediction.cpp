#include "eyesim/tracking/marker_prediction.hpp"

#include "eyesim/tracking/distortion.hpp"
#include "eyesim/tracking/tracker.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>

namespace eyesim::tracking {

bool project_sphere_outline(const CameraGeometry& cam, const Eigen::Vector3d& centre_rig_mm, double radius_mm,
                            ProjectedOutline& out) {
    const Eigen::Vector3d c = cam.R_cam_rig * centre_rig_mm + cam.t_cam_rig_mm;
    const double dist = c.norm();
    if (!(radius_mm > 0) || !(dist > 2.0 * radius_mm) || !(c.z() > radius_mm)) return false;
    // The circle where the camera's tangent cone touches the sphere, projected point by point through the camera
    // model (distortion bends it), then one conic through the points.
    const Eigen::Vector3d d = c / dist;
    const Eigen::Vector3d u = d.unitOrthogonal(), w = d.cross(u);
    const double back = radius_mm * radius_mm / dist, rad = radius_mm * std::sqrt(1.0 - back / dist);
    const Eigen::Matrix3d rt = cam.R_cam_rig.transpose();
    const Eigen::Vector3d centre_cam = c - back * d;
    constexpr int kPoints = 24;
    Eigen::Vector2d p0;
    if (!project_point(cam, centre_rig_mm, p0)) return false;
    Eigen::Matrix<double, 5, 5> ata = Eigen::Matrix<double, 5, 5>::Zero();
    Eigen::Matrix<double, 5, 1> atb = Eigen::Matrix<double, 5, 1>::Zero();
    for (int k = 0; k < kPoints; ++k) {
        const double phi = 2.0 * M_PI * k / kPoints;
        const Eigen::Vector3d q_cam = centre_cam + rad * (std::cos(phi) * u + std::sin(phi) * w);
        Eigen::Vector2d px;
        if (!project_point(cam, rt * (q_cam - cam.t_cam_rig_mm), px)) return false;
        const double x = px.x() - p0.x(), y = px.y() - p0.y();
        // A·x² + 2B·x·y + C·y² + 2D·x + 2E·y = 1 about the centre's projection (well conditioned).
        const Eigen::Matrix<double, 5, 1> row(x * x, 2 * x * y, y * y, 2 * x, 2 * y);
        ata += row * row.transpose();
        atb += row;
    }
    const Eigen::Matrix<double, 5, 1> s = ata.ldlt().solve(atb);
    Eigen::Matrix2d m;
    m << s(0), s(1), s(1), s(2);
    const Eigen::Vector2d b(s(3), s(4));
    if (!s.allFinite() || !(m.determinant() > 0) || !(m.trace() > 0)) return false;
    const Eigen::Vector2d off = -m.inverse() * b;
    const double k = 1.0 + b.dot(m.inverse() * b), norm = 2.0 / m.trace();
    out.x_px = p0.x() + off.x();
    out.v_px = p0.y() + off.y();
    out.r_px = std::sqrt(k * norm);
    out.e1 = 0.5 * (m(0, 0) - m(1, 1)) * norm;
    out.e2 = m(0, 1) * norm;
    return std::isfinite(out.r_px);
}

namespace {

// The hint's view-frame axes for a marker at `centre_rig_mm`: d along the line of sight from the camera, ex and ey
// across it.
void view_axes(const CameraGeometry& cam, const Eigen::Vector3d& centre_rig_mm, Eigen::Vector3d& ex, Eigen::Vector3d& ey,
               Eigen::Vector3d& d) {
    d = (centre_rig_mm - cam.centre_rig_mm()).normalized();
    ex = d.unitOrthogonal();
    ey = d.cross(ex);
}

// A sphere (the eye, or another marker nearer the camera) as the hint's occluder, in the view frame (ex, ey, d) of
// the marker at `centre_rig_mm`: centre and radius in marker radii.
void set_sphere_occluder(const Eigen::Vector3d& ex, const Eigen::Vector3d& ey, const Eigen::Vector3d& d,
                         const Eigen::Vector3d& centre_rig_mm, double radius_mm, const Eigen::Vector3d& occ_centre_rig_mm,
                         double occ_radius_mm, MarkerHint& out, bool second = false) {
    const Eigen::Vector3d e = (occ_centre_rig_mm - centre_rig_mm) / radius_mm;
    double* view = second ? out.occluder2_view : out.occluder_view;
    view[0] = e.dot(ex);
    view[1] = e.dot(ey);
    view[2] = e.dot(d);
    (second ? out.occluder2_radius : out.occluder_radius) = occ_radius_mm / radius_mm;
}

// The hint's view frame for a marker: outline prior and the map from frame px to marker radii; `ex`, `ey`, `d`
// the view frame's axes in the rig frame.
bool view_frame(const CameraGeometry& cam, const Eigen::Vector3d& centre_rig_mm, double radius_mm, MarkerHint& out,
                Eigen::Vector3d& ex, Eigen::Vector3d& ey, Eigen::Vector3d& d) {
    ProjectedOutline o;
    if (!project_sphere_outline(cam, centre_rig_mm, radius_mm, o)) return false;
    Eigen::Vector2d px;
    Eigen::Matrix<double, 2, 3> j;  // ∂px/∂X_rig at the centre (distortion included)
    if (!project_point(cam, centre_rig_mm, px, &j)) return false;
    // View frame: z along the line of sight, x and y across it; a view-frame offset projects by j (moving along the
    // line of sight does not move the image), so its inverse maps frame-px offsets back to marker radii.
    const Eigen::Vector3d los = centre_rig_mm - cam.centre_rig_mm();
    view_axes(cam, centre_rig_mm, ex, ey, d);
    Eigen::Matrix2d across;
    across.col(0) = j * ex;
    across.col(1) = j * ey;
    // A frame row is a frame px: j is in frame px, as the fit's (x, v).
    const Eigen::Matrix2d inv = (across * radius_mm).inverse();
    if (!inv.allFinite()) return false;
    out = MarkerHint{};
    out.radius_px = o.r_px;
    out.e1 = o.e1;
    out.e2 = o.e2;
    out.view_per_px[0] = inv(0, 0);
    out.view_per_px[1] = inv(0, 1);
    out.view_per_px[2] = inv(1, 0);
    out.view_per_px[3] = inv(1, 1);
    out.view_distance = los.norm() / radius_mm;
    out.centre_x_px = px.x();
    out.centre_v_px = px.y();
    return true;
}

// Whether the sphere (centre c, radius r) lies wholly behind the sphere (e, big_r) seen from o: its image inside
// the other's and it further away. A marker at the eye's outline with part of it past the outline is seen.
bool hidden_by_sphere(const Eigen::Vector3d& o, const Eigen::Vector3d& c, double r, const Eigen::Vector3d& e,
                      double big_r) {
    const Eigen::Vector3d to_c = c - o, to_e = e - o;
    const double dc = to_c.norm(), de = to_e.norm();
    if (!(dc > r) || !(de > big_r)) return false;
    if (dc <= de) return false;  // nearer than the eye's centre: in front of its far half
    const double cos_t = std::clamp(to_c.dot(to_e) / (dc * de), -1.0, 1.0);
    return std::acos(cos_t) + std::asin(r / dc) <= std::asin(big_r / de);
}

// Whether the hint's occluders cover some of the marker's disc (points just inside its rim).
bool disc_rim_covered(const MarkerHint& hint) {
    for (int k = 0; k < 32; ++k) {
        const double phi = 2.0 * M_PI * k / 32, rr = 0.97;
        if (hint_covers(hint, rr * std::cos(phi), rr * std::sin(phi))) return true;
    }
    return false;
}

}  // namespace

bool predict_shaft_hint(const CameraGeometry& cam, const Eigen::Vector3d& centre_rig_mm, double radius_mm,
                        const Eigen::Vector3d& axis_rig, double shaft_radius_mm, MarkerHint& out) {
    Eigen::Vector3d ex, ey, d;
    if (!view_frame(cam, centre_rig_mm, radius_mm, out, ex, ey, d)) return false;
    const Eigen::Vector3d a = axis_rig.normalized();
    out.axis_view[0] = a.dot(ex);
    out.axis_view[1] = a.dot(ey);
    out.axis_view[2] = a.dot(d);
    out.radius_ratio = shaft_radius_mm / radius_mm;
    return true;
}

bool predict_shaft_eye_hint(const CameraGeometry& cam, const Eigen::Vector3d& centre_rig_mm, double radius_mm,
                            const Eigen::Vector3d& axis_rig, double shaft_radius_mm,
                            const Eigen::Vector3d& eye_centre_rig_mm, double eye_radius_mm, MarkerHint& out) {
    if (!predict_shaft_hint(cam, centre_rig_mm, radius_mm, axis_rig, shaft_radius_mm, out)) return false;
    Eigen::Vector3d ex, ey, d;
    view_axes(cam, centre_rig_mm, ex, ey, d);
    set_sphere_occluder(ex, ey, d, centre_rig_mm, radius_mm, eye_centre_rig_mm, eye_radius_mm, out);
    MarkerHint eye_only = out;
    eye_only.radius_ratio = 0;
    return disc_rim_covered(eye_only);
}

bool predict_clear_hint(const CameraGeometry& cam, const Eigen::Vector3d& centre_rig_mm, double radius_mm,
                        MarkerHint& out) {
    Eigen::Vector3d ex, ey, d;
    return view_frame(cam, centre_rig_mm, radius_mm, out, ex, ey, d);
}

bool predict_eye_hint(const CameraGeometry& cam, const Eigen::Vector3d& centre_rig_mm, double radius_mm,
                      const Eigen::Vector3d& eye_centre_rig_mm, double eye_radius_mm, MarkerHint& out) {
    Eigen::Vector3d ex, ey, d;
    if (!view_frame(cam, centre_rig_mm, radius_mm, out, ex, ey, d)) return false;
    set_sphere_occluder(ex, ey, d, centre_rig_mm, radius_mm, eye_centre_rig_mm, eye_radius_mm, out);
    // Only where the eye hides some of the marker's disc: elsewhere the plain fit stands.
    return disc_rim_covered(out);
}

MarkerHintSource::MarkerHintSource(std::span<const CameraGeometry> cameras, const BodySet& bodies) : bodies_(bodies) {
    ncam_ = static_cast<int>(std::min<std::size_t>(cameras.size(), kMaxCameras));
    for (int c = 0; c < ncam_; ++c) cams_[static_cast<std::size_t>(c)] = cameras[static_cast<std::size_t>(c)];
    age_.fill(kMaxAgeFrames + 1);
}

void MarkerHintSource::update(const TrackingFrame& frame) {
    update(frame.eye,
           std::span<const InstrumentPose>(frame.instruments.data(), static_cast<std::size_t>(frame.instrument_count)));
    // An instrument one camera alone sees: its image there is what the hints need (TrackingFrame::one_view).
    for (int b = 0; b < frame.instrument_count && b < static_cast<int>(poses_.size()); ++b)
        if ((frame.one_view_mask >> b) & 1u) {
            poses_[static_cast<std::size_t>(b)] = frame.one_view[static_cast<std::size_t>(b)];
            age_[static_cast<std::size_t>(b)] = 0;
        }
}

void MarkerHintSource::update(const EyePose& eye, std::span<const InstrumentPose> instruments) {
    if (eye.measured()) {
        eye_ = eye;
        eye_age_ = 0;
    } else if (eye_age_ <= kMaxAgeFrames) {
        ++eye_age_;
    }
    for (std::size_t b = 0; b < poses_.size(); ++b) {
        if (b < instruments.size() && instruments[b].measured()) {
            poses_[b] = instruments[b];
            age_[b] = 0;
        } else if (age_[b] <= kMaxAgeFrames) {
            ++age_[b];
        }
    }
}

void MarkerHintSource::predict(const EyePose& eye, std::span<const InstrumentPose> instruments) {
    if (eye.measured() && eye_age_ <= kMaxAgeFrames) eye_ = eye;
    for (std::size_t b = 0; b < poses_.size() && b < instruments.size(); ++b)
        if (instruments[b].measured() && age_[b] <= kMaxAgeFrames) poses_[b] = instruments[b];
}

bool MarkerHintSource::predicted_centroid(int camera, const BlobBox& blob, const MarkerHint* hint,
                                          const SphereFitConfig& config, int field_lines, double& cx_px,
                                          double& cy_px) const {
    Eigen::Vector2d px;  // frame px
    if (hint) {
        double dx = 0, dv = 0, visible = 0;
        if (!hinted_centroid_offset(config, *hint, blob.parity, dx, dv, visible)) return false;
        px = Eigen::Vector2d(hint->centre_x_px + dx, hint->centre_v_px + dv);
    } else {
        int b = -1, m = -1;
        Eigen::Vector3d centre;
        if (!nearest(camera, blob, b, m, centre, field_lines) ||
            !project_point(cams_[static_cast<std::size_t>(camera)], centre, px))
            return false;
    }
    cx_px = px.x();
    cy_px = 0.5 * (px.y() - (blob.parity & 1));
    return true;
}

SphereFitResult MarkerHintSource::fit(const MarkerHintSource* source, const uint8_t* field, int height,
                                      const BlobBox& blob, int camera, const SphereFitConfig& config,
                                      SphereFitWorkspace& work, bool& hinted) {
    MarkerHint hint;
    PatchMask mask;
    hinted = source && source->hint(camera, blob, hint, config.hint_with_outline, height);
    const SphereFitResult r = fit_sphere(field, height, blob, config, work, hinted ? &hint : nullptr);
    // Another instrument's shaft in the patch: its pixels left out only when the fit without that fails (the
    // strip, from poses a field or two old, is wider than the shaft, and it takes marker pixels where it passes
    // close: left out always, it cost fits that had stood).
    const bool retry = !r.ok && (r.refusal == FitRefusal::kChi2 || r.refusal == FitRefusal::kOutliers ||
                                 r.refusal == FitRefusal::kShift || r.refusal == FitRefusal::kImplausible);
    SphereFitResult out = r;
    if (retry && source && source->patch_mask(camera, blob, mask, height)) {
        // The pipeline's centroid beside another shaft takes some of its chroma: the shift gate widens as on video.
        SphereFitConfig wide = config;
        wide.max_shift_px = std::max(config.max_shift_px, kLossyMaxShiftPx);
        out = fit_sphere(field, height, blob, wide, work, hinted ? &hint : nullptr, &mask);
    }
    // On lossy video, once more from the pose's predicted centre (SphereFitConfig::restart_from_prediction).
    if (config.restart_from_prediction && !out.ok && hinted &&
        (out.refusal == FitRefusal::kChi2 || out.refusal == FitRefusal::kShift || out.refusal == FitRefusal::kImplausible)) {
        const SphereFitResult again = fit_sphere(field, height, blob, config, work, &hint, nullptr, true);
        if (again.ok) return again;
    }
    // A marker's pipeline centroid on lossy video can sit 0.3 px or more off field after field (DV `sweep` seeds 133,
    // 135: a clear eye marker of camera 1, its chroma in the same DCT blocks; DVCPRO25 seed 147: a light-pipe marker
    // 17–24 % hidden, 1.0–1.3 px off in x), beyond the shift gate, while its fit is right: a fit refused for that
    // shift alone stands where it lies within the plain gate of the centroid the pose predicts (a clear marker's
    // centre, a hinted one's visible part).
    double px = 0, py = 0;
    if (config.restart_from_prediction && !out.ok && out.refusal == FitRefusal::kShift && !mask.merged && source &&
        source->predicted_centroid(camera, blob, out.hinted ? &hint : nullptr, config, height, px, py) &&
        std::hypot((out.cx_px - px) / config.shift_x_scale, (out.cy_px - py) / config.shift_y_scale) <=
            config.max_shift_px) {
        out.ok = true;
        out.refusal = FitRefusal::kNone;
        return out;
    }
    // Two markers of one class in one blob: its moments, and so the fit's start, lie between them; once more from
    // the marker's predicted centre and outline (sweep seed 135, DV and H.264: an eye marker joined with its
    // neighbour, its pipeline centroid 2 px off, each of its fits refused).
    if (!out.ok && mask.merged && !(hinted && hint.radius_px > 0)) {
        const SphereFitResult again =
            fit_sphere(field, height, blob, config, work, hinted ? &hint : nullptr, &mask, true);
        if (again.ok) return again;
    }
    return out;
}

bool MarkerHintSource::ready() const {
    if (eye_age_ <= kMaxAgeFrames) return true;
    for (int b = 0; b < bodies_.instrument_count; ++b)
        if (age_[static_cast<std::size_t>(b)] <= kMaxAgeFrames) return true;
    return false;
}

bool MarkerHintSource::nearest(int camera, const BlobBox& blob, int& body, int& marker, Eigen::Vector3d& centre,
                               int field_lines) const {
    if (camera < 0 || camera >= ncam_) return false;
    const CameraGeometry& cam = cams_[static_cast<std::size_t>(camera)];
    const Eigen::Vector2d seen(blob.cx_px, 2.0 * blob.cy_px + (blob.parity & 1));  // frame px
    const bool has_box = blob.x_max >= blob.x_min && blob.y_max >= blob.y_min;  // BlobBox's default has none
    const bool on_edge = has_box && (blob.y_min == 0 || blob.x_min == 0 || blob.x_max == kImageColumns - 1 ||
                                     (field_lines > 0 && blob.y_max == field_lines - 1));
    double best = kGatePx + (on_edge ? kEdgeGatePx : 0.0);
    body = -1;
    marker = -1;
    // A marker of the blob's class at `c` (rig), nearer the blob than the best so far, becomes the best.
    auto consider = [&](const BodyMarker& bm, const Eigen::Vector3d& c, int b, int m) {
        if (bm.colour_class != blob.class_id || !(bm.radius_mm > 0)) return;
        Eigen::Vector2d px;
        if (!project_point(cam, c, px)) return;
        const double d = (px - seen).norm();
        if (d < best) {
            best = d;
            body = b;
            marker = m;
            centre = c;
        }
    };
    // The eye's markers too: the nearest of all wins (an eye marker is not fitted with a shaft).
    for_each_marker([&](int b, int m, const BodyMarker& bm, const Eigen::Vector3d& c) {
        if (b < 0 || bodies_.instruments[static_cast<std::size_t>(b)].shaft_radius_mm > 0) consider(bm, c, b, m);
    });
    return marker >= 0;
}

bool MarkerHintSource::hint(int camera, const BlobBox& blob, MarkerHint& out, bool eye_in_front, int field_lines) const {
    int b = -1, m = -1;
    Eigen::Vector3d centre;
    if (!nearest(camera, blob, b, m, centre, field_lines)) return false;
    const CameraGeometry& cam = cams_[static_cast<std::size_t>(camera)];
    if (b < 0)
        return predict_eye_hint(cam, centre, bodies_.eye.markers[static_cast<std::size_t>(m)].radius_mm,
                                eye_.centre_rig_mm, bodies_.eye.radius_mm, out);
    const InstrumentModel& im = bodies_.instruments[static_cast<std::size_t>(b)];
    const InstrumentPose& pose = poses_[static_cast<std::size_t>(b)];
    const Eigen::Vector3d axis = pose.rotation_body_to_rig * im.axis_body;
    const double radius_mm = im.markers[static_cast<std::size_t>(m)].radius_mm;
    if (!predict_shaft_hint(cam, centre, radius_mm, axis, im.shaft_radius_mm, out)) return false;
    Eigen::Vector3d ex, ey, d;
    view_axes(cam, centre, ex, ey, d);
    // Another marker nearer the camera with its image in the patch (markers along a shaft seen near its axis: it
    // may hide part of this one, and its pixels are not the background): the nearest such one, the eye's markers
    // included.
    const Eigen::Vector3d cam_c = cam.centre_rig_mm();
    const double depth = (centre - cam_c).norm();
    const Eigen::Vector2d px(out.centre_x_px, out.centre_v_px);  // the view frame's projection of the centre
    int occ_body = 0;
    Eigen::Vector3d occ_c;
    double occ_r_mm = 0;
    auto nearest_in_front = [&] {
        double best = HUGE_VAL;
        occ_r_mm = 0;
        for_each_marker([&](int ob, int om_i, const BodyMarker& bm, const Eigen::Vector3d& c) {
            if (ob == b && om_i == m) return;
            const double sep = (c - centre).norm();
            Eigen::Vector2d opx;
            if (!(bm.radius_mm > 0) || !((c - cam_c).norm() < depth) || sep >= best || !project_point(cam, c, opx)) return;
            // Its image's edge within the patch's reach (radii from the outline prediction's scale).
            const double r_px = out.radius_px, or_px = out.radius_px * bm.radius_mm / radius_mm * depth / (c - cam_c).norm();
            if ((opx - px).norm() - r_px - or_px > kForeignReachPx) return;
            best = sep;
            occ_body = ob;
            occ_c = c;
            occ_r_mm = bm.radius_mm;
        });
    };
    // The eye in front of part of the marker (a marker outside the eye seen past its outline): the eye is the
    // occluding sphere, the largest thing across a marker the poses place. Its outline stands still in the image
    // (the eye's centre is fixed in the rig) while the marker's predicted place is a pose a field old: the fit
    // keeps the occluder where the image has it (occluder_fixed). Only for sources whose pipeline centroid the
    // eye's outline spoils (hint_with_outline): on raw fields the pipeline's is as good there (2 s sweeps, seeds
    // 1–4: equal on three, 0.0296 → 0.0303 px over all blobs on seed 2).
    if (eye_in_front && eye_age_ <= kMaxAgeFrames) {
        MarkerHint with_eye = out;
        set_sphere_occluder(ex, ey, d, centre, radius_mm, eye_.centre_rig_mm, bodies_.eye.radius_mm, with_eye);
        with_eye.occluder_fixed = true;
        MarkerHint eye_only = with_eye;
        eye_only.radius_ratio = 0;
        if (disc_rim_covered(eye_only)) {
            out = with_eye;
            // A marker in front across it as well (an eye marker at the outline, where the eye hides the rest: sweep
            // seed 6): the second occluder, kept where the image has it when it is on another body.
            nearest_in_front();
            if (occ_r_mm > 0) {
                set_sphere_occluder(ex, ey, d, centre, radius_mm, occ_c, occ_r_mm, out, true);
                out.occluder2_fixed = occ_body != b;
            }
            return true;
        }
    }
    // Else the nearest marker in front, an eye marker included (a light-pipe marker behind an eye marker: sweep
    // seeds 52 and 57, camera 1); patch_mask leaves such a marker to the hint. One of another body stays where the
    // image has it.
    nearest_in_front();
    if (occ_r_mm > 0) {
        set_sphere_occluder(ex, ey, d, centre, radius_mm, occ_c, occ_r_mm, out);
        out.occluder_fixed = occ_body != b;
    }
    return true;
}

bool MarkerHintSource::patch_mask(int camera, const BlobBox& blob, PatchMask& out, int field_lines) const {
    out = PatchMask{};
    int own = -1, m = -1;
    Eigen::Vector3d centre;
    if (!nearest(camera, blob, own, m, centre, field_lines)) return false;
    const CameraGeometry& cam = cams_[static_cast<std::size_t>(camera)];
    const double marker_r_mm = own < 0 ? bodies_.eye.markers[static_cast<std::size_t>(m)].radius_mm
                                       : bodies_.instruments[static_cast<std::size_t>(own)].markers[static_cast<std::size_t>(m)].radius_mm;
    ProjectedOutline outline;
    if (!project_sphere_outline(cam, centre, marker_r_mm, outline)) return false;
    out.keep_x_px = outline.x_px;
    out.keep_v_px = outline.v_px;
    out.keep_radius_px = outline.r_px - 1.0;  // the marker's own pixels, short of its rim (which a shaft behind shares)
    out.keep_outline_r_px = outline.r_px;
    out.keep_e1 = outline.e1;
    out.keep_e2 = outline.e2;
    const Eigen::Vector3d cam_c = cam.centre_rig_mm();
    const Eigen::Vector3d d = (centre - cam_c).normalized();
    const double marker_depth = (centre - cam_c).dot(d);
    const Eigen::Vector2d mc(outline.x_px, outline.v_px);
    for (int b = 0; b < bodies_.instrument_count && out.count < PatchMask::kMaxShafts; ++b) {
        const InstrumentModel& im = bodies_.instruments[static_cast<std::size_t>(b)];
        if (b == own || age_[static_cast<std::size_t>(b)] > kMaxAgeFrames || !(im.shaft_radius_mm > 0)) continue;
        const InstrumentPose& pose = poses_[static_cast<std::size_t>(b)];
        const Eigen::Vector3d a = (pose.rotation_body_to_rig * im.axis_body).normalized();
        const Eigen::Vector3d tip = pose.tip_rig_mm;
        // The shaft's point nearest the marker's line of sight (tip → handle: s ≥ 0, up to its length).
        const Eigen::Vector3d w0 = cam_c - tip;
        const double bb = d.dot(a), dd = d.dot(w0), e = a.dot(w0), den = 1.0 - bb * bb;
        if (!(den > 1e-9)) continue;  // along the line of sight: no strip
        double s = e + bb * (bb * e - dd) / den;
        s = std::max(0.0, im.shaft_length_mm > 0 ? std::min(s, im.shaft_length_mm) : s);
        const Eigen::Vector3d p0 = tip + s * a;
        Eigen::Vector2d px0, px1, pxw;
        const Eigen::Vector3d across = a.cross(d).normalized();
        if (!project_point(cam, p0, px0) || !project_point(cam, p0 + a, px1) ||
            !project_point(cam, p0 + im.shaft_radius_mm * across, pxw))
            continue;
        Eigen::Vector2d u = px1 - px0;
        if (!(u.norm() > 1e-9)) continue;
        u.normalize();
        ForeignShaft fs;
        fs.x_px = px0.x();
        fs.v_px = px0.y();
        fs.ux = u.x();
        fs.uv = u.y();
        fs.half_width_px = (pxw - px0).norm() + kForeignMarginPx;
        fs.from_start = s <= 0.0;
        // Its distance from the marker's image, and whether it passes in front of the marker there.
        const Eigen::Vector2d q = mc - px0;
        const double along = q.dot(u), off = std::fabs(q.x() * u.y() - q.y() * u.x());
        const double gap = (fs.from_start && along < 0 ? q.norm() : off) - fs.half_width_px;
        if (gap > kForeignReachPx) continue;
        const bool in_front = (p0 - cam_c).dot(d) < marker_depth;
        if (gap < outline.r_px && in_front) continue;  // it hides part of the marker: not modelled
        out.shafts[static_cast<std::size_t>(out.count++)] = fs;
    }
    // Other markers in the patch: their discs, but not one in front across the marker (the hint's occluder).
    // The blob's box in frame px (v: frame rows; a field line spans two).
    const double box_x0 = blob.x_min - 0.5, box_x1 = blob.x_max + 0.5;
    const double box_v0 = 2.0 * blob.y_min + (blob.parity & 1) - 1.0, box_v1 = 2.0 * blob.y_max + (blob.parity & 1) + 1.0;
    auto add_disc = [&](const Eigen::Vector3d& c, double r_mm, int colour_class) {
        if (out.disc_count >= PatchMask::kMaxDiscs || !(r_mm > 0)) return;
        ProjectedOutline o;
        if (!project_sphere_outline(cam, c, r_mm, o)) return;
        const double gap = std::hypot(o.x_px - outline.x_px, o.v_px - outline.v_px) - o.r_px - outline.r_px;
        if (gap > kForeignReachPx) return;
        if (gap < 0 && (c - cam_c).dot(d) < marker_depth) return;  // in front, across it
        out.discs[static_cast<std::size_t>(out.disc_count++)] = {o.x_px, o.v_px, o.r_px + kForeignMarginPx};
        // Its image reaching half a pixel into the blob's box, in the blob's colour: the pipeline joined the two.
        const double ox = std::clamp(o.x_px, box_x0, box_x1) - o.x_px, ov = std::clamp(o.v_px, box_v0, box_v1) - o.v_px;
        if (colour_class == blob.class_id && std::hypot(ox, ov) < o.r_px - 0.5) out.merged = true;
    };
    for_each_marker([&](int b, int k, const BodyMarker& bm, const Eigen::Vector3d& c) {
        if (b == own && k == m) return;
        // An eye marker the eye hides whole is not in the image; one at its outline, partly seen, is.
        if (b < 0 && hidden_by_sphere(cam_c, c, bm.radius_mm, eye_.centre_rig_mm, bodies_.eye.radius_mm)) return;
        add_disc(c, bm.radius_mm, bm.colour_class);
    });
    return out.count > 0 || out.disc_count > 0;
}

}  // namespace eyesim::tracking
