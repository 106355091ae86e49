#include "eyesim/tracking/validation.hpp"

#include "eyesim/tracking/rigid_fit.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace eyesim::tracking {

ErrorSummary summarise(std::vector<double>& v) {
    ErrorSummary s;
    s.count = v.size();
    if (v.empty()) return s;
    std::sort(v.begin(), v.end());
    double ss = 0, sum = 0;
    for (double x : v) {
        ss += x * x;
        sum += x;
    }
    const auto rank = [&](double q) {
        const std::size_t k = std::size_t(std::ceil(q * double(v.size())));
        return v[std::min(v.size() - 1, k == 0 ? 0 : k - 1)];
    };
    s.rms = std::sqrt(ss / double(v.size()));
    s.mean = sum / double(v.size());
    s.p50 = rank(0.50);
    s.p95 = rank(0.95);
    s.p99 = rank(0.99);
    s.max = v.back();
    return s;
}

FrameScore score_frame(const TrackingFrame& frame, const BodySet& bodies, const rig::FieldTruth& truth,
                       double reach_mm) {
    FrameScore fs;
    fs.t_us = truth.t_us;
    for (const rig::MarkerTruth& mt : truth.markers) {
        int seen = 0;
        for (const auto& c : mt.cams) seen += c.visible ? 1 : 0;
        if (seen >= 2) ++fs.truth_markers_visible2;
    }
    auto body_name = [&](int body) -> std::string {
        if (body == 0) return "eye";
        if (body >= 1 && body <= bodies.instrument_count) return bodies.instruments[std::size_t(body - 1)].name;
        return {};
    };
    for (int k = 0; k < frame.markers.count; ++k) {
        const MatchedMarker& m = frame.markers.markers[std::size_t(k)];
        MarkerScore ms;
        ms.body = frame.assignment.body[std::size_t(k)];
        ms.colour_class = m.colour_class;
        ms.views = m.point.views;
        ms.occluded = m.occluded;
        const rig::MarkerTruth* best = nullptr;
        double bd = 1e300;
        if (ms.body >= 0) {
            // The marker the body fit says it is.
            const std::string name = body_name(ms.body);
            const int id = frame.assignment.marker[std::size_t(k)];
            for (const rig::MarkerTruth& mt : truth.markers)
                if (mt.body == name && mt.id == id) best = &mt;
            if (best) bd = (best->center_rig_mm - m.point.X_rig_mm).norm();
            // A wrong assignment shows as a large error here, which is what a user of the pose would see.
        } else {
            for (const rig::MarkerTruth& mt : truth.markers) {
                if (mt.colour_class != m.colour_class) continue;
                const double d = (mt.center_rig_mm - m.point.X_rig_mm).norm();
                if (d < bd) { bd = d; best = &mt; }
            }
            if (bd > reach_mm) best = nullptr;
        }
        if (!best) {
            ++fs.ghosts;
            continue;
        }
        ms.id = best->id;
        ms.truth_eye = best->body == "eye";
        ms.truth_rig_mm = best->center_rig_mm;
        ms.error_mm = bd;
        fs.markers.push_back(ms);
    }
    const double rad2deg = 180.0 / std::numbers::pi;
    for (int b = 0; b < frame.instrument_count; ++b) {
        const InstrumentPose& p = frame.instruments[std::size_t(b)];
        const rig::InstrumentTruth* t = nullptr;
        for (const rig::InstrumentTruth& it : truth.instruments)
            if (bodies.instruments[std::size_t(b)].name == rig::instrument_kind_name(it.kind)) t = &it;
        const bool ok = t && p.measured();
        fs.tip_error_mm.push_back(ok ? (p.tip_rig_mm - t->tip_rig_mm).norm() : -1.0);
        fs.tip_eye_error_mm.push_back(ok ? (p.tip_eye_mm - t->tip_eye_mm).norm() : -1.0);
        fs.axis_error_deg.push_back(
            ok ? std::acos(std::clamp(p.axis_rig.dot(t->axis_rig.normalized()), -1.0, 1.0)) * rad2deg : -1.0);
        fs.insertion_error_mm.push_back(ok && bodies.instruments[std::size_t(b)].has_trocar
                                            ? std::abs(p.insertion_depth_mm - t->insertion_mm)
                                            : -1.0);
        fs.tip_in_eye.push_back(t && bodies.instruments[std::size_t(b)].has_trocar && t->insertion_mm > 0.0);
    }
    if (frame.eye.measured())
        fs.eye_error_deg = rotation_angle_deg(frame.eye.rotation_eye_to_rig.toRotationMatrix(),
                                              truth.q_eye_to_rig.toRotationMatrix());
    return fs;
}

}  // namespace eyesim::tracking
