#include "eyesim/tracking/correspondence.hpp"

#include <algorithm>
#include <cmath>

namespace eyesim::tracking {

namespace {

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
    Eigen::Matrix3d S;
    S << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
    return S;
}



}  // namespace

Correspondence::Correspondence(std::span<const CameraGeometry> cams, const CorrespondenceOptions& opt)
    : cams_(cams.first(std::min<std::size_t>(cams.size(), kMaxCameras))), opt_(opt) {
    for (std::size_t a = 0; a < cams_.size(); ++a) {
        for (std::size_t b = 0; b < cams_.size(); ++b) {
            // Relative pose a→b: X_b = R X_a + t with R = R_b R_aᵀ, t = t_b − R t_a; E = [t]× R.
            const Eigen::Matrix3d R = cams_[b].R_cam_rig * cams_[a].R_cam_rig.transpose();
            const Eigen::Vector3d t = cams_[b].t_cam_rig_mm - R * cams_[a].t_cam_rig_mm;
            E_[a][b] = skew(t) * R;
        }
    }
}

void Correspondence::check_occlusion(std::span<const CameraObservations> views, MatchedMarker& m, int ncam) const {
    std::array<double, kMaxCameras> ratio{};
    double best = 0.0;
    for (int c = 0; c < ncam; ++c) {
        ratio[std::size_t(c)] = -1.0;
        const int i = m.image_index[std::size_t(c)];
        if (i < 0) continue;
        const ImagePoint& p = views[std::size_t(c)].points[std::size_t(i)];
        const CameraGeometry& g = cams_[std::size_t(c)];
        const double z = (g.R_cam_rig * m.point.X_rig_mm + g.t_cam_rig_mm).z();
        if (!(p.area_px > 0.0f) || !(z > 0.0)) continue;
        const double r = opt_.marker_radius_mm / z;
        const double expected = 3.141592653589793 * (g.fx * r) * (g.fy * r) * 0.5;  // field pixels
        ratio[std::size_t(c)] = double(p.area_px) / expected;
        best = std::max(best, ratio[std::size_t(c)]);
    }
    if (best <= 0.0) return;
    int clean = 0;
    for (int c = 0; c < ncam; ++c) {
        const double q = ratio[std::size_t(c)];
        if (m.image_index[std::size_t(c)] < 0) continue;
        if (q >= 0.0 && (q < opt_.min_area_ratio || q < opt_.relative_area_ratio * best))
            m.occluded_views = std::uint8_t(m.occluded_views | (1u << c));
        else
            ++clean;
    }
    if (m.occluded_views == 0) return;
    if (clean < 2) {
        m.occluded = true;
        return;
    }
    // Re-triangulate from the unoccluded views only.
    std::array<Observation, kMaxCameras> obs;
    int n = 0;
    for (int c = 0; c < ncam; ++c) {
        const int i = m.image_index[std::size_t(c)];
        if (i < 0 || (m.occluded_views & (1u << c))) continue;
        const ImagePoint& p = views[std::size_t(c)].points[std::size_t(i)];
        obs[std::size_t(n++)] = Observation{c, p.px, p.xn, p.sigma_px};
    }
    const TriangulatedPoint tp =
        triangulate(cams_, std::span<const Observation>(obs.data(), std::size_t(n)), opt_.triangulation);
    if (tp.usable()) m.point = tp;
}

double Correspondence::epipolar_distance_px(int a, int b, const Eigen::Vector2d& xa,
                                            const Eigen::Vector2d& xb) const {
    const Eigen::Vector3d ha(xa.x(), xa.y(), 1.0), hb(xb.x(), xb.y(), 1.0);
    const Eigen::Matrix3d& E = E_[std::size_t(a)][std::size_t(b)];
    const Eigen::Vector3d lb = E * ha;               // epipolar line of xa in camera b
    const Eigen::Vector3d la = E.transpose() * hb;   // epipolar line of xb in camera a
    const double e = hb.dot(lb);
    const double db = std::abs(e) / std::max(std::hypot(lb.x(), lb.y()), 1e-300) * cams_[std::size_t(b)].mean_focal_px();
    const double da = std::abs(e) / std::max(std::hypot(la.x(), la.y()), 1e-300) * cams_[std::size_t(a)].mean_focal_px();
    return 0.5 * (da + db);
}

