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

double Correspondence::expected_area_px(int c, const Eigen::Vector3d& X_rig_mm) const {
    const CameraGeometry& g = cams_[std::size_t(c)];
    const double z = (g.R_cam_rig * X_rig_mm + g.t_cam_rig_mm).z();
    if (!(z > 0.0)) return -1.0;
    const double r = opt_.marker_radius_mm / z;
    return 3.141592653589793 * (g.fx * r) * (g.fy * r) * 0.5;  // field pixels
}

double Correspondence::area_ratio(const ImagePoint& p, int c, const Eigen::Vector3d& X_rig_mm) const {
    const double expected = expected_area_px(c, X_rig_mm);
    if (!(p.area_px > 0.0f) || !(expected > 0.0)) return -1.0;
    return double(p.area_px) / expected;
}

double Correspondence::relative_area_threshold(double expected_area_px) const {
    if (!(opt_.relative_area_noise > 0.0) || !(expected_area_px > 0.0)) return opt_.relative_area_ratio;
    return std::min(opt_.relative_area_ratio, 1.0 - opt_.relative_area_noise / std::sqrt(expected_area_px));
}

std::uint8_t Correspondence::occluded_views(std::span<const CameraObservations> views,
                                            const std::array<std::int8_t, kMaxCameras>& idx,
                                            const Eigen::Vector3d& X_rig_mm, int ncam, int& clean) const {
    std::array<double, kMaxCameras> ratio{};
    double best = 0.0;
    clean = 0;
    for (int c = 0; c < ncam; ++c) {
        ratio[std::size_t(c)] = -1.0;
        const int i = idx[std::size_t(c)];
        if (i < 0) continue;
        ratio[std::size_t(c)] = area_ratio(views[std::size_t(c)].points[std::size_t(i)], c, X_rig_mm);
        best = std::max(best, ratio[std::size_t(c)]);
    }
    std::uint8_t out = 0;
    for (int c = 0; c < ncam; ++c) {
        const double q = ratio[std::size_t(c)];
        if (idx[std::size_t(c)] < 0) continue;
        const double rel = q > 0.0 ? relative_area_threshold(expected_area_px(c, X_rig_mm)) : opt_.relative_area_ratio;
        if (best > 0.0 && q >= 0.0 && (q < opt_.min_area_ratio || q < rel * best))
            out = std::uint8_t(out | (1u << c));
        else
            ++clean;
    }
    return out;
}

void Correspondence::check_occlusion(std::span<const CameraObservations> views, MatchedMarker& m, int ncam) const {
    int clean = 0;
    m.occluded_views = occluded_views(views, m.image_index, m.point.X_rig_mm, ncam, clean);
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
    // Epipolar px a pair's score gains per unit of its poorer view's area ratio below min_area_ratio (a view
    // judged partly hidden): a blob at a fifth of its area costs twice the gate, so a pair that sees the marker
    // whole goes first. Ranking down every pair below 0.9 instead (a fifth hidden) made 2 s `occlusion` seeds 24
    // and 26 worse (eye 0.0324 → 0.0396°, 3D all 77 → 84 µm): there the clean-looking pair was the wrong one.
    constexpr double kHiddenPairPx = 10.0;
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
        TriangulatedPoint tp =
            triangulate(cams_, std::span<const Observation>(obs.data(), std::size_t(n)), opt_.triangulation);
        const ClassRegion& reg = opt_.region[cls];
        auto passes = [&](const TriangulatedPoint& p) {
            return p.usable() && p.rms_px <= opt_.max_rms_px &&
                   (!reg.enabled ||
                    std::abs((p.X_rig_mm - reg.centre_rig_mm).norm() - reg.radius_mm) <= reg.tolerance_mm);
        };
        bool ok = passes(tp);
        // Three views that agree to the epipolar gate but not to the residual: one of them may be a marker mostly
        // hidden, whose blob's centroid is a pixel or more from the centre (sweep seed 30: an instrument marker 70-80
        // % hidden in one camera). Its small blob says which: the marker is placed from the others, and that image
        // stays with it (occluded view), instead of the hidden view pairing with one of them in the two-view stage.
        std::uint8_t hidden = 0;
        if (!ok && n >= 3 && opt_.marker_radius_mm > 0.0 && tp.X_rig_mm.allFinite()) {
            int clean = 0;
            hidden = occluded_views(views, h.idx, tp.X_rig_mm, ncam, clean);
            if (hidden != 0 && clean >= 2) {
                int k = 0;
                for (int v = 0; v < n; ++v)
                    if (!(hidden & (1u << obs[std::size_t(v)].camera))) obs[std::size_t(k++)] = obs[std::size_t(v)];
                tp = triangulate(cams_, std::span<const Observation>(obs.data(), std::size_t(k)), opt_.triangulation);
                ok = passes(tp);
            }
        }
        if (!ok) {
            ++out.rejected_hypotheses;
            return;
        }
        if (out.count >= kMaxMarkersPerFrame) return;
        MatchedMarker& m = out.markers[std::size_t(out.count++)];
        m.colour_class = cls;
        m.point = tp;
        m.image_index = h.idx;
        m.occluded_views = hidden;
        m.occluded = false;
        if (opt_.marker_radius_mm > 0.0 && hidden == 0) check_occlusion(views, m, ncam);
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
                        // A pair whose poorer view's blob is small for the marker's depth (mostly hidden, its
                        // centroid off the centre) goes after pairs that see more of it: a hidden view's error along
                        // the epipolar line does not show in the distance (surgery seed 23: a forceps marker 80 %
                        // hidden in camera 0 paired with camera 2, 0.55 mm off, while cameras 1 and 2 saw it whole).
                        if (opt_.marker_radius_mm > 0.0) {
                            const ImagePoint& pa = views[std::size_t(a)].points[std::size_t(ia)];
                            const ImagePoint& pb = views[std::size_t(b)].points[std::size_t(jb)];
                            const std::array<Observation, 2> ob{Observation{a, pa.px, pa.xn, pa.sigma_px},
                                                                Observation{b, pb.px, pb.xn, pb.sigma_px}};
                            // The depth for the expected area: the linear point does (the area test is coarse).
                            Eigen::Vector3d X;
                            if (triangulate_dlt(cams_, ob, X) && X.allFinite()) {
                                const double q = std::min(area_ratio(pa, a, X), area_ratio(pb, b, X));
                                if (q >= 0.0) h.score += float(kHiddenPairPx * std::max(0.0, opt_.min_area_ratio - q));
                            }
                        }
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
