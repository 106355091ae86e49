#include "eyesim/sim/collision/contact.hpp"

#include "eyesim/sim/collision/tri_tri.hpp"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

// The transform and outcode loops compare floats per vertex; without trapping-math semantics GCC turns the
// comparisons into vector selects (no FP exception flags are used here).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC optimize("no-trapping-math")
#endif

namespace eyesim::sim::collision {

namespace {

/// Margin of the float filters (mm). Coordinates in the instrument frame stay below ~20 mm for anything that
/// can touch an instrument (its bounds), so a transformed coordinate or a plane distance computed in float is
/// off by well under 1e-5 mm; pairs within the margin go to the double-precision predicates.
constexpr float kEps_mm = 2e-5f;
constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr int kMaxCells = 96;  // per axis of the instrument grid
constexpr int kMaxBins = 32;   // per axis of the deformation bins

/// Advances a stamp counter; on wrap-around clears the stamped arrays.
template <typename... Vs>
uint32_t bump(uint32_t& counter, Vs&... arrays) {
    if (++counter == 0) {
        (std::fill(arrays.begin(), arrays.end(), 0u), ...);
        counter = 1;
    }
    return counter;
}

}  // namespace

ExactContact::ExactContact(const TriangleMesh& membrane, size_t max_instrument_triangles) {
    triangles_ = membrane.triangles;
    vertex_count_ = membrane.vertex_count();
    if (membrane.vertex_triangle_begin.size() == vertex_count_ + 1) {
        vt_begin_ = membrane.vertex_triangle_begin;
        vt_items_ = membrane.vertex_triangles;
    } else {
        TriangleMesh copy = membrane;
        copy.build_adjacency();
        vt_begin_ = std::move(copy.vertex_triangle_begin);
        vt_items_ = std::move(copy.vertex_triangles);
    }
    const size_t nt = triangles_.size(), nv = vertex_count_;
    local_.resize(nv);
    code_.resize(nv);
    tri_stamp_.assign(nt, 0);
    tri_state_.assign(nt, 0);
    vert_stamp_.assign(nv, 0);
    vert_inside_.assign(nv, 0);
    vdepth_.assign(nv, 0.0f);
    vdepth_stamp_.assign(nv, 0);
    node_sum_.assign(nv, Vec3f::Zero());
    node_max_.assign(nv, 0.0f);
    node_stamp_.assign(nv, 0);
    out_.reserve(nt);
    queue_.reserve(nt);
    contacts_.reserve(nt);
    nodes_.reserve(nv);
    grabbed_.reserve(nv);
    push_.reserve(nv);
    const size_t ni = max_instrument_triangles;
    inst_vertices_.reserve(ni);
    inst_triangles_.reserve(ni);
    tris_.reserve(ni);
    tri_part_.reserve(ni);
    inst_stamp_.reserve(ni);
    cell_items_.reserve(ni * 8);
    iu_.reserve(ni);
    iw_.reserve(ni);
    is_.reserve(ni);
    rel_.reserve(ni);
    bin_items_.reserve(ni * 4);
    bin_begin_.reserve(kMaxBins * kMaxBins + 1);
    bin_fill_.reserve(kMaxBins * kMaxBins);
}

void ExactContact::reset_result() {
    result_ = ContactResult{};
    out_.clear();
    queue_.clear();
    contacts_.clear();
    nodes_.clear();
    grabbed_.clear();
    push_.clear();
    bump(query_, tri_stamp_, vert_stamp_, vdepth_stamp_, node_stamp_);
}

bool ExactContact::instrument_changed(const MeshRef& ins, std::span<const uint32_t> parts) const {
    if (!built_ || ins.vertices_mm.size() != inst_vertices_.size() ||
        ins.triangles.size() != inst_triangles_.size())
        return true;
    const size_t np = parts.size() > 1 ? parts.size() : 2;
    if (np != parts_.size()) return true;
    if (parts.size() > 1 && !std::equal(parts.begin(), parts.end(), parts_.begin())) return true;
    // The articulation (forceps opening) moves vertices: compare them all (≈12 kB, about a microsecond).
    return std::memcmp(ins.vertices_mm.data(), inst_vertices_.data(), ins.vertices_mm.size_bytes()) != 0 ||
           std::memcmp(ins.triangles.data(), inst_triangles_.data(), ins.triangles.size_bytes()) != 0;
}

void ExactContact::build_instrument(const MeshRef& ins, std::span<const uint32_t> parts) {
    inst_vertices_.assign(ins.vertices_mm.begin(), ins.vertices_mm.end());
    inst_triangles_.assign(ins.triangles.begin(), ins.triangles.end());
    const size_t nt = inst_triangles_.size();
    if (parts.size() > 1) parts_.assign(parts.begin(), parts.end());
    else parts_.assign({0u, uint32_t(nt)});
    tris_.resize(nt);
    lo_ = Vec3f::Constant(kInf);
    hi_ = Vec3f::Constant(-kInf);
    for (size_t t = 0; t < nt; ++t) {
        const auto& tr = inst_triangles_[t];
        InstTri& T = tris_[t];
        T.a = inst_vertices_[tr[0]];
        T.b = inst_vertices_[tr[1]];
        T.c = inst_vertices_[tr[2]];
        const Vec3f n = (T.b - T.a).cross(T.c - T.a);
        const float len = n.norm();
        T.n = len > 0.0f ? Vec3f(n / len) : Vec3f::Zero();  // degenerate: never rejected by the filter
        T.d = T.n.dot(T.a);
        T.lo = T.a.cwiseMin(T.b).cwiseMin(T.c);
        T.hi = T.a.cwiseMax(T.b).cwiseMax(T.c);
        lo_ = lo_.cwiseMin(T.lo);
        hi_ = hi_.cwiseMax(T.hi);
    }
    const size_t np = parts_.size() - 1;
    part_lo_.assign(np, Vec3f::Constant(kInf));
    part_hi_.assign(np, Vec3f::Constant(-kInf));
    tri_part_.resize(nt);
    for (size_t p = 0; p < np; ++p)
        for (uint32_t t = parts_[p]; t < parts_[p + 1] && t < nt; ++t) {
            tri_part_[t] = uint32_t(p);
            part_lo_[p] = part_lo_[p].cwiseMin(tris_[t].lo);
            part_hi_[p] = part_hi_[p].cwiseMax(tris_[t].hi);
        }
    // Uniform grid in the instrument frame, cells about the size of the instrument's triangles (built once per
    // articulation, so it can afford to be fine).
    const Vec3f ext = (hi_ - lo_).cwiseMax(Vec3f::Constant(1e-4f));
    const float cell = std::max(ext.maxCoeff() / float(kMaxCells), std::cbrt(ext.prod() / float(std::max<size_t>(nt, 1))) * 0.75f);
    for (int k = 0; k < 3; ++k) dims_[k] = std::clamp(int(std::ceil(ext[k] / cell)), 1, kMaxCells);
    inv_cell_ = Vec3f(float(dims_[0]) / ext.x(), float(dims_[1]) / ext.y(), float(dims_[2]) / ext.z());
    const size_t ncell = size_t(dims_[0]) * size_t(dims_[1]) * size_t(dims_[2]);
    cell_begin_.assign(ncell + 1, 0);
    auto cell_of = [&](float x, int k) { return std::clamp(int((x - lo_[k]) * inv_cell_[k]), 0, dims_[k] - 1); };
    auto for_cells = [&](const Vec3f& a, const Vec3f& b, auto&& fn) {
        const int x0 = cell_of(a.x(), 0), x1 = cell_of(b.x(), 0), y0 = cell_of(a.y(), 1), y1 = cell_of(b.y(), 1),
                  z0 = cell_of(a.z(), 2), z1 = cell_of(b.z(), 2);
        for (int z = z0; z <= z1; ++z)
            for (int y = y0; y <= y1; ++y)
                for (int x = x0; x <= x1; ++x)
                    fn((size_t(z) * size_t(dims_[1]) + size_t(y)) * size_t(dims_[0]) + size_t(x));
    };
    const Vec3f m = Vec3f::Constant(kEps_mm);
    for (size_t t = 0; t < nt; ++t) for_cells(tris_[t].lo - m, tris_[t].hi + m, [&](size_t c) { ++cell_begin_[c + 1]; });
    for (size_t c = 0; c < ncell; ++c) cell_begin_[c + 1] += cell_begin_[c];
    cell_items_.resize(cell_begin_[ncell]);
    cell_fill_.assign(cell_begin_.begin(), cell_begin_.end() - 1);
    for (size_t t = 0; t < nt; ++t)
        for_cells(tris_[t].lo - m, tris_[t].hi + m, [&](size_t c) { cell_items_[cell_fill_[c]++] = uint32_t(t); });
    inst_stamp_.assign(nt, 0);
    inst_query_ = 0;
    built_ = true;
}

bool ExactContact::intersects_any(uint32_t mt) {
    const auto& tr = triangles_[mt];
    const Vec3f &a = local_[tr[0]], &b = local_[tr[1]], &c = local_[tr[2]];
    const Vec3f m = Vec3f::Constant(kEps_mm);
    const Vec3f tlo = a.cwiseMin(b).cwiseMin(c) - m, thi = a.cwiseMax(b).cwiseMax(c) + m;
    auto cell_of = [&](float x, int k) { return std::clamp(int((x - lo_[k]) * inv_cell_[k]), 0, dims_[k] - 1); };
    const int x0 = cell_of(tlo.x(), 0), x1 = cell_of(thi.x(), 0), y0 = cell_of(tlo.y(), 1), y1 = cell_of(thi.y(), 1),
              z0 = cell_of(tlo.z(), 2), z1 = cell_of(thi.z(), 2);
    const uint32_t q = bump(inst_query_, inst_stamp_);
    // The membrane triangle's plane (unnormalised) for the second filter.
    const Vec3f nm = (b - a).cross(c - a);
    const float dm = nm.dot(a), epsm = kEps_mm * nm.norm();
    for (int z = z0; z <= z1; ++z)
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                const size_t cidx = (size_t(z) * size_t(dims_[1]) + size_t(y)) * size_t(dims_[0]) + size_t(x);
                for (uint32_t k = cell_begin_[cidx]; k < cell_begin_[cidx + 1]; ++k) {
                    const uint32_t it = cell_items_[k];
                    if (inst_stamp_[it] == q) continue;
                    inst_stamp_[it] = q;
                    const InstTri& T = tris_[it];
                    if ((thi.array() < T.lo.array()).any() || (tlo.array() > T.hi.array()).any()) continue;
                    // Plane filters (float, conservative margin): all of one triangle strictly on one side of
                    // the other's plane → disjoint.
                    const float da = T.n.dot(a) - T.d, db = T.n.dot(b) - T.d, dc = T.n.dot(c) - T.d;
                    if ((da > kEps_mm && db > kEps_mm && dc > kEps_mm) || (da < -kEps_mm && db < -kEps_mm && dc < -kEps_mm))
                        continue;
                    const float ea = nm.dot(T.a) - dm, eb = nm.dot(T.b) - dm, ec = nm.dot(T.c) - dm;
                    if ((ea > epsm && eb > epsm && ec > epsm) || (ea < -epsm && eb < -epsm && ec < -epsm)) continue;
                    ++result_.pair_tests;
                    if (triangles_intersect(a, b, c, T.a, T.b, T.c)) return true;
                }
            }
    return false;
}