void Correspondence::solve(std::span<const CameraObservations> views, CorrespondenceResult& out) const {
    out.count = 0;
    out.unmatched_images = 0;
    out.rejected_hypotheses = 0;
    const int ncam = int(std::min(views.size(), cams_.size()));
    std::array<std::array<bool, kMaxMarkersPerCamera>, kMaxCameras> used{};
    std::array<Observation, kMaxCameras> obs;
    // Per class and camera: indices of that class's images.
    std::array<std::array<std::int8_t, kMaxImagesPerClass>, kMaxCameras> members{};
    std::array<int, kMaxCameras> nm{};
    // Epipolar distance between member i of camera a and member j of camera b (a < b).
    std::array<std::array<std::array<float, kMaxImagesPerClass * kMaxImagesPerClass>, kMaxCameras>, kMaxCameras> dist;
    struct Hyp {
        float score;
        std::array<std::int8_t, kMaxCameras> idx;
    };
    constexpr int kMaxHyp = 512;
    std::array<Hyp, kMaxHyp> hyp;

    auto try_accept = [&](const Hyp& h, std::uint8_t cls) {
        int n = 0;
        for (int c = 0; c < ncam; ++c) {
            const int i = h.idx[std::size_t(c)];
            if (i < 0) continue;
            if (used[std::size_t(c)][std::size_t(i)]) return;
            const ImagePoint& p = views[std::size_t(c)].points[std::size_t(i)];
            obs[std::size_t(n++)] = Observation{c, p.px, p.xn, p.sigma_px};
        }
        const TriangulatedPoint tp =
            triangulate(cams_, std::span<const Observation>(obs.data(), std::size_t(n)), opt_.triangulation);
        bool ok = tp.usable() && tp.rms_px <= opt_.max_rms_px;
        const ClassRegion& reg = opt_.region[cls];
        if (ok && reg.enabled)
            ok = std::abs((tp.X_rig_mm - reg.centre_rig_mm).norm() - reg.radius_mm) <= reg.tolerance_mm;
        if (!ok) {
            ++out.rejected_hypotheses;
            return;
        }
        if (out.count >= kMaxMarkersPerFrame) return;
        MatchedMarker& m = out.markers[std::size_t(out.count++)];
        m.colour_class = cls;
        m.point = tp;
        m.image_index = h.idx;
        m.occluded_views = 0;
        m.occluded = false;
        if (opt_.marker_radius_mm > 0.0) check_occlusion(views, m, ncam);
        for (int c = 0; c < ncam; ++c)
            if (h.idx[std::size_t(c)] >= 0) used[std::size_t(c)][std::size_t(h.idx[std::size_t(c)])] = true;
    };

    for (std::uint8_t cls = 1; cls <= 4; ++cls) {
        int present = 0;
        for (int c = 0; c < ncam; ++c) {
            nm[std::size_t(c)] = 0;
            const CameraObservations& v = views[std::size_t(c)];
            if (!v.present) continue;
            for (int i = 0; i < v.count && nm[std::size_t(c)] < kMaxImagesPerClass; ++i) {
                const ImagePoint& p = v.points[std::size_t(i)];
                if (p.colour_class == cls && p.xn.allFinite())
                    members[std::size_t(c)][std::size_t(nm[std::size_t(c)]++)] = std::int8_t(i);
            }
            if (nm[std::size_t(c)] > 0) ++present;
        }
        if (present < 2) continue;
        // Pairwise epipolar distances: the epipolar line of each image of a in b, then point-line distances.
        for (int a = 0; a < ncam; ++a)
            for (int b = a + 1; b < ncam; ++b) {
                const Eigen::Matrix3d& E = E_[std::size_t(a)][std::size_t(b)];
                const double fa = cams_[std::size_t(a)].mean_focal_px(), fb = cams_[std::size_t(b)].mean_focal_px();
                for (int i = 0; i < nm[std::size_t(a)]; ++i) {
                    const Eigen::Vector2d& xa = views[std::size_t(a)].points[std::size_t(members[std::size_t(a)][std::size_t(i)])].xn;
                    const Eigen::Vector3d lb = E * Eigen::Vector3d(xa.x(), xa.y(), 1.0);
                    const double inv_lb = fb / std::sqrt(lb.x() * lb.x() + lb.y() * lb.y() + 1e-300);
                    for (int j = 0; j < nm[std::size_t(b)]; ++j) {
                        const Eigen::Vector2d& xb = views[std::size_t(b)].points[std::size_t(members[std::size_t(b)][std::size_t(j)])].xn;
                        const Eigen::Vector3d la = E.transpose() * Eigen::Vector3d(xb.x(), xb.y(), 1.0);
                        const double e = std::abs(xb.x() * lb.x() + xb.y() * lb.y() + lb.z());
                        const double da = e * fa / std::sqrt(la.x() * la.x() + la.y() * la.y() + 1e-300);
                        dist[std::size_t(a)][std::size_t(b)][std::size_t(i * kMaxImagesPerClass + j)] =
                            float(0.5 * (da + e * inv_lb));
                    }
                }
            }
        const float gate = float(opt_.epipolar_gate_px);
        auto d = [&](int a, int i, int b, int j) {
            return dist[std::size_t(a)][std::size_t(b)][std::size_t(i * kMaxImagesPerClass + j)];
        };
        // Three-view candidates (epipolar transfer: the third image lies on both other images' lines).
        int nh = 0;
        for (int a = 0; a < ncam; ++a)
            for (int b = a + 1; b < ncam; ++b)
                for (int c = b + 1; c < ncam; ++c)
                    for (int i = 0; i < nm[std::size_t(a)]; ++i)
                        for (int j = 0; j < nm[std::size_t(b)]; ++j) {
                            const float dab = d(a, i, b, j);
                            if (dab > gate) continue;
                            for (int k = 0; k < nm[std::size_t(c)]; ++k) {
                                const float dac = d(a, i, c, k), dbc = d(b, j, c, k);
                                if (dac > gate || dbc > gate || nh == kMaxHyp) continue;
                                Hyp& h = hyp[std::size_t(nh++)];
                                h.score = dab + dac + dbc;
                                h.idx.fill(-1);
                                h.idx[std::size_t(a)] = members[std::size_t(a)][std::size_t(i)];
                                h.idx[std::size_t(b)] = members[std::size_t(b)][std::size_t(j)];
                                h.idx[std::size_t(c)] = members[std::size_t(c)][std::size_t(k)];
                            }
                        }
        auto by_score = [](const Hyp& x, const Hyp& y) { return x.score < y.score; };
        std::sort(hyp.begin(), hyp.begin() + nh, by_score);
        for (int h = 0; h < nh; ++h) try_accept(hyp[std::size_t(h)], cls);
        // Two-view candidates among the images still free.
        nh = 0;
        for (int a = 0; a < ncam; ++a)
            for (int b = a + 1; b < ncam; ++b)
                for (int i = 0; i < nm[std::size_t(a)]; ++i) {
                    const int ia = members[std::size_t(a)][std::size_t(i)];
                    if (used[std::size_t(a)][std::size_t(ia)]) continue;
                    for (int j = 0; j < nm[std::size_t(b)]; ++j) {
                        const int jb = members[std::size_t(b)][std::size_t(j)];
                        if (used[std::size_t(b)][std::size_t(jb)] || d(a, i, b, j) > gate || nh == kMaxHyp) continue;
                        Hyp& h = hyp[std::size_t(nh++)];
                        h.score = d(a, i, b, j);
                        h.idx.fill(-1);
                        h.idx[std::size_t(a)] = std::int8_t(ia);
                        h.idx[std::size_t(b)] = std::int8_t(jb);
                    }
                }
        std::sort(hyp.begin(), hyp.begin() + nh, by_score);
        for (int h = 0; h < nh; ++h) try_accept(hyp[std::size_t(h)], cls);
    }
    for (int c = 0; c < ncam; ++c) {
        if (!views[std::size_t(c)].present) continue;
        for (int i = 0; i < views[std::size_t(c)].count; ++i)
            if (!used[std::size_t(c)][std::size_t(i)]) ++out.unmatched_images;
    }
}

}  // namespace eyesim::tracking
