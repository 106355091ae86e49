#include "eyesim/sim/collision/zcoll.hpp"

#include <algorithm>
#include <cmath>

namespace eyesim::sim::collision {

Vec3f eq1_push_vector(std::span<const Vec3f> deformation_vectors) {
    Vec3f sum = Vec3f::Zero();
    float max_len = 0.0f;
    for (const Vec3f& d : deformation_vectors) {
        sum += d;
        max_len = std::max(max_len, d.norm());
    }
    const float n = sum.norm();
    if (n <= 0.0f || max_len <= 0.0f) return Vec3f::Zero();
    return sum * (max_len / n);
}

void eq1_node_pushes(std::vector<uint32_t>& nodes, std::span<const Vec3f> node_sum, std::span<const float> node_max,
                     std::vector<Vec3f>& push) {
    std::sort(nodes.begin(), nodes.end());
    for (uint32_t v : nodes) {
        const float n = node_sum[v].norm();
        push.push_back(n > 0.0f ? Vec3f(node_sum[v] * (node_max[v] / n)) : Vec3f::Zero());
    }
}

ZcollEngine::ZcollEngine(const TriangleMesh& membrane, const ZcollConfig& config,
                         std::unique_ptr<ZcollRasterBackend> backend, size_t max_instrument_triangles)
    : topology_(membrane),
      config_(config),
      backend_(backend ? std::move(backend) : std::make_unique<CpuRasterBackend>(membrane.vertex_count() + 4096)),
      exact_(membrane.triangle_count(), max_instrument_triangles) {
    if (topology_.vertex_triangle_begin.size() != topology_.vertex_count() + 1) topology_.build_adjacency();
    buffers_.resize(config.resolution_px);
    const size_t nt = membrane.triangle_count(), nv = membrane.vertex_count();
    const size_t npx = size_t(config.resolution_px) * size_t(config.resolution_px);
    features_.reserve(npx);
    triangles_.reserve(nt);
    nodes_.reserve(nv);
    grabbed_.reserve(nv);
    suction_nodes_.reserve(nv);
    push_.reserve(nv);
    suction_force_.reserve(nv);
    tri_stamp_.assign(nt, 0);
    node_stamp_.assign(nv, 0);
    tri_sum_.assign(nt, Vec3f::Zero());
    tri_max_.assign(nt, 0.0f);
    node_sum_.assign(nv, Vec3f::Zero());
    node_max_.assign(nv, 0.0f);
}

ZcollEngine::~ZcollEngine() = default;

void ZcollEngine::reset_result() {
    result_ = ZcollResult{};
    features_.clear();
    triangles_.clear();
    nodes_.clear();
    grabbed_.clear();
    suction_nodes_.clear();
    push_.clear();
    suction_force_.clear();
    if (++stamp_ == 0) {  // wrap-around: forget every stamp
        std::fill(tri_stamp_.begin(), tri_stamp_.end(), 0u);
        std::fill(node_stamp_.begin(), node_stamp_.end(), 0u);
        stamp_ = 1;
    }
}

bool ZcollEngine::volume_touches(std::span<const Vec3f> membrane_vertices_eye_mm, const ZcollView& view) const {
    if (membrane_vertices_eye_mm.empty()) return false;
    Vec3f lo = membrane_vertices_eye_mm[0], hi = lo;
    for (const Vec3f& p : membrane_vertices_eye_mm) {
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
    }
    return box_overlaps_aabb(view_volume(view), lo, hi);
}

void ZcollEngine::collect_features(const ZcollView& view, bool only_single_layer) {
    const int r = view.resolution_px;
    const auto& b = buffers_;
    for (int y = b.y0; y <= b.y1; ++y)
        for (int x = b.x0; x <= b.x1; ++x) {
            const size_t p = size_t(y) * size_t(r) + size_t(x);
            // Paper lines 11–13: the instrument changed the depth buffer where the membrane was seen.
            if (b.cm[p] == 0 || !(b.zi_mm[p] < b.zm_mm[p])) continue;
            if (only_single_layer && b.layers[p] >= 2) continue;
            features_.push_back({b.cm[p] - 1u, uint16_t(x), uint16_t(y), b.zi_mm[p] - b.zm_mm[p]});
        }
    result_.features = features_;
}

void ZcollEngine::unique_triangles_from_features() {
    for (const ZcollFeature& f : features_)
        if (tri_stamp_[f.id] != stamp_) {
            tri_stamp_[f.id] = stamp_;
            triangles_.push_back(f.id);
        }
    std::sort(triangles_.begin(), triangles_.end());
}

void ZcollEngine::compute_push_vectors(const ZcollView& view) {
    // Eq. 1: v_i = max_{d∈D_i}|d| · Σd/|Σd|, D_i = the deformation vectors of node i's adjacent triangles
    // (triangle features) or of node i itself (vertex features). d = π · (ZI − ZM), eye frame.
    const Vec3f pi = view.direction_eye();
    const TriangleMesh& m = topology_;
    const uint32_t node_mark = stamp_;
    if (config_.features == FeatureKind::Triangle) {
        // Per colliding triangle: Σd and max|d| over its pixels.
        for (uint32_t t : triangles_) {
            tri_sum_[t] = Vec3f::Zero();
            tri_max_[t] = 0.0f;
        }
        for (const ZcollFeature& f : features_) {
            tri_sum_[f.id] += pi * f.depth_delta_mm;
            tri_max_[f.id] = std::max(tri_max_[f.id], std::fabs(f.depth_delta_mm));
        }
        for (uint32_t t : triangles_) {
            if (tri_stamp_[t] != stamp_ || tri_max_[t] <= 0.0f) continue;  // exact-only triangles: no vectors
            for (uint32_t v : m.triangles[t]) {
                if (node_stamp_[v] != node_mark) {
                    node_stamp_[v] = node_mark;
                    node_sum_[v] = Vec3f::Zero();
                    node_max_[v] = 0.0f;
                    nodes_.push_back(v);
                }
                node_sum_[v] += tri_sum_[t];
                node_max_[v] = std::max(node_max_[v], tri_max_[t]);
            }
        }
    } else {
        for (const ZcollFeature& f : features_) {
            const uint32_t v = f.id;
            if (node_stamp_[v] != node_mark) {
                node_stamp_[v] = node_mark;
                node_sum_[v] = Vec3f::Zero();
                node_max_[v] = 0.0f;
                nodes_.push_back(v);
            }
            node_sum_[v] += pi * f.depth_delta_mm;
            node_max_[v] = std::max(node_max_[v], std::fabs(f.depth_delta_mm));
        }
    }
    eq1_node_pushes(nodes_, node_sum_, node_max_, push_);
    result_.pushed_nodes = nodes_;
    result_.node_push_eye_mm = push_;
}

void ZcollEngine::collect_grab(std::span<const Vec3f> membrane_vertices_eye_mm, const PosedInstrument& instrument) {
    // Grab rule (§3.3.1): colliding nodes and nodes near the tip are bound to the tip.
    const TriangleMesh& m = topology_;
    const uint32_t mark = stamp_;
    auto add = [&](uint32_t v) {
        if (node_stamp_[v] != mark) {
            node_stamp_[v] = mark;
            grabbed_.push_back(v);
        }
    };
    if (config_.features == FeatureKind::Triangle) {
        for (uint32_t t : triangles_)
            for (uint32_t v : m.triangles[t]) add(v);
    } else {
        for (const ZcollFeature& f : features_) add(f.id);
    }
    const Vec3f tip = instrument.tip_eye_mm();
    const float r2 = config_.grab_radius_mm * config_.grab_radius_mm;
    for (uint32_t v = 0; v < membrane_vertices_eye_mm.size(); ++v)
        if ((membrane_vertices_eye_mm[v] - tip).squaredNorm() <= r2) add(v);
    std::sort(grabbed_.begin(), grabbed_.end());
    result_.grabbed_nodes = grabbed_;
    result_.grabbed = !grabbed_.empty();
}

const ZcollResult& ZcollEngine::push(std::span<const Vec3f> membrane_vertices_eye_mm,
                                     const PosedInstrument& instrument, const ZcollView& view) {
    reset_result();
    if (membrane_vertices_eye_mm.size() != topology_.vertex_count()) {
        result_.invalid_input = true;
        return result_;
    }
    if (!volume_touches(membrane_vertices_eye_mm, view)) {
        result_.gated_out = true;
        return result_;
    }
    const MeshRef membrane{membrane_vertices_eye_mm, topology_.triangles, Eigen::Isometry3f::Identity()};
    const MeshRef tool{instrument.vertices_local_mm(), instrument.instrument().mesh.triangles,
                       instrument.instrument_to_eye()};
    RasterRequest req;
    req.ids = config_.features;
    req.count_layers = config_.check_pi_convexity;
    req.instrument = true;
    backend_->render(membrane, &tool, view, req, buffers_);
    result_.multi_layer_pixels = config_.check_pi_convexity ? buffers_.multi_layer_pixels : 0;
    result_.pi_convex = result_.multi_layer_pixels == 0;
    const bool fallback = !result_.pi_convex && config_.exact_fallback;
    collect_features(view, fallback);
    if (config_.features == FeatureKind::Triangle) unique_triangles_from_features();
    if (fallback) {
        // Not π-convex in V: the exact narrow phase decides which triangles collide (inside V).
        const OrientedBox box = view_volume(view);
        ExactOptions opt;
        opt.within = &box;
        opt.vertex_triangle_begin = topology_.vertex_triangle_begin;
        opt.vertex_triangles = topology_.vertex_triangles;
        const auto exact = exact_.colliding_triangles(membrane, tool, instrument.instrument().part_triangle_begin, opt);
        triangles_.assign(exact.begin(), exact.end());
        result_.fallback_used = true;
    }
    result_.colliding_triangles = triangles_;
    result_.colliding = !triangles_.empty() || !features_.empty();
    const bool closed_forceps = instrument.instrument().kind == InstrumentKind::Forceps &&
                                instrument.opening_deg() < config_.grab_below_deg;
    if (closed_forceps) {
        collect_grab(membrane_vertices_eye_mm, instrument);
        if (result_.grabbed) return result_;
    }
    compute_push_vectors(view);
    return result_;
}

bool ZcollEngine::collides(std::span<const Vec3f> membrane_vertices_eye_mm, const PosedInstrument& instrument,
                           const ZcollView& view) {
    if (membrane_vertices_eye_mm.size() != topology_.vertex_count()) return false;
    if (!volume_touches(membrane_vertices_eye_mm, view)) return false;
    const MeshRef membrane{membrane_vertices_eye_mm, topology_.triangles, Eigen::Isometry3f::Identity()};
    const MeshRef tool{instrument.vertices_local_mm(), instrument.instrument().mesh.triangles,
                       instrument.instrument_to_eye()};
    return backend_->any_penetration(membrane, tool, view);
}

const ZcollResult& ZcollEngine::suction(std::span<const Vec3f> membrane_vertices_eye_mm, const ZcollView& cone_view,
                                        const Vec3f& suction_tip_eye_mm) {
    reset_result();
    if (membrane_vertices_eye_mm.size() != topology_.vertex_count()) {
        result_.invalid_input = true;
        return result_;
    }
    if (!volume_touches(membrane_vertices_eye_mm, cone_view)) {
        result_.gated_out = true;
        return result_;
    }
    const MeshRef membrane{membrane_vertices_eye_mm, topology_.triangles, Eigen::Isometry3f::Identity()};
    RasterRequest req;
    req.ids = FeatureKind::Triangle;
    req.count_layers = false;
    req.instrument = false;
    backend_->render(membrane, nullptr, cone_view, req, buffers_);
    // Lines 120–130: every non-background colour names a triangle in the suction cone.
    const int r = cone_view.resolution_px;
    for (int y = buffers_.y0; y <= buffers_.y1; ++y)
        for (int x = buffers_.x0; x <= buffers_.x1; ++x) {
            const uint32_t id = buffers_.cm[size_t(y) * size_t(r) + size_t(x)];
            if (id == 0 || tri_stamp_[id - 1] == stamp_) continue;
            tri_stamp_[id - 1] = stamp_;
            triangles_.push_back(id - 1);
        }
    std::sort(triangles_.begin(), triangles_.end());
    const TriangleMesh& m = topology_;
    for (uint32_t t : triangles_)
        for (uint32_t v : m.triangles[t]) {
            if (node_stamp_[v] == stamp_) continue;
            node_stamp_[v] = stamp_;
            // Only nodes that are themselves inside the frustum get a force.
            const Vec3f c = cone_view.to_camera(membrane_vertices_eye_mm[v]);
            const float lim = c.z() * cone_view.tan_half_angle;
            if (c.z() < cone_view.near_mm || c.z() > cone_view.far_mm || std::fabs(c.x()) > lim ||
                std::fabs(c.y()) > lim)
                continue;
            suction_nodes_.push_back(v);
        }
    std::sort(suction_nodes_.begin(), suction_nodes_.end());
    for (uint32_t v : suction_nodes_) {
        const Vec3f to_tip = suction_tip_eye_mm - membrane_vertices_eye_mm[v];
        const float d = std::max(to_tip.norm(), config_.suction_min_distance_mm);
        suction_force_.push_back(to_tip.normalized() * (config_.suction_gain_mm2 / d));
    }
    result_.colliding_triangles = triangles_;
    result_.suction_nodes = suction_nodes_;
    result_.suction_force_eye = suction_force_;
    result_.colliding = !suction_nodes_.empty();
    return result_;
}

}  // namespace eyesim::sim::collision