bool ExactContact::inside_any_part(const Vec3f& p) {
    ++result_.inside_tests;
    // Ray parity along an almost axis-aligned direction (+x with a tiny skew against hits on the edges of
    // regular meshes): the ray stays within one or two grid rows. Per part: parts may overlap.
    const double sy = 1.37e-4, sz = 0.71e-4;
    const Eigen::Vector3d dir(1.0, sy, sz);
    const Eigen::Vector3d o = p.cast<double>();
    auto cell = [&](float x, int k) { return std::clamp(int((x - lo_[k]) * inv_cell_[k]), 0, dims_[k] - 1); };
    for (size_t part = 0; part + 1 < parts_.size(); ++part) {
        if ((p.array() < part_lo_[part].array()).any() || (p.array() > part_hi_[part].array()).any()) continue;
        const float run = part_hi_[part].x() - p.x();
        const int x0 = cell(p.x(), 0), x1 = cell(part_hi_[part].x(), 0);
        const int y0 = cell(p.y(), 1), y1 = cell(p.y() + float(sy) * run, 1);
        const int z0 = cell(p.z(), 2), z1 = cell(p.z() + float(sz) * run, 2);
        const uint32_t q = bump(inst_query_, inst_stamp_);
        const uint32_t t0 = parts_[part], t1 = parts_[part + 1];
        int crossings = 0;
        for (int z = z0; z <= z1; ++z)
            for (int y = y0; y <= y1; ++y)
                for (int x = x0; x <= x1; ++x) {
                    const size_t c = (size_t(z) * size_t(dims_[1]) + size_t(y)) * size_t(dims_[0]) + size_t(x);
                    for (uint32_t k = cell_begin_[c]; k < cell_begin_[c + 1]; ++k) {
                        const uint32_t it = cell_items_[k];
                        if (it < t0 || it >= t1 || inst_stamp_[it] == q) continue;
                        inst_stamp_[it] = q;
                        const InstTri& T = tris_[it];
                        if (T.hi.x() < p.x()) continue;
                        const Eigen::Vector3d v0 = T.a.cast<double>();
                        const Eigen::Vector3d e1 = T.b.cast<double>() - v0, e2 = T.c.cast<double>() - v0;
                        const Eigen::Vector3d h = dir.cross(e2);
                        const double det = e1.dot(h);
                        if (std::fabs(det) < 1e-18) continue;
                        const Eigen::Vector3d s = o - v0;
                        const double u = s.dot(h) / det;
                        if (u < 0 || u > 1) continue;
                        const Eigen::Vector3d qq = s.cross(e1);
                        const double w = dir.dot(qq) / det;
                        if (w < 0 || u + w > 1) continue;
                        if (e2.dot(qq) / det > 0) ++crossings;
                    }
                }
        if (crossings & 1) return true;
    }
    return false;
}

