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

/// A candidate match: one image index per camera (−1 unused) and its triangulation.
struct Hypothesis {
    std::array<std::int8_t, kMaxCameras> idx{};
    TriangulatedPoint point;
    int views = 0;
};

constexpr int kMaxHypotheses = 256;

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
    std::array<Hypothesis, kMaxHypotheses> hyp;
    std::array<Observation, kMaxCameras> obs;

    auto build_obs = [&](const std::array<std::int8_t, kMaxCameras>& idx) {
        int n = 0;
        for (int c = 0; c < ncam; ++c) {
            if (idx[std::size_t(c)] < 0) continue;
            const ImagePoint& p = views[std::size_t(c)].points[std::size_t(idx[std::size_t(c)])];
            obs[std::size_t(n)] = Observation{c, p.px, p.xn, p.sigma_px};
            ++n;
        }
        return n;
    };

    for (std::uint8_t cls = 1; cls <= 4; ++cls) {
        // Hypotheses are generated from consistent pairs, extended by a third camera when it agrees.
        int nh = 0;
        for (int a = 0; a < ncam; ++a) {
            const CameraObservations& va = views[std::size_t(a)];
            if (!va.present) continue;
            for (int b = a + 1; b < ncam; ++b) {
                const CameraObservations& vb = views[std::size_t(b)];
                if (!vb.present) continue;
                for (int i = 0; i < va.count; ++i) {
                    const ImagePoint& pa = va.points[std::size_t(i)];
                    if (pa.colour_class != cls || !pa.xn.allFinite()) continue;
                    for (int j = 0; j < vb.count; ++j) {
                        const ImagePoint& pb = vb.points[std::size_t(j)];
                        if (pb.colour_class != cls || !pb.xn.allFinite()) continue;
                        if (epipolar_distance_px(a, b, pa.xn, pb.xn) > opt_.epipolar_gate_px) continue;
                        // Pair hypothesis.
                        if (nh < kMaxHypotheses) {
                            Hypothesis& h = hyp[std::size_t(nh++)];
                            h.idx.fill(-1);
                            h.idx[std::size_t(a)] = std::int8_t(i);
                            h.idx[std::size_t(b)] = std::int8_t(j);
                            h.views = 2;
                        }
                        // Three-view extensions: a third camera c > b whose image lies on both epipolar lines
                        // (epipolar transfer). Only generated from the lowest pair so each triple appears once.
                        for (int c = b + 1; c < ncam; ++c) {
                            const CameraObservations& vc = views[std::size_t(c)];
                            if (!vc.present) continue;
                            for (int k = 0; k < vc.count; ++k) {
                                const ImagePoint& pc = vc.points[std::size_t(k)];
                                if (pc.colour_class != cls || !pc.xn.allFinite()) continue;
                                if (epipolar_distance_px(a, c, pa.xn, pc.xn) > opt_.epipolar_gate_px) continue;
                                if (epipolar_distance_px(b, c, pb.xn, pc.xn) > opt_.epipolar_gate_px) continue;
                                if (nh < kMaxHypotheses) {
                                    Hypothesis& h = hyp[std::size_t(nh++)];
                                    h.idx.fill(-1);
                                    h.idx[std::size_t(a)] = std::int8_t(i);
                                    h.idx[std::size_t(b)] = std::int8_t(j);
                                    h.idx[std::size_t(c)] = std::int8_t(k);
                                    h.views = 3;
                                }
                            }
                        }
                    }
                }
            }
        }
        if (nh == 0) continue;
        // Order: more views first; triangulate lazily so that a clean three-view match costs one solve.
        std::sort(hyp.begin(), hyp.begin() + nh, [](const Hypothesis& x, const Hypothesis& y) {
            return x.views > y.views;
        });
        for (int h = 0; h < nh; ++h) {
            Hypothesis& H = hyp[std::size_t(h)];
            H.point.flags = kTriTooFewViews;  // marks "not yet triangulated / unusable"
        }
        // Greedy acceptance within each view-count tier, best residual first.
        int tier_begin = 0;
        while (tier_begin < nh) {
            const int views_here = hyp[std::size_t(tier_begin)].views;
            int tier_end = tier_begin;
            while (tier_end < nh && hyp[std::size_t(tier_end)].views == views_here) ++tier_end;
            for (int h = tier_begin; h < tier_end; ++h) {
                Hypothesis& H = hyp[std::size_t(h)];
                bool free = true;
                for (int c = 0; c < ncam; ++c)
                    if (H.idx[std::size_t(c)] >= 0 && used[std::size_t(c)][std::size_t(H.idx[std::size_t(c)])])
                        free = false;
                if (!free) continue;
                const int n = build_obs(H.idx);
                H.point = triangulate(cams_, std::span<const Observation>(obs.data(), std::size_t(n)),
                                      opt_.triangulation);
                if (!H.point.usable() || H.point.rms_px > opt_.max_rms_px) {
                    ++out.rejected_hypotheses;
                    H.point.flags |= kTriHighResidual;
                }
            }
            // Accept in residual order among usable hypotheses of this tier.
            while (true) {
                int best = -1;
                for (int h = tier_begin; h < tier_end; ++h) {
                    const Hypothesis& H = hyp[std::size_t(h)];
                    if (!H.point.usable() || H.point.rms_px > opt_.max_rms_px) continue;
                    bool free = true;
                    for (int c = 0; c < ncam; ++c)
                        if (H.idx[std::size_t(c)] >= 0 && used[std::size_t(c)][std::size_t(H.idx[std::size_t(c)])])
                            free = false;
                    if (!free) continue;
                    if (best < 0 || H.point.rms_px < hyp[std::size_t(best)].point.rms_px) best = h;
                }
                if (best < 0 || out.count >= kMaxMarkersPerFrame) break;
                const Hypothesis& B = hyp[std::size_t(best)];
                MatchedMarker& m = out.markers[std::size_t(out.count++)];
                m.colour_class = cls;
                m.point = B.point;
                m.image_index.fill(-1);
                for (int c = 0; c < ncam; ++c) {
                    m.image_index[std::size_t(c)] = B.idx[std::size_t(c)];
                    if (B.idx[std::size_t(c)] >= 0) used[std::size_t(c)][std::size_t(B.idx[std::size_t(c)])] = true;
                }
            }
            tier_begin = tier_end;
        }
    }
    for (int c = 0; c < ncam; ++c) {
        if (!views[std::size_t(c)].present) continue;
        for (int i = 0; i < views[std::size_t(c)].count; ++i)
            if (!used[std::size_t(c)][std::size_t(i)]) ++out.unmatched_images;
    }
}

}  // namespace eyesim::tracking
