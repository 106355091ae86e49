#include "eyesim/sim/collision/raster_backend.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>

// The projection loops compare and convert floats per vertex; without trapping-math semantics GCC turns the
// comparisons into vector selects (no FP exception flags are used anywhere in this file).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC optimize("no-trapping-math")
#endif

namespace eyesim::sim::collision {

void RasterBuffers::resize(int r) {
    resolution_px = r;
    const size_t n = size_t(r) * size_t(r);
    zm_mm.assign(n, kEmptyDepth);
    zi_mm.assign(n, kEmptyDepth);
    cm.assign(n, 0);
    layers.assign(n, 0);
    multi_layer_pixels = 0;
    x0 = y0 = 0;
    x1 = y1 = -1;
}

namespace {

constexpr int kSubBits = 8;
constexpr int32_t kSub = 1 << kSubBits;
constexpr int32_t kHalf = kSub / 2;
constexpr float kClampFx = float(1 << 22);

struct Vtx {
    int32_t x, y;
    float q;
};

/// Rasterises one triangle with the top-left rule; calls frag(pixel index, depth, corner) for each covered
/// sample inside [0,R)², where corner ∈ {0,1,2} is the original vertex with the largest barycentric weight.
/// Returns true if frag asked to stop (by returning true).
template <bool kCentral, typename Frag>
inline bool raster_triangle(Vtx v0, Vtx v1, Vtx v2, int r, int bx0, int by0, int bx1, int by1, Frag&& frag) {
    int64_t area = int64_t(v1.x - v0.x) * (v2.y - v0.y) - int64_t(v1.y - v0.y) * (v2.x - v0.x);
    if (area == 0) return false;
    int corner_of[3] = {0, 1, 2};
    if (area < 0) {
        std::swap(v1, v2);
        std::swap(corner_of[1], corner_of[2]);
        area = -area;
    }
    // Pixel bounds of the samples the triangle can cover.
    const int32_t minx = std::min({v0.x, v1.x, v2.x}), maxx = std::max({v0.x, v1.x, v2.x});
    const int32_t miny = std::min({v0.y, v1.y, v2.y}), maxy = std::max({v0.y, v1.y, v2.y});
    int x0 = int((minx - kHalf + kSub - 1) >> kSubBits), x1 = int((maxx - kHalf) >> kSubBits);
    int y0 = int((miny - kHalf + kSub - 1) >> kSubBits), y1 = int((maxy - kHalf) >> kSubBits);
    x0 = std::max(x0, bx0);
    y0 = std::max(y0, by0);
    x1 = std::min(x1, bx1);
    y1 = std::min(y1, by1);
    if (x0 > x1 || y0 > y1) return false;
    // Edge e_k is opposite vertex k: e0 = v1→v2, e1 = v2→v0, e2 = v0→v1. Inside: E > 0, or E = 0 on a
    // top-left edge (counter-clockwise with y up: edges going down, or horizontal edges going left).
    const Vtx* pv[3] = {&v0, &v1, &v2};
    int64_t e_row[3], step_x[3], step_y[3];
    int bias[3];
    const int32_t sx = (x0 << kSubBits) + kHalf, sy = (y0 << kSubBits) + kHalf;
    for (int k = 0; k < 3; ++k) {
        const Vtx& a = *pv[(k + 1) % 3];
        const Vtx& b = *pv[(k + 2) % 3];
        const int64_t dx = int64_t(b.x) - a.x, dy = int64_t(b.y) - a.y;
        e_row[k] = dx * (int64_t(sy) - a.y) - dy * (int64_t(sx) - a.x);
        step_x[k] = -dy * kSub;
        step_y[k] = dx * kSub;
        bias[k] = (dy < 0 || (dy == 0 && dx < 0)) ? 0 : -1;
    }
    // Depth plane (interpolated quantity q) over the snapped positions, per pixel steps.
    const float inv_area = 1.0f / float(area);
    const float q_row0 = (float(e_row[0]) * v0.q + float(e_row[1]) * v1.q + float(e_row[2]) * v2.q) * inv_area;
    const float dq_x = (float(step_x[0]) * v0.q + float(step_x[1]) * v1.q + float(step_x[2]) * v2.q) * inv_area;
    const float dq_y = (float(step_y[0]) * v0.q + float(step_y[1]) * v1.q + float(step_y[2]) * v2.q) * inv_area;
    float q_row = q_row0;
    for (int y = y0; y <= y1; ++y) {
        int64_t e0 = e_row[0], e1 = e_row[1], e2 = e_row[2];
        float q = q_row;
        for (int x = x0; x <= x1; ++x) {
            if ((e0 + bias[0]) >= 0 && (e1 + bias[1]) >= 0 && (e2 + bias[2]) >= 0) {
                const int c = (e0 >= e1 && e0 >= e2) ? 0 : (e1 >= e2 ? 1 : 2);
                const float depth = kCentral ? 1.0f / q : q;
                if (frag(size_t(y) * size_t(r) + size_t(x), depth, corner_of[c])) return true;
            }
            e0 += step_x[0];
            e1 += step_x[1];
            e2 += step_x[2];
            q += dq_x;
        }
        e_row[0] += step_y[0];
        e_row[1] += step_y[1];
        e_row[2] += step_y[2];
        q_row += dq_y;
    }
    return false;
}

/// Window coordinate → 1/256 pixel, rounded half away from zero (inline; no libm call).
inline int32_t to_fx(float w) {
    float f = w * float(kSub);
    f = f < -kClampFx ? -kClampFx : f;  // selects, not branches: the projection loops vectorise
    f = f > kClampFx ? kClampFx : f;
    return int32_t(f + (f < 0.0f ? -0.5f : 0.5f));
}

}  // namespace

void CpuRasterBackend::Projected::resize(size_t n) {
    wx.resize(n);
    wy.resize(n);
    x.resize(n);
    y.resize(n);
    q.resize(n);
    code.resize(n);
}

CpuRasterBackend::CpuRasterBackend(size_t max_vertices) {
    membrane_px_.resize(max_vertices);
    instrument_px_.resize(max_vertices);
}

void CpuRasterBackend::project(const MeshRef& mesh, const ZcollView& view, Projected& out) {
    // Combined mesh → camera → window transform, then three simple loops the compiler vectorises.
    const Eigen::Matrix3f ct = view.camera_to_eye.transpose();
    const Eigen::Matrix3f m = ct * mesh.to_eye.linear();
    const Vec3f t = ct * (mesh.to_eye.translation() - view.origin_eye_mm);
    const float half_r = 0.5f * float(view.resolution_px);
    const size_t n = mesh.vertices_mm.size();
    if (out.x.size() < n) out.resize(n);
    const bool central = view.projection == Projection::Central;
    const float s = half_r / (central ? view.tan_half_angle : view.half_width_mm);
    const float m00 = m(0, 0) * s, m01 = m(0, 1) * s, m02 = m(0, 2) * s, t0 = t.x() * s;
    const float m10 = m(1, 0) * s, m11 = m(1, 1) * s, m12 = m(1, 2) * s, t1 = t.y() * s;
    const float m20 = m(2, 0), m21 = m(2, 1), m22 = m(2, 2), t2 = t.z();
    const float* v = mesh.vertices_mm.data()->data();
    float* __restrict wx = out.wx.data();
    float* __restrict wy = out.wy.data();
    float* __restrict q = out.q.data();
    for (size_t i = 0; i < n; ++i) {
        const float x = v[3 * i], y = v[3 * i + 1], z = v[3 * i + 2];
        wx[i] = m00 * x + m01 * y + m02 * z + t0;
        wy[i] = m10 * x + m11 * y + m12 * z + t1;
        q[i] = m20 * x + m21 * y + m22 * z + t2;
    }
    const float r = 2.0f * half_r, zn = view.near_mm, zf = view.far_mm;
    int32_t* __restrict fx = out.x.data();
    int32_t* __restrict fy = out.y.data();
    uint8_t* __restrict code = out.code.data();
    if (!central) {
        for (size_t i = 0; i < n; ++i) {
            const float px = wx[i] + half_r, py = wy[i] + half_r;
            fx[i] = to_fx(px);
            fy[i] = to_fx(py);
            const int c = (px < 0.0f ? 1 : 0) | (px > r ? 2 : 0) | (py < 0.0f ? 4 : 0) | (py > r ? 8 : 0) |
                          (q[i] < zn ? 16 : 0) | (q[i] > zf ? 32 : 0);
            code[i] = uint8_t(c);
        }
    } else {
        for (size_t i = 0; i < n; ++i) {
            const float z = q[i];
            const bool behind = z < zn;
            const float iz = behind ? 0.0f : 1.0f / z;
            const float px = wx[i] * iz + half_r, py = wy[i] * iz + half_r;
            fx[i] = to_fx(px);
            fy[i] = to_fx(py);
            q[i] = iz;
            code[i] = uint8_t((px < 0.0f) | ((px > r) << 1) | ((py < 0.0f) << 2) | ((py > r) << 3) |
                              ((z > zf) << 5) | (behind << 6));
        }
    }
}

void CpuRasterBackend::instrument_codes(const ZcollView& view) {
    const int32_t bx0 = mem_x0_ << kSubBits, bx1 = (mem_x1_ + 1) << kSubBits;
    const int32_t by0 = mem_y0_ << kSubBits, by1 = (mem_y1_ + 1) << kSubBits;
    const bool central = view.projection == Projection::Central;
    // Parallel views also reject triangles behind the deepest membrane sample or in front of the camera.
    const float zmax = central ? -1.0f : mem_zmax_, znear = central ? -1.0f : view.near_mm;
    const size_t n = instrument_px_.code.size();
    const int32_t* fx = instrument_px_.x.data();
    const int32_t* fy = instrument_px_.y.data();
    const float* q = instrument_px_.q.data();
    uint8_t* code = instrument_px_.code.data();
    for (size_t i = 0; i < n; ++i) {
        const uint8_t behind = code[i] & 64;
        code[i] = uint8_t((fx[i] < bx0) | ((fx[i] > bx1) << 1) | ((fy[i] < by0) << 2) | ((fy[i] > by1) << 3) |
                          (central ? 0 : ((q[i] >= zmax) << 4) | ((q[i] < znear) << 5)) | behind);
    }
}

void CpuRasterBackend::raster_membrane(const MeshRef& membrane, const ZcollView& view, const RasterRequest& req,
                                       RasterBuffers& out) {
    const int r = view.resolution_px;
    if (out.resolution_px != r) out.resize(r);
    // Only the previous query's membrane rectangle can hold anything: clear just that.
    for (int y = out.y0; y <= out.y1; ++y) {
        const size_t row = size_t(y) * size_t(r);
        std::fill(out.zm_mm.begin() + long(row) + out.x0, out.zm_mm.begin() + long(row) + out.x1 + 1, kEmptyDepth);
        std::fill(out.zi_mm.begin() + long(row) + out.x0, out.zi_mm.begin() + long(row) + out.x1 + 1, kEmptyDepth);
        std::fill(out.cm.begin() + long(row) + out.x0, out.cm.begin() + long(row) + out.x1 + 1, 0u);
        std::fill(out.layers.begin() + long(row) + out.x0, out.layers.begin() + long(row) + out.x1 + 1, uint8_t{0});
    }
    out.multi_layer_pixels = 0;
    project(membrane, view, membrane_px_);
    const uint8_t* mc = membrane_px_.code.data();
    const int32_t* mx = membrane_px_.x.data();
    const int32_t* my = membrane_px_.y.data();
    const float* mq = membrane_px_.q.data();
    const bool central = view.projection == Projection::Central;
    const float znear = view.near_mm, zfar = view.far_mm;
    float* zm = out.zm_mm.data();
    uint32_t* cm = out.cm.data();
    uint8_t* layers = out.layers.data();
    const bool vertex_ids = req.ids == FeatureKind::Vertex;
    mem_x0_ = r;
    mem_y0_ = r;
    mem_x1_ = -1;
    mem_y1_ = -1;
    mem_zmax_ = -kEmptyDepth;
    for (size_t ti = 0; ti < membrane.triangles.size(); ++ti) {
        const auto& tr = membrane.triangles[ti];
        // Trivial reject: all three vertices outside the same side of V (or any behind a central camera).
        const uint8_t ca = mc[tr[0]], cb = mc[tr[1]], cc = mc[tr[2]];
        if ((ca & cb & cc) || ((ca | cb | cc) & 64)) continue;
        const uint32_t ids[3] = {tr[0], tr[1], tr[2]};
        const uint32_t tid = uint32_t(ti);
        auto frag = [&](size_t p, float z, int corner) {
            if (z < znear || z > zfar) return false;
            if (req.count_layers && layers[p] < 255 && ++layers[p] == 2) ++out.multi_layer_pixels;
            if (z < zm[p]) {
                zm[p] = z;
                cm[p] = (vertex_ids ? ids[corner] : tid) + 1u;
            }
            return false;
        };
        const Vtx va{mx[tr[0]], my[tr[0]], mq[tr[0]]}, vb{mx[tr[1]], my[tr[1]], mq[tr[1]]},
            vc{mx[tr[2]], my[tr[2]], mq[tr[2]]};
        // Conservative image bounds and deepest depth of the membrane (the instrument pass culls by them):
        // the triangle's clipped sample box and its deepest vertex inside V.
        const int bx0 = std::max(0, int((std::min({va.x, vb.x, vc.x}) - kHalf + kSub - 1) >> kSubBits));
        const int bx1 = std::min(r - 1, int((std::max({va.x, vb.x, vc.x}) - kHalf) >> kSubBits));
        const int by0 = std::max(0, int((std::min({va.y, vb.y, vc.y}) - kHalf + kSub - 1) >> kSubBits));
        const int by1 = std::min(r - 1, int((std::max({va.y, vb.y, vc.y}) - kHalf) >> kSubBits));
        if (bx0 > bx1 || by0 > by1) continue;
        mem_x0_ = std::min(mem_x0_, bx0);
        mem_x1_ = std::max(mem_x1_, bx1);
        mem_y0_ = std::min(mem_y0_, by0);
        mem_y1_ = std::max(mem_y1_, by1);
        if (!central) mem_zmax_ = std::max(mem_zmax_, std::min(zfar, std::max({va.q, vb.q, vc.q})));
        if (central) raster_triangle<true>(va, vb, vc, r, 0, 0, r - 1, r - 1, frag);
        else raster_triangle<false>(va, vb, vc, r, 0, 0, r - 1, r - 1, frag);
    }
    out.x0 = mem_x0_;
    out.y0 = mem_y0_;
    out.x1 = mem_x1_;
    out.y1 = mem_y1_;
}

void CpuRasterBackend::render(const MeshRef& membrane, const MeshRef* instrument, const ZcollView& view,
                              const RasterRequest& req, RasterBuffers& out) {
    raster_membrane(membrane, view, req, out);
    const int r0 = view.resolution_px;
    for (int y = out.y0; y <= out.y1; ++y) {
        const size_t row = size_t(y) * size_t(r0);
        std::copy(out.zm_mm.begin() + long(row) + out.x0, out.zm_mm.begin() + long(row) + out.x1 + 1,
                  out.zi_mm.begin() + long(row) + out.x0);
    }
    if (!req.instrument || instrument == nullptr || mem_x1_ < 0) return;
    project(*instrument, view, instrument_px_);
    instrument_codes(view);
    const int r = view.resolution_px;
    const float znear = view.near_mm;
    float* zi = out.zi_mm.data();
    const bool central = view.projection == Projection::Central;
    const uint8_t* ic = instrument_px_.code.data();
    const int32_t* ix = instrument_px_.x.data();
    const int32_t* iy = instrument_px_.y.data();
    const float* iq = instrument_px_.q.data();
    for (const auto& tr : instrument->triangles) {
        const uint8_t ca = ic[tr[0]], cb = ic[tr[1]], cc = ic[tr[2]];
        if ((ca & cb & cc) || ((ca | cb | cc) & 64)) continue;
        auto frag = [&](size_t p, float z, int) {
            if (z >= znear && z <= zi[p]) zi[p] = z;  // LEQUAL against the membrane depth
            return false;
        };
        const Vtx va{ix[tr[0]], iy[tr[0]], iq[tr[0]]}, vb{ix[tr[1]], iy[tr[1]], iq[tr[1]]},
            vc{ix[tr[2]], iy[tr[2]], iq[tr[2]]};
        if (central) raster_triangle<true>(va, vb, vc, r, mem_x0_, mem_y0_, mem_x1_, mem_y1_, frag);
        else raster_triangle<false>(va, vb, vc, r, mem_x0_, mem_y0_, mem_x1_, mem_y1_, frag);
    }
}

bool CpuRasterBackend::any_penetration(const MeshRef& membrane, const MeshRef& instrument, const ZcollView& view) {
    RasterRequest req;
    req.instrument = false;
    raster_membrane(membrane, view, req, scratch_);
    if (mem_x1_ < 0) return false;
    project(instrument, view, instrument_px_);
    instrument_codes(view);
    const int r = view.resolution_px;
    const float znear = view.near_mm;
    const float* zm = scratch_.zm_mm.data();
    const uint32_t* cm = scratch_.cm.data();
    const bool central = view.projection == Projection::Central;
    const uint8_t* ic = instrument_px_.code.data();
    const int32_t* ix = instrument_px_.x.data();
    const int32_t* iy = instrument_px_.y.data();
    const float* iq = instrument_px_.q.data();
    for (const auto& tr : instrument.triangles) {
        const uint8_t ca = ic[tr[0]], cb = ic[tr[1]], cc = ic[tr[2]];
        if ((ca & cb & cc) || ((ca | cb | cc) & 64)) continue;
        // Early out on the first instrument sample in front of a membrane sample.
        auto frag = [&](size_t p, float z, int) { return cm[p] != 0 && z >= znear && z < zm[p]; };
        const Vtx va{ix[tr[0]], iy[tr[0]], iq[tr[0]]}, vb{ix[tr[1]], iy[tr[1]], iq[tr[1]]},
            vc{ix[tr[2]], iy[tr[2]], iq[tr[2]]};
        const bool hit = central ? raster_triangle<true>(va, vb, vc, r, mem_x0_, mem_y0_, mem_x1_, mem_y1_, frag)
                                 : raster_triangle<false>(va, vb, vc, r, mem_x0_, mem_y0_, mem_x1_, mem_y1_, frag);
        if (hit) return true;
    }
    return false;
}

}  // namespace eyesim::sim::collision