float ExactContact::front_depth(float u, float w, float s) const {
    // Smallest depth s of the instrument surface on the line through (u, w) along π; +inf when none.
    const int bu = int((u - bu0_) * binv_u_), bw = int((w - bw0_) * binv_w_);
    if (bu < 0 || bw < 0 || bu >= bins_ || bw >= bins_) return kInf;
    const size_t b = size_t(bw) * size_t(bins_) + size_t(bu);
    float best = kInf;
    (void)s;
    for (uint32_t k = bin_begin_[b]; k < bin_begin_[b + 1]; ++k) {
        const auto& tr = inst_triangles_[bin_items_[k]];
        const float u0 = iu_[tr[0]], w0 = iw_[tr[0]], u1 = iu_[tr[1]], w1 = iw_[tr[1]], u2 = iu_[tr[2]], w2 = iw_[tr[2]];
        const float area = (u1 - u0) * (w2 - w0) - (w1 - w0) * (u2 - u0);
        const float l1 = ((u - u0) * (w2 - w0) - (w - w0) * (u2 - u0)) / area;
        const float l2 = ((u1 - u0) * (w - w0) - (w1 - w0) * (u - u0)) / area;
        const float l0 = 1.0f - l1 - l2;
        constexpr float kTol = -1e-6f;  // closed triangles: a line through a shared edge meets both
        if (l0 < kTol || l1 < kTol || l2 < kTol) continue;
        best = std::min(best, l0 * is_[tr[0]] + l1 * is_[tr[1]] + l2 * is_[tr[2]]);
    }
    return best;
}

