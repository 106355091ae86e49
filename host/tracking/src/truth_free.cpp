#include "eyesim/tracking/truth_free.hpp"

#include "eyesim/tracking/distortion.hpp"
#include "eyesim/tracking/rigid_fit.hpp"

#include <algorithm>
#include <cmath>

namespace eyesim::tracking {

namespace {

/// Index of the pair (a, b), a < b, among the m(m−1)/2 pairs of an m-marker body in lexicographic order.
int pair_offset(int m, int a, int b) { return a * m - a * (a + 1) / 2 + (b - a - 1); }

}  // namespace

const BodyMarker& TruthFreeStats::body_marker(int body, int k) const {
    if (body == wand_body_) return wand_.markers[std::size_t(k)];
    return body == 0 ? model_.eye.markers[std::size_t(k)]
                     : model_.instruments[std::size_t(body - 1)].markers[std::size_t(k)];
}

int TruthFreeStats::marker_count(int body) const {
    if (body == wand_body_) return wand_.marker_count;
    return body == 0 ? model_.eye.marker_count : model_.instruments[std::size_t(body - 1)].marker_count;
}

TruthFreeStats::TruthFreeStats(const BodySet& bodies, int camera_count, const InstrumentModel* wand)
    : model_(bodies), ncam_(camera_count), eye_centre_mm_(bodies.eye.centre_rig_mm),
      cameras_(std::size_t(std::max(0, camera_count))) {
    int nbodies = 1 + bodies.instrument_count;
    if (wand && wand->marker_count >= 2) {
        wand_ = *wand;
        wand_body_ = nbodies++;
    }
    for (int body = 0; body < nbodies; ++body) {
        BodyTrack t;
        t.body = body;
        t.name = body == 0 ? std::string("eye") : body == wand_body_ ? std::string("wand")
                                                                      : bodies.instruments[std::size_t(body - 1)].name;
        const int m = marker_count(body);
        body_first_marker_.push_back(int(markers_.size()));
        for (int k = 0; k < m; ++k) markers_.push_back({body, k, body_marker(body, k).colour_class, 0, 0, 0, 0, 0, 0});
        body_first_pair_.push_back(int(pairs_.size()));
        for (int a = 0; a < m; ++a)
            for (int b = a + 1; b < m; ++b)
                pairs_.push_back({body, a, b, (body_marker(body, a).pos_body_mm - body_marker(body, b).pos_body_mm).norm(),
                                  0, 0, 0, 0});
        if (body > 0 && m >= 2) t.length_pair = body_first_pair_.back() + pair_offset(m, 0, m - 1);
        bodies_.push_back(t);
    }
}

int TruthFreeStats::marker_index(int body, int marker) const {
    if (body < 0 || body >= int(bodies_.size()) || marker < 0 || marker >= marker_count(body)) return -1;
    return body_first_marker_[std::size_t(body)] + marker;
}

long TruthFreeStats::span_marker_frames() const {
    long n = 0;
    for (const MarkerResiduals& m : markers_) {
        const BodyTrack& t = bodies_[std::size_t(m.body)];
        if (t.first_frame >= 0) n += t.last_frame - t.first_frame + 1;
    }
    return n;
}

long TruthFreeStats::dropped_marker_frames() const {
    long n = 0;
    for (const MarkerResiduals& m : markers_) n += m.frames_assigned;
    return span_marker_frames() - n;
}

bool TruthFreeStats::find_wand(const TrackingFrame& frame, std::array<int, kMaxBodyMarkers>& which,
                               InstrumentPose& pose) const {
    // Every wand marker, among the markers no body claimed, with every pairwise distance within the tolerance of
    // the tracker's own body search (0.4 mm); of several such sets the one with the smallest distance error.
    constexpr double kTolMm = 0.4;
    const int m = wand_.marker_count;
    std::array<int, kMaxBodyMarkers> cur{};
    double best_err = 1e300;
    bool found = false;
    const auto usable = [&](int k) {
        const MatchedMarker& mk = frame.markers.markers[std::size_t(k)];
        return frame.assignment.body[std::size_t(k)] < 0 && mk.point.usable() && !mk.occluded;
    };
    const auto search = [&](auto&& self, int i, double err) -> void {
        if (i == m) {
            if (err < best_err) best_err = err, which = cur, found = true;
            return;
        }
        for (int k = 0; k < frame.markers.count; ++k) {
            if (!usable(k) || frame.markers.markers[std::size_t(k)].colour_class != wand_.markers[std::size_t(i)].colour_class)
                continue;
            bool ok = true;
            double e = err;
            for (int j = 0; j < i && ok; ++j) {
                if (cur[std::size_t(j)] == k) { ok = false; break; }
                const double dm = (frame.markers.markers[std::size_t(k)].point.X_rig_mm -
                                   frame.markers.markers[std::size_t(cur[std::size_t(j)])].point.X_rig_mm).norm();
                const double de = dm - (wand_.markers[std::size_t(i)].pos_body_mm - wand_.markers[std::size_t(j)].pos_body_mm).norm();
                ok = std::abs(de) <= kTolMm;
                e += de * de;
            }
            if (!ok) continue;
            cur[std::size_t(i)] = k;
            self(self, i + 1, e);
        }
    };
    search(search, 0, 0.0);
    if (!found) return false;
    std::array<Eigen::Vector3d, kMaxBodyMarkers> pts;
    std::array<int, kMaxBodyMarkers> ids;
    for (int i = 0; i < m; ++i) {
        pts[std::size_t(i)] = frame.markers.markers[std::size_t(which[std::size_t(i)])].point.X_rig_mm;
        ids[std::size_t(i)] = i;
    }
    return fit_instrument(wand_, std::span<const Eigen::Vector3d>(pts.data(), std::size_t(m)),
                          std::span<const int>(ids.data(), std::size_t(m)), {}, pose);
}

void TruthFreeStats::add(const Tracker& tracker, const TrackingFrame& frame) {
    const long ordinal = frames_++;
    const std::span<const CameraGeometry> cams = tracker.cameras();
    const int ncam = std::min(ncam_, int(cams.size()));
    // The wand (not a tracked body): its markers among those no body claimed.
    std::array<int, kMaxBodyMarkers> wand_at{};
    std::array<int, kMaxMarkersPerFrame> wand_id{};
    wand_id.fill(-1);
    InstrumentPose wand_pose;
    const bool wand_found = wand_body_ >= 0 && find_wand(frame, wand_at, wand_pose);
    if (wand_found)
        for (int i = 0; i < wand_.marker_count; ++i) wand_id[std::size_t(wand_at[std::size_t(i)])] = i;
    // Bodies measured this frame: their tracked span.
    const int nbodies = int(bodies_.size());
    std::array<bool, kMaxInstruments + 2> measured{};
    for (int body = 0; body < nbodies; ++body) {
        measured[std::size_t(body)] =
            body == 0             ? frame.eye.measured()
            : body == wand_body_ ? wand_found
                                  : body - 1 < frame.instrument_count && frame.instruments[std::size_t(body - 1)].measured();
        if (!measured[std::size_t(body)]) continue;
        BodyTrack& t = bodies_[std::size_t(body)];
        if (t.first_frame < 0) t.first_frame = ordinal;
        t.last_frame = ordinal;
        ++t.measured_frames;
    }
    // The fitted pose of each body: where it puts its model markers.
    const auto fitted = [&](int body, int k) -> Eigen::Vector3d {
        const Eigen::Vector3d& b = body_marker(body, k).pos_body_mm;
        if (body == 0) return frame.eye.rotation_eye_to_rig * b + frame.eye.centre_rig_mm;
        if (body == wand_body_) return wand_pose.rotation_body_to_rig * (b - wand_.tip_body_mm) + wand_pose.tip_rig_mm;
        const InstrumentPose& p = frame.instruments[std::size_t(body - 1)];
        return p.rotation_body_to_rig * (b - model_.instruments[std::size_t(body - 1)].tip_body_mm) + p.tip_rig_mm;
    };
    double frame_ss = 0;
    long frame_n = 0;
    // Assigned markers of each body this frame (index into frame.markers, −1 none), for pairs and the eye centre.
    std::array<std::array<int, kMaxBodyMarkers>, kMaxInstruments + 2> at{};
    for (auto& a : at) a.fill(-1);
    for (int k = 0; k < frame.markers.count; ++k) {
        int body = frame.assignment.body[std::size_t(k)];
        int id = frame.assignment.marker[std::size_t(k)];
        if (body < 0 && wand_id[std::size_t(k)] >= 0) body = wand_body_, id = wand_id[std::size_t(k)];
        if (body < 0) {
            ++unassigned_;
            continue;
        }
        const int mi = marker_index(body, id);
        if (mi < 0 || !measured[std::size_t(body)]) continue;
        MarkerResiduals& mr = markers_[std::size_t(mi)];
        ++mr.frames_assigned;
        const MatchedMarker& m = frame.markers.markers[std::size_t(k)];
        if (m.occluded || !m.point.usable()) {
            ++mr.frames_occluded;
            continue;
        }
        at[std::size_t(body)][std::size_t(id)] = k;
        const Eigen::Vector3d X = m.point.X_rig_mm;
        const Eigen::Vector3d Xf = fitted(body, id);
        for (int c = 0; c < ncam; ++c) {
            const Tracker::MarkerView v = tracker.marker_view(frame, k, c);
            if (!v.present) continue;
            CameraResiduals& cr = cameras_[std::size_t(c)];
            if (v.left_out) {
                ++cr.views_left_out;
                continue;
            }
            const CameraGeometry& g = cams[std::size_t(c)];
            Eigen::Vector2d px, pf;
            if (!project_point(g, X, px) || !project_point(g, Xf, pf)) continue;
            const double r = (px - v.used_px).norm(), rf = (pf - v.used_px).norm();
            const Eigen::Vector3d d = (g.R_cam_rig.transpose() * Eigen::Vector3d(v.used_xn.x(), v.used_xn.y(), 1.0)).normalized();
            const double ray = (X - g.centre_rig_mm()).cross(d).norm() * 1e3;
            cr.reprojection_px.push_back(float(r));
            cr.fit_reprojection_px.push_back(float(rf));
            cr.ray_um.push_back(float(ray));
            ++mr.views;
            mr.reprojection_ss_px2 += r * r;
            mr.fit_reprojection_ss_px2 += rf * rf;
            mr.ray_ss_um2 += ray * ray;
            frame_ss += r * r;
            ++frame_n;
        }
    }
    // Pair distances of every body measured this frame.
    for (int body = 0; body < nbodies; ++body) {
        const int m = marker_count(body);
        const auto& idx = at[std::size_t(body)];
        for (int a = 0; a < m; ++a) {
            if (idx[std::size_t(a)] < 0) continue;
            const Eigen::Vector3d& Xa = frame.markers.markers[std::size_t(idx[std::size_t(a)])].point.X_rig_mm;
            for (int b = a + 1; b < m; ++b) {
                if (idx[std::size_t(b)] < 0) continue;
                const Eigen::Vector3d& Xb = frame.markers.markers[std::size_t(idx[std::size_t(b)])].point.X_rig_mm;
                PairDistance& p = pairs_[std::size_t(body_first_pair_[std::size_t(body)] + pair_offset(m, a, b))];
                const double e = ((Xa - Xb).norm() - p.model_mm) * 1e3;
                ++p.frames;
                p.sum_um += e;
                p.ss_um2 += e * e;
                p.max_abs_um = std::max(p.max_abs_um, std::abs(e));
                pair_errors_um_.push_back(float(e));
            }
        }
    }
    // Eye centre from a free rigid fit of its markers (eye frame origin = centre): t of X_rig = R·X_eye + t.
    {
        std::array<Eigen::Vector3d, kMaxBodyMarkers> body_pts, rig_pts;
        std::size_t n = 0;
        for (int i = 0; i < model_.eye.marker_count; ++i) {
            const int k = at[0][std::size_t(i)];
            if (k < 0) continue;
            body_pts[n] = model_.eye.markers[std::size_t(i)].pos_body_mm;
            rig_pts[n++] = frame.markers.markers[std::size_t(k)].point.X_rig_mm;
        }
        if (n >= 3) {
            const RigidFit f = fit_rigid(std::span<const Eigen::Vector3d>(body_pts.data(), n),
                                         std::span<const Eigen::Vector3d>(rig_pts.data(), n));
            if (f.ok) eye_centres_mm_.push_back(f.t_mm);
        }
    }
    frame_t_s_.push_back(frame.time_device_us * 1e-6);
    frame_reprojection_px_.push_back(frame_n ? std::sqrt(frame_ss / double(frame_n)) : -1.0);
}

}  // namespace eyesim::tracking