void ExactContact::compute_deformation(std::span<const Vec3f> verts_eye, const Eigen::Isometry3f& to_eye,
                                       const Vec3f& pi_eye) {
    // π and a basis of the plane ⊥ π, in the instrument frame.
    ps_ = (to_eye.linear().transpose() * pi_eye).normalized();
    const Vec3f hint = std::fabs(ps_.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY();
    pu_ = ps_.cross(hint).normalized();
    pw_ = ps_.cross(pu_);
    // Region ⊥ π covered by the colliding triangles, and their deepest point along π.
    float u_lo = kInf, u_hi = -kInf, w_lo = kInf, w_hi = -kInf, s_hi = -kInf;
    for (uint32_t t : out_)
        for (uint32_t v : triangles_[t]) {
            const float u = pu_.dot(local_[v]), w = pw_.dot(local_[v]), s = ps_.dot(local_[v]);
            u_lo = std::min(u_lo, u);
            u_hi = std::max(u_hi, u);
            w_lo = std::min(w_lo, w);
            w_hi = std::max(w_hi, w);
            s_hi = std::max(s_hi, s);
        }
    // Instrument vertices in (u, w, s); triangles over the region that reach in front of the membrane.
    const size_t niv = inst_vertices_.size();
    iu_.resize(niv);
    iw_.resize(niv);
    is_.resize(niv);
    for (size_t i = 0; i < niv; ++i) {
        const Vec3f& v = inst_vertices_[i];
        iu_[i] = pu_.dot(v);
        iw_[i] = pw_.dot(v);
        is_[i] = ps_.dot(v);
    }
    rel_.clear();
    for (uint32_t t = 0; t < inst_triangles_.size(); ++t) {
        const auto& tr = inst_triangles_[t];
        const float a0 = iu_[tr[0]], a1 = iu_[tr[1]], a2 = iu_[tr[2]];
        if (std::max({a0, a1, a2}) < u_lo || std::min({a0, a1, a2}) > u_hi) continue;
        const float b0 = iw_[tr[0]], b1 = iw_[tr[1]], b2 = iw_[tr[2]];
        if (std::max({b0, b1, b2}) < w_lo || std::min({b0, b1, b2}) > w_hi) continue;
        if (std::min({is_[tr[0]], is_[tr[1]], is_[tr[2]]}) > s_hi) continue;
        const float area = (a1 - a0) * (b2 - b0) - (b1 - b0) * (a2 - a0);
        if (std::fabs(area) < 1e-12f) continue;  // seen edge-on: its neighbours cover the line
        rel_.push_back(t);
    }
    bins_ = std::clamp(int(std::sqrt(double(rel_.size()) / 2.0)), 1, kMaxBins);
    const float eu = std::max(u_hi - u_lo, 1e-6f), ew = std::max(w_hi - w_lo, 1e-6f);
    bu0_ = u_lo;
    bw0_ = w_lo;
    binv_u_ = float(bins_) / eu * (1.0f - 1e-6f);
    binv_w_ = float(bins_) / ew * (1.0f - 1e-6f);
    const size_t nb = size_t(bins_) * size_t(bins_);
    bin_begin_.assign(nb + 1, 0);
    auto bin_range = [&](uint32_t t, int& x0, int& x1, int& y0, int& y1) {
        const auto& tr = inst_triangles_[t];
        const float ulo = std::min({iu_[tr[0]], iu_[tr[1]], iu_[tr[2]]}), uhi = std::max({iu_[tr[0]], iu_[tr[1]], iu_[tr[2]]});
        const float wlo = std::min({iw_[tr[0]], iw_[tr[1]], iw_[tr[2]]}), whi = std::max({iw_[tr[0]], iw_[tr[1]], iw_[tr[2]]});
        x0 = std::clamp(int((ulo - bu0_) * binv_u_), 0, bins_ - 1);
        x1 = std::clamp(int((uhi - bu0_) * binv_u_), 0, bins_ - 1);
        y0 = std::clamp(int((wlo - bw0_) * binv_w_), 0, bins_ - 1);
        y1 = std::clamp(int((whi - bw0_) * binv_w_), 0, bins_ - 1);
    };
    for (uint32_t t : rel_) {
        int x0, x1, y0, y1;
        bin_range(t, x0, x1, y0, y1);
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) ++bin_begin_[size_t(y) * size_t(bins_) + size_t(x) + 1];
    }
    for (size_t b = 0; b < nb; ++b) bin_begin_[b + 1] += bin_begin_[b];
    bin_items_.resize(bin_begin_[nb]);
    bin_fill_.assign(bin_begin_.begin(), bin_begin_.end() - 1);
    for (uint32_t t : rel_) {
        int x0, x1, y0, y1;
        bin_range(t, x0, x1, y0, y1);
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) bin_items_[bin_fill_[size_t(y) * size_t(bins_) + size_t(x)]++] = t;
    }
    // ZI − ZM at a membrane point: the front-most instrument surface on its line minus its own depth, ≤ 0.
    auto delta_at = [&](const Vec3f& p_local) {
        const float s = ps_.dot(p_local);
        const float front = front_depth(pu_.dot(p_local), pw_.dot(p_local), s);
        return std::min(0.0f, front - s);
    };
    for (uint32_t t : out_) {
        const auto& tr = triangles_[t];
        TriangleContact c;
        c.triangle = t;
        c.depth_delta_mm = 0.0f;
        c.point_eye_mm = (verts_eye[tr[0]] + verts_eye[tr[1]] + verts_eye[tr[2]]) / 3.0f;
        for (uint32_t v : tr) {
            if (vdepth_stamp_[v] != query_) {
                vdepth_stamp_[v] = query_;
                vdepth_[v] = delta_at(local_[v]);
            }
            if (vdepth_[v] < c.depth_delta_mm) {
                c.depth_delta_mm = vdepth_[v];
                c.point_eye_mm = verts_eye[v];
            }
        }
        const float centre = delta_at((local_[tr[0]] + local_[tr[1]] + local_[tr[2]]) / 3.0f);
        if (centre < c.depth_delta_mm) {
            c.depth_delta_mm = centre;
            c.point_eye_mm = (verts_eye[tr[0]] + verts_eye[tr[1]] + verts_eye[tr[2]]) / 3.0f;
        }
        contacts_.push_back(c);
    }
    result_.contacts = contacts_;
}

const ContactResult& ExactContact::query(std::span<const Vec3f> verts, const PosedInstrument& instrument,
                                         const Vec3f& pi_eye, const ContactOptions& options) {
    const MeshRef tool{instrument.vertices_local_mm(), instrument.instrument().mesh.triangles,
                       instrument.instrument_to_eye()};
    return query(verts, tool, instrument.instrument().part_triangle_begin, pi_eye, options);
}

const ContactResult& ExactContact::query(std::span<const Vec3f> verts, const MeshRef& instrument,
                                         std::span<const uint32_t> part_triangle_begin, const Vec3f& pi_eye,
                                         const ContactOptions& options) {
    reset_result();
    if (verts.size() != vertex_count_ || instrument.triangles.empty()) {
        result_.invalid_input = true;
        return result_;
    }
    if (instrument_changed(instrument, part_triangle_begin)) {
        build_instrument(instrument, part_triangle_begin);
        result_.rebuilt = true;
    }
    // Membrane → instrument frame, outcodes against the instrument's bounds (with the filter margin).
    const Eigen::Matrix3f r = instrument.to_eye.linear().transpose();
    const Vec3f tr = -(r * instrument.to_eye.translation());
    const float r00 = r(0, 0), r01 = r(0, 1), r02 = r(0, 2), r10 = r(1, 0), r11 = r(1, 1), r12 = r(1, 2);
    const float r20 = r(2, 0), r21 = r(2, 1), r22 = r(2, 2), t0 = tr.x(), t1 = tr.y(), t2 = tr.z();
    const float lx = lo_.x() - kEps_mm, ly = lo_.y() - kEps_mm, lz = lo_.z() - kEps_mm;
    const float hx = hi_.x() + kEps_mm, hy = hi_.y() + kEps_mm, hz = hi_.z() + kEps_mm;
    const size_t nv = verts.size();
    const float* __restrict in = verts.data()->data();
    float* __restrict out = local_.data()->data();
    uint8_t* __restrict code = code_.data();
    for (size_t i = 0; i < nv; ++i) {
        const float x = in[3 * i], y = in[3 * i + 1], z = in[3 * i + 2];
        const float px = r00 * x + r01 * y + r02 * z + t0;
        const float py = r10 * x + r11 * y + r12 * z + t1;
        const float pz = r20 * x + r21 * y + r22 * z + t2;
        out[3 * i] = px;
        out[3 * i + 1] = py;
        out[3 * i + 2] = pz;
        code[i] = uint8_t((px < lx) | ((px > hx) << 1) | ((py < ly) << 2) | ((py > hy) << 3) | ((pz < lz) << 4) |
                          ((pz > hz) << 5));
    }
    const uint32_t q = query_;
    const size_t nt = triangles_.size();
    enum : uint8_t { kMiss = 0, kHit = 1, kInside = 2 };
    auto within = [&](uint32_t t) {
        if (!options.within) return true;
        const auto& tri = triangles_[t];
        const Vec3f &a = verts[tri[0]], &b = verts[tri[1]], &c = verts[tri[2]];
        return box_overlaps_aabb(*options.within, a.cwiseMin(b).cwiseMin(c), a.cwiseMax(b).cwiseMax(c));
    };
    for (size_t mt = 0; mt < nt; ++mt) {
        const auto& tri = triangles_[mt];
        if (code[tri[0]] & code[tri[1]] & code[tri[2]]) continue;
        if (!within(uint32_t(mt))) continue;
        ++result_.candidate_triangles;
        tri_stamp_[mt] = q;
        const bool hit = intersects_any(uint32_t(mt));
        tri_state_[mt] = hit ? kHit : kMiss;
        if (hit) out_.push_back(uint32_t(mt));
    }
    if (options.include_contained && !out_.empty()) {
        // A membrane triangle inside a part without touching its surface shares a vertex with a hit or another
        // such triangle: grow from the hits. A triangle that meets no instrument triangle is wholly inside or
        // wholly outside, and so are its vertices: one parity test classifies a whole run of neighbours.
        queue_.assign(out_.begin(), out_.end());
        for (size_t qi = 0; qi < queue_.size(); ++qi) {
            for (uint32_t v : triangles_[queue_[qi]]) {
                for (uint32_t k = vt_begin_[v]; k < vt_begin_[v + 1]; ++k) {
                    const uint32_t t = vt_items_[k];
                    if (tri_stamp_[t] != q || tri_state_[t] != kMiss) continue;  // outside the bounds, or decided
                    tri_state_[t] = 3;  // visited
                    const auto& tri = triangles_[t];
                    int known = -1;
                    for (uint32_t w : tri)
                        if (vert_stamp_[w] == q) known = vert_inside_[w];
                    if (known < 0) known = inside_any_part(local_[tri[0]]) ? 1 : 0;
                    for (uint32_t w : tri) {
                        vert_stamp_[w] = q;
                        vert_inside_[w] = uint8_t(known);
                    }
                    if (known) {
                        tri_state_[t] = kInside;
                        out_.push_back(t);
                        queue_.push_back(t);
                    }
                }
            }
        }
        std::sort(out_.begin(), out_.end());
    }
    result_.colliding_triangles = out_;
    result_.colliding = !out_.empty();
    if (out_.empty()) return result_;
    if (options.deformation) compute_deformation(verts, instrument.to_eye, pi_eye);
    if (options.grab) {
        // Grab rule: nodes of the colliding triangles and nodes near the tip are bound to the tip.
        auto add = [&](uint32_t v) {
            if (node_stamp_[v] != q) {
                node_stamp_[v] = q;
                grabbed_.push_back(v);
            }
        };
        for (uint32_t t : out_)
            for (uint32_t v : triangles_[t]) add(v);
        const float r2 = options.grab_radius_mm * options.grab_radius_mm;
        for (uint32_t v = 0; v < nv; ++v)
            if ((verts[v] - options.grab_tip_eye_mm).squaredNorm() <= r2) add(v);
        std::sort(grabbed_.begin(), grabbed_.end());
        result_.grabbed_nodes = grabbed_;
        result_.grabbed = !grabbed_.empty();
        if (result_.grabbed) return result_;
    }
    if (options.deformation) {
        // Eq. 1 over node i's adjacent colliding triangles: v_i = max|d| · Σd / |Σd|, d = π · (ZI − ZM).
        const Vec3f pi = pi_eye.normalized();
        for (const TriangleContact& c : contacts_) {
            if (c.depth_delta_mm >= 0.0f) continue;
            const Vec3f d = pi * c.depth_delta_mm;
            for (uint32_t v : triangles_[c.triangle]) {
                if (node_stamp_[v] != q) {
                    node_stamp_[v] = q;
                    node_sum_[v] = Vec3f::Zero();
                    node_max_[v] = 0.0f;
                    nodes_.push_back(v);
                }
                node_sum_[v] += d;
                node_max_[v] = std::max(node_max_[v], -c.depth_delta_mm);
            }
        }
        std::sort(nodes_.begin(), nodes_.end());
        for (uint32_t v : nodes_) {
            const float n = node_sum_[v].norm();
            push_.push_back(n > 0.0f ? Vec3f(node_sum_[v] * (node_max_[v] / n)) : Vec3f::Zero());
        }
        result_.pushed_nodes = nodes_;
        result_.node_push_eye_mm = push_;
    }
    return result_;
}

}  // namespace eyesim::sim::collision
