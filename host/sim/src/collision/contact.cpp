#include "eyesim/sim/collision/contact.hpp"

#include "eyesim/sim/collision/tri_tri.hpp"
#include "eyesim/sim/collision/zcoll.hpp"

#include <Eigen/Geometry>
#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace eyesim::sim::collision {

namespace {

/// Margin of the float filters (mm). Coordinates in the instrument frame stay below ~20 mm for anything that
/// can touch an instrument (its bounds), so a transformed coordinate or a plane distance computed in float is
/// off by well under 1e-5 mm; pairs within the margin go to the double-precision predicates.
constexpr float kEps_mm = 2e-5f;
constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr int kMaxCells = 192;  // per axis of the instrument grid
constexpr int kMaxBins = 32;   // per axis of the deformation bins
constexpr double kBinsPerRootWork = 0.5;  // deformation bins per √(sample points × candidate front triangles)
constexpr uint32_t kNoHint = 0xFFFFFFFFu;

inline float min3(float a, float b, float c) { return std::min(std::min(a, b), c); }
inline float max3(float a, float b, float c) { return std::max(std::max(a, b), c); }

/// Advances a stamp counter; on wrap-around clears the stamped arrays.
template <typename... Vs>
uint32_t bump(uint32_t& counter, Vs&... arrays) {
    if (++counter == 0) {
        (std::fill(arrays.begin(), arrays.end(), 0u), ...);
        counter = 1;
    }
    return counter;
}

/// Triangle–triangle test for the common, well-separated-from-degenerate case: Möller's interval overlap on
/// the planes' intersection line, in double. Returns 1 (intersect), 0 (disjoint) or −1 when a vertex lies within
/// 1e-7 mm of the other plane, the planes are nearly parallel or the intervals nearly touch (the caller then
/// uses `triangles_intersect`'s predicates). Inputs are floats, so the differences are exact in double and the
/// rounding of the products is ~1e-15 relative: far inside these margins.
int interval_test(const Vec3f& a0, const Vec3f& a1, const Vec3f& a2, const Vec3f& b0, const Vec3f& b1, const Vec3f& b2) {
    using D3 = Eigen::Vector3d;
    const D3 A[3] = {a0.cast<double>(), a1.cast<double>(), a2.cast<double>()};
    const D3 B[3] = {b0.cast<double>(), b1.cast<double>(), b2.cast<double>()};
    const D3 na = (A[1] - A[0]).cross(A[2] - A[0]), nb = (B[1] - B[0]).cross(B[2] - B[0]);
    // Squared lengths and squared margins throughout: no square root on this path (it runs once per colliding
    // triangle at least).
    const double la2 = na.squaredNorm(), lb2 = nb.squaredNorm();
    if (la2 == 0.0 || lb2 == 0.0) return -1;
    double da[3], db[3];
    for (int i = 0; i < 3; ++i) {
        da[i] = nb.dot(A[i] - B[0]);  // A's vertices against B's plane (× |nb|)
        db[i] = na.dot(B[i] - A[0]);
    }
    constexpr double kTolDist2 = 1e-7 * 1e-7, kTolLine2 = 1e-6 * 1e-6;  // (mm)²
    const double near_b = kTolDist2 * lb2, near_a = kTolDist2 * la2;
    for (int i = 0; i < 3; ++i)
        if (da[i] * da[i] < near_b || db[i] * db[i] < near_a) return -1;
    if ((da[0] > 0) == (da[1] > 0) && (da[1] > 0) == (da[2] > 0)) return 0;
    if ((db[0] > 0) == (db[1] > 0) && (db[1] > 0) == (db[2] > 0)) return 0;
    const D3 dir = na.cross(nb);
    const double ld2 = dir.squaredNorm();
    if (ld2 < 1e-12 * la2 * lb2) return -1;  // nearly parallel planes
    // Interval of a triangle on the line: the vertex alone on its side, and the edges to it.
    auto interval = [&](const D3* v, const double* d, double& lo, double& hi) {
        const int k = ((d[0] > 0) == (d[1] > 0)) ? 2 : (((d[0] > 0) == (d[2] > 0)) ? 1 : 0);
        const int i = (k + 1) % 3, j = (k + 2) % 3;
        const double pk = dir.dot(v[k]), pi = dir.dot(v[i]), pj = dir.dot(v[j]);
        const double t1 = pi + (pk - pi) * d[i] / (d[i] - d[k]);
        const double t2 = pj + (pk - pj) * d[j] / (d[j] - d[k]);
        lo = std::min(t1, t2);
        hi = std::max(t1, t2);
    };
    double alo, ahi, blo, bhi;
    interval(A, da, alo, ahi);
    interval(B, db, blo, bhi);
    const double gap = std::max(alo, blo) - std::min(ahi, bhi);
    if (gap * gap <= kTolLine2 * ld2) return -1;  // the intervals nearly touch
    return gap < 0 ? 1 : 0;
}

}  // namespace

ExactContact::ExactContact(const TriangleMesh& membrane, size_t max_instrument_triangles) {
    set_membrane(membrane);
    const size_t ni = max_instrument_triangles;
    inst_vertices_.reserve(ni);
    inst_triangles_.reserve(ni);
    tris_.reserve(ni);
    tri_part_.reserve(ni);
    inst_stamp_.reserve(ni);
    for (auto* v : {&tcx_, &tcy_, &tcz_, &trad_, &tnx_, &tny_, &tnz_}) v->reserve(ni);
    kept_.reserve(ni);
    bin_begin_.reserve(kMaxBins * kMaxBins + 1);
    bin_fill_.reserve(kMaxBins * kMaxBins);
}

void ExactContact::set_membrane(const TriangleMesh& membrane) {
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
    lx_.resize(nv);
    ly_.resize(nv);
    lz_.resize(nv);
    code_.resize(nv);
    tri_stamp_.assign(nt, 0);
    tri_state_.assign(nt, 0);
    hint_.assign(nt, kNoHint);
    vert_stamp_.assign(nv, 0);
    vscan_stamp_.assign(nv, 0);
    vert_inside_.assign(nv, 0);
    vin_stamp_.assign(nv, 0);
    vin_.assign(nv, 0);
    vpoint_.assign(nv, 0);
    vdepth_stamp_.assign(nv, 0);
    node_sum_.assign(nv, Vec3f::Zero());
    node_max_.assign(nv, 0.0f);
    node_stamp_.assign(nv, 0);
    out_.reserve(nt);
    queue_.reserve(nt);
    merged_.reserve(nt);
    contacts_.reserve(nt);
    nodes_.reserve(nv);
    grabbed_.reserve(nv);
    push_.reserve(nv);
    query_ = 0;
}

void ExactContact::reset_result() {
    result_ = ContactResult{};
    out_.clear();
    queue_.clear();
    contacts_.clear();
    nodes_.clear();
    grabbed_.clear();
    push_.clear();
    bump(query_, tri_stamp_, vert_stamp_, vscan_stamp_, vdepth_stamp_, node_stamp_, vin_stamp_);
}

ExactContact::InstrumentChange ExactContact::instrument_change(const MeshRef& ins,
                                                               std::span<const uint32_t> parts) const {
    if (!built_ || ins.vertices_mm.size() != inst_vertices_.size() ||
        ins.triangles.size() != inst_triangles_.size())
        return InstrumentChange::Topology;
    const size_t np = parts.size() > 1 ? parts.size() : 2;
    if (np != parts_.size()) return InstrumentChange::Topology;
    if (parts.size() > 1 && !std::equal(parts.begin(), parts.end(), parts_.begin())) return InstrumentChange::Topology;
    if (std::memcmp(ins.triangles.data(), inst_triangles_.data(), ins.triangles.size_bytes()) != 0)
        return InstrumentChange::Topology;
    // The articulation (forceps opening) moves vertices: compare them all (≈12 kB, about a microsecond).
    return std::memcmp(ins.vertices_mm.data(), inst_vertices_.data(), ins.vertices_mm.size_bytes()) != 0
               ? InstrumentChange::Vertices
               : InstrumentChange::None;
}

void ExactContact::set_triangle(size_t t) {
    // Plain float arithmetic: this runs for every triangle of a part that moved (≈ 900 per forceps opening).
    const auto& tr = inst_triangles_[t];
    InstTri& T = tris_[t];
    T.a = inst_vertices_[tr[0]];
    T.b = inst_vertices_[tr[1]];
    T.c = inst_vertices_[tr[2]];
    const float ax = T.a.x(), ay = T.a.y(), az = T.a.z(), bx = T.b.x(), by = T.b.y(), bz = T.b.z(), cx = T.c.x(),
                cy = T.c.y(), cz = T.c.z();
    const float e1x = bx - ax, e1y = by - ay, e1z = bz - az, e2x = cx - ax, e2y = cy - ay, e2z = cz - az;
    const float nx = e1y * e2z - e1z * e2y, ny = e1z * e2x - e1x * e2z, nz = e1x * e2y - e1y * e2x;
    const float len = std::sqrt(nx * nx + ny * ny + nz * nz);
    T.n = len > 0.0f ? Vec3f(nx / len, ny / len, nz / len) : Vec3f::Zero();  // degenerate: never rejected
    T.d = T.n.x() * ax + T.n.y() * ay + T.n.z() * az;
    T.lo = Vec3f(min3(ax, bx, cx), min3(ay, by, cy), min3(az, bz, cz));
    T.hi = Vec3f(max3(ax, bx, cx), max3(ay, by, cy), max3(az, bz, cz));
    const float mx = (ax + bx + cx) / 3.0f, my = (ay + by + cy) / 3.0f, mz = (az + bz + cz) / 3.0f;
    auto d2 = [&](float x, float y, float z) { return (x - mx) * (x - mx) + (y - my) * (y - my) + (z - mz) * (z - mz); };
    tcx_[t] = mx;
    tcy_[t] = my;
    tcz_[t] = mz;
    // One square root: it is monotonic and correctly rounded, so this is the largest of the three distances.
    trad_[t] = std::sqrt(std::max(std::max(d2(ax, ay, az), d2(bx, by, bz)), d2(cx, cy, cz))) * (1.0f + 1e-5f) + kEps_mm;
    tnx_[t] = T.n.x();
    tny_[t] = T.n.y();
    tnz_[t] = T.n.z();
}

void ExactContact::set_triangles(uint32_t t0, uint32_t t1) {
    // Runs for every triangle of a part that moved (≈ 900 per forceps opening): four at a time with SSE2, the same
    // single-precision operations in the same order as set_triangle (so the same values), the rest one by one.
    uint32_t t = t0;
#if defined(__SSE2__)
    const __m128 zero = _mm_setzero_ps(), third = _mm_set1_ps(3.0f), grow = _mm_set1_ps(1.0f + 1e-5f),
                 eps = _mm_set1_ps(kEps_mm);
    // std::min(a, b) is (b < a ? b : a), which is MINPS with the operands swapped; likewise for max.
    auto mn3 = [](__m128 a, __m128 b, __m128 c) { return _mm_min_ps(c, _mm_min_ps(b, a)); };
    auto mx3 = [](__m128 a, __m128 b, __m128 c) { return _mm_max_ps(c, _mm_max_ps(b, a)); };
    for (; t + 4 <= t1; t += 4) {
        const Vec3f* v[4][3];
        for (int l = 0; l < 4; ++l)
            for (int k = 0; k < 3; ++k) v[l][k] = &inst_vertices_[inst_triangles_[t + uint32_t(l)][size_t(k)]];
        auto lanes = [&](int corner, int axis) {
            return _mm_setr_ps((*v[0][corner])[axis], (*v[1][corner])[axis], (*v[2][corner])[axis],
                               (*v[3][corner])[axis]);
        };
        const __m128 ax = lanes(0, 0), ay = lanes(0, 1), az = lanes(0, 2), bx = lanes(1, 0), by = lanes(1, 1),
                     bz = lanes(1, 2), cx = lanes(2, 0), cy = lanes(2, 1), cz = lanes(2, 2);
        const __m128 e1x = _mm_sub_ps(bx, ax), e1y = _mm_sub_ps(by, ay), e1z = _mm_sub_ps(bz, az);
        const __m128 e2x = _mm_sub_ps(cx, ax), e2y = _mm_sub_ps(cy, ay), e2z = _mm_sub_ps(cz, az);
        const __m128 nx = _mm_sub_ps(_mm_mul_ps(e1y, e2z), _mm_mul_ps(e1z, e2y));
        const __m128 ny = _mm_sub_ps(_mm_mul_ps(e1z, e2x), _mm_mul_ps(e1x, e2z));
        const __m128 nz = _mm_sub_ps(_mm_mul_ps(e1x, e2y), _mm_mul_ps(e1y, e2x));
        const __m128 len =
            _mm_sqrt_ps(_mm_add_ps(_mm_add_ps(_mm_mul_ps(nx, nx), _mm_mul_ps(ny, ny)), _mm_mul_ps(nz, nz)));
        const __m128 ok = _mm_cmpgt_ps(len, zero);  // degenerate: a zero normal, never rejected
        const __m128 ux = _mm_and_ps(ok, _mm_div_ps(nx, len)), uy = _mm_and_ps(ok, _mm_div_ps(ny, len)),
                     uz = _mm_and_ps(ok, _mm_div_ps(nz, len));
        const __m128 d = _mm_add_ps(_mm_add_ps(_mm_mul_ps(ux, ax), _mm_mul_ps(uy, ay)), _mm_mul_ps(uz, az));
        const __m128 mx = _mm_div_ps(_mm_add_ps(_mm_add_ps(ax, bx), cx), third),
                     my = _mm_div_ps(_mm_add_ps(_mm_add_ps(ay, by), cy), third),
                     mz = _mm_div_ps(_mm_add_ps(_mm_add_ps(az, bz), cz), third);
        auto d2 = [&](__m128 x, __m128 y, __m128 z) {
            const __m128 dx = _mm_sub_ps(x, mx), dy = _mm_sub_ps(y, my), dz = _mm_sub_ps(z, mz);
            return _mm_add_ps(_mm_add_ps(_mm_mul_ps(dx, dx), _mm_mul_ps(dy, dy)), _mm_mul_ps(dz, dz));
        };
        const __m128 r = _mm_add_ps(
            _mm_mul_ps(_mm_sqrt_ps(_mm_max_ps(d2(cx, cy, cz), _mm_max_ps(d2(bx, by, bz), d2(ax, ay, az)))), grow), eps);
        _mm_storeu_ps(&tcx_[t], mx);
        _mm_storeu_ps(&tcy_[t], my);
        _mm_storeu_ps(&tcz_[t], mz);
        _mm_storeu_ps(&trad_[t], r);
        _mm_storeu_ps(&tnx_[t], ux);
        _mm_storeu_ps(&tny_[t], uy);
        _mm_storeu_ps(&tnz_[t], uz);
        // InstTri's first ten floats (lo, hi, n, d) per lane: three 4 × 4 transposes of the field rows.
        static_assert(offsetof(InstTri, d) == 36 && offsetof(InstTri, a) == 40 && sizeof(InstTri) == 76);
        __m128 r0 = mn3(ax, bx, cx), r1 = mn3(ay, by, cy), r2 = mn3(az, bz, cz), r3 = mx3(ax, bx, cx);
        __m128 r4 = mx3(ay, by, cy), r5 = mx3(az, bz, cz), r6 = ux, r7 = uy;
        __m128 r8 = uz, r9 = d, r10 = zero, r11 = zero;
        _MM_TRANSPOSE4_PS(r0, r1, r2, r3);
        _MM_TRANSPOSE4_PS(r4, r5, r6, r7);
        _MM_TRANSPOSE4_PS(r8, r9, r10, r11);
        auto put = [&](int l, __m128 head, __m128 mid, __m128 tail) __attribute__((always_inline)) {
            alignas(16) float rec[12];
            _mm_store_ps(rec, head);
            _mm_store_ps(rec + 4, mid);
            _mm_store_ps(rec + 8, tail);
            InstTri& T = tris_[t + uint32_t(l)];
            std::memcpy(static_cast<void*>(&T), rec, 10 * sizeof(float));
            T.a = *v[l][0];
            T.b = *v[l][1];
            T.c = *v[l][2];
        };
        put(0, r0, r4, r8);
        put(1, r1, r5, r9);
        put(2, r2, r6, r10);
        put(3, r3, r7, r11);
    }
#endif
    for (; t < t1; ++t) set_triangle(t);
}

void ExactContact::update_bounds(bool changed_only) {
    lo_ = Vec3f::Constant(kInf);
    hi_ = Vec3f::Constant(-kInf);
    for (size_t p = 0; p < grids_.size(); ++p) {
        if (!changed_only || grids_[p].changed) {
            // The bounds of the part's triangles are those of their corners: its vertex list.
            float lo[3] = {kInf, kInf, kInf}, hi[3] = {-kInf, -kInf, -kInf};
            for (uint32_t v : grids_[p].vertices) {
                const float* q = inst_vertices_[v].data();
                for (int k = 0; k < 3; ++k) {
                    lo[k] = std::min(lo[k], q[k]);
                    hi[k] = std::max(hi[k], q[k]);
                }
            }
            part_lo_[p] = Vec3f(lo[0], lo[1], lo[2]);
            part_hi_[p] = Vec3f(hi[0], hi[1], hi[2]);
            float* pb = &part_box_[p * 8];
            for (int k = 0; k < 3; ++k) {
                pb[k] = lo[k];
                pb[4 + k] = hi[k];
            }
            pb[3] = pb[7] = 0.0f;
        }
        lo_ = lo_.cwiseMin(part_lo_[p]);
        hi_ = hi_.cwiseMax(part_hi_[p]);
    }
}

void ExactContact::build_grid(PartGrid& g) {
    // The grid's frame is the instrument frame as the part is now.
    for (size_t i = 0; i < g.vertices.size(); ++i) g.built_mm[i] = inst_vertices_[g.vertices[i]];
    g.moved = false;
    g.rot.setIdentity();
    g.trans.setZero();
    g.slack_mm = 0.0f;
    Vec3f lo = Vec3f::Constant(kInf), hi = Vec3f::Constant(-kInf);
    for (uint32_t t = g.t0; t < g.t1; ++t) {
        lo = lo.cwiseMin(tris_[t].lo);
        hi = hi.cwiseMax(tris_[t].hi);
    }
    const uint32_t nt = g.t1 - g.t0;
    if (nt == 0) lo = hi = Vec3f::Zero();
    // Cells about the size of the part's triangles (0.75 × the cube root of bounds volume per triangle: the
    // fewest instructions per dense query of 0.5, 0.75, 1 and 1.5; a walk reads a row's cells as one run).
    const Vec3f ext = (hi - lo).cwiseMax(Vec3f::Constant(1e-4f));
    const float cell = std::max(ext.maxCoeff() / float(kMaxCells),
                                std::cbrt(ext.prod() / float(std::max<uint32_t>(nt, 1))) * 0.75f);
    for (int k = 0; k < 3; ++k) g.dims[k] = std::clamp(int(std::ceil(ext[k] / cell)), 1, kMaxCells);
    g.lo = lo;
    g.inv_cell = Vec3f(float(g.dims[0]) / ext.x(), float(g.dims[1]) / ext.y(), float(g.dims[2]) / ext.z());
    const size_t ncell = size_t(g.dims[0]) * size_t(g.dims[1]) * size_t(g.dims[2]);
    g.cell_begin.assign(ncell + 1, 0);
    auto for_cells = [&](const Vec3f& a, const Vec3f& b, auto&& fn) {
        const int x0 = g.cell(a.x(), 0), x1 = g.cell(b.x(), 0), y0 = g.cell(a.y(), 1), y1 = g.cell(b.y(), 1),
                  z0 = g.cell(a.z(), 2), z1 = g.cell(b.z(), 2);
        for (int z = z0; z <= z1; ++z)
            for (int y = y0; y <= y1; ++y)
                for (int x = x0; x <= x1; ++x) fn(g.index(x, y, z));
    };
    const Vec3f m = Vec3f::Constant(kEps_mm);
    for (uint32_t t = g.t0; t < g.t1; ++t)
        for_cells(tris_[t].lo - m, tris_[t].hi + m, [&](size_t c) { ++g.cell_begin[c + 1]; });
    for (size_t c = 0; c < ncell; ++c) g.cell_begin[c + 1] += g.cell_begin[c];
    g.cell_items.resize(g.cell_begin[ncell]);
    g.cell_box.resize(size_t(g.cell_begin[ncell]) * 6 + 2);  // + 2: the walk reads the last bounds four floats wide
    cell_fill_.assign(g.cell_begin.begin(), g.cell_begin.end() - 1);
    for (uint32_t t = g.t0; t < g.t1; ++t)
        for_cells(tris_[t].lo - m, tris_[t].hi + m, [&](size_t c) {
            const uint32_t k = cell_fill_[c]++;
            g.cell_items[k] = t;
            float* box = &g.cell_box[size_t(k) * 6];
            for (int i = 0; i < 3; ++i) {
                box[i] = tris_[t].lo[i];
                box[3 + i] = tris_[t].hi[i];
            }
        });
}

void ExactContact::build_instrument(const MeshRef& ins, std::span<const uint32_t> parts) {
    inst_vertices_.assign(ins.vertices_mm.begin(), ins.vertices_mm.end());
    inst_triangles_.assign(ins.triangles.begin(), ins.triangles.end());
    const size_t nt = inst_triangles_.size(), nv = inst_vertices_.size();
    if (parts.size() > 1) parts_.assign(parts.begin(), parts.end());
    else parts_.assign({0u, uint32_t(nt)});
    tris_.resize(nt);
    for (auto* v : {&tcx_, &tcy_, &tcz_, &trad_, &tnx_, &tny_, &tnz_}) v->resize(nt);
    kept_.reserve(nt);
    set_triangles(0, uint32_t(nt));
    const size_t np = parts_.size() - 1;
    part_lo_.resize(np);
    part_hi_.resize(np);
    part_box_.resize(np * 8);
    tri_part_.resize(nt);
    grids_.resize(np);
    std::vector<uint32_t> mark(nv, 0);  // topology change: allocates anyway
    for (size_t p = 0; p < np; ++p) {
        PartGrid& g = grids_[p];
        g.t0 = std::min<uint32_t>(parts_[p], uint32_t(nt));
        g.t1 = std::clamp<uint32_t>(parts_[p + 1], g.t0, uint32_t(nt));
        g.vertices.clear();
        for (uint32_t t = g.t0; t < g.t1; ++t) {
            tri_part_[t] = uint32_t(p);
            for (uint32_t v : inst_triangles_[t])
                if (v < nv && mark[v] != p + 1) {
                    mark[v] = uint32_t(p + 1);
                    g.vertices.push_back(v);
                }
        }
        std::sort(g.vertices.begin(), g.vertices.end());
        g.built_mm.resize(g.vertices.size());
        build_grid(g);
    }
    update_bounds(false);
    inst_stamp_.assign(nt, 0);
    inst_query_ = 0;
    std::fill(hint_.begin(), hint_.end(), kNoHint);  // they name triangles of the previous structure
    last_hit_ = kNoHint;
    built_ = true;
}

void ExactContact::move_instrument(const MeshRef& ins) {
    // Which parts moved (against the vertices of the last query), before the copy is overwritten.
    for (PartGrid& g : grids_) {
        g.changed = false;
        for (uint32_t v : g.vertices)
            if (std::memcmp(&ins.vertices_mm[v], &inst_vertices_[v], sizeof(Vec3f)) != 0) {
                g.changed = true;
                break;
            }
    }
    std::copy(ins.vertices_mm.begin(), ins.vertices_mm.end(), inst_vertices_.begin());
    for (PartGrid& g : grids_) {
        if (!g.changed) continue;
        set_triangles(g.t0, g.t1);
        // The rigid motion from the grid's frame to the part now (Kabsch, in double): a forceps jaw turning about
        // its hinge fits to rounding. Anything else that moves a vertex by more than a tenth of a cell from that
        // motion rebuilds the part's grid.
        const size_t n = g.vertices.size();
        Eigen::Vector3d cb = Eigen::Vector3d::Zero(), cn = Eigen::Vector3d::Zero();
        for (size_t i = 0; i < n; ++i) {
            cb += g.built_mm[i].cast<double>();
            cn += inst_vertices_[g.vertices[i]].cast<double>();
        }
        cb /= double(std::max<size_t>(n, 1));
        cn /= double(std::max<size_t>(n, 1));
        Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
        for (size_t i = 0; i < n; ++i)
            h += (g.built_mm[i].cast<double>() - cb) * (inst_vertices_[g.vertices[i]].cast<double>() - cn).transpose();
        const Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
        Eigen::Matrix3d fix = Eigen::Matrix3d::Identity();
        fix(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1.0 : 1.0;
        const Eigen::Matrix3d r = svd.matrixV() * fix * svd.matrixU().transpose();  // built → now
        double slack = 0;
        for (size_t i = 0; i < n; ++i) {
            const Eigen::Vector3d now = inst_vertices_[g.vertices[i]].cast<double>();
            slack = std::max(slack, (r * (g.built_mm[i].cast<double>() - cb) + cn - now).norm());
        }
        const float cell = 1.0f / g.inv_cell.maxCoeff();
        if (!(slack <= 0.1 * double(cell))) {  // also NaN
            build_grid(g);
            result_.rebuilt = true;
            continue;
        }
        // Now → built: x_b = rᵀ (x − cn) + cb. The walk maps membrane corners with it in float; the slack covers
        // the fit residual, and the rounding of that map is added per corner (mapped_box).
        g.rot = r.transpose().cast<float>();
        g.trans = (cb - r.transpose() * cn).cast<float>();
        g.slack_mm = float(slack * (1.0 + 1e-6)) + 1e-9f;  // rounded up
        g.moved = true;
        ++result_.refit_parts;
    }
    update_bounds(true);
}

bool ExactContact::intersects_any(uint32_t mt) {
    const auto& tr = triangles_[mt];
    const Vec3f a = local(tr[0]), b = local(tr[1]), c = local(tr[2]);
    // Plain float arithmetic in this loop: GCC at -O2 does not inline Eigen's small reductions.
    const float ax = a.x(), ay = a.y(), az = a.z(), bx = b.x(), by = b.y(), bz = b.z(), cx = c.x(), cy = c.y(),
                cz = c.z();
    const float lox = min3(ax, bx, cx) - kEps_mm, loy = min3(ay, by, cy) - kEps_mm,
                loz = min3(az, bz, cz) - kEps_mm;
    const float hix = max3(ax, bx, cx) + kEps_mm, hiy = max3(ay, by, cy) + kEps_mm,
                hiz = max3(az, bz, cz) + kEps_mm;
    const uint32_t q = bump(inst_query_, inst_stamp_);
    // The membrane triangle's normal (unnormalised) and edge planes, computed when a pair first gets there.
    bool plane = false;
    float nmx = 0, nmy = 0, nmz = 0;
#if defined(__SSE2__)
    __m128 emx = _mm_setzero_ps(), emy = _mm_setzero_ps(), emz = _mm_setzero_ps(), emlim = _mm_setzero_ps();
#endif
    // The pair test after the bounds test (the grid walk reads the bounds from the cell's own copy).
    auto pair_after_bounds = [&](const InstTri& T) __attribute__((always_inline)) {
        if (!plane) {
            plane = true;
            const float e1x = bx - ax, e1y = by - ay, e1z = bz - az, e2x = cx - ax, e2y = cy - ay, e2z = cz - az;
            nmx = e1y * e2z - e1z * e2y;
            nmy = e1z * e2x - e1x * e2z;
            nmz = e1x * e2y - e1y * e2x;
#if defined(__SSE2__)
            // The edge planes (through an edge, ⊥ the triangle), inward normals m_k = n × e_k, one lane each
            // (the fourth lane is zero and never rejects).
            const __m128 ox = _mm_setr_ps(ax, bx, cx, 0.0f), oy = _mm_setr_ps(ay, by, cy, 0.0f),
                         oz = _mm_setr_ps(az, bz, cz, 0.0f);
            const __m128 ex = _mm_sub_ps(_mm_setr_ps(bx, cx, ax, 0.0f), ox),
                         ey = _mm_sub_ps(_mm_setr_ps(by, cy, ay, 0.0f), oy),
                         ez = _mm_sub_ps(_mm_setr_ps(bz, cz, az, 0.0f), oz);
            const __m128 nx4 = _mm_set1_ps(nmx), ny4 = _mm_set1_ps(nmy), nz4 = _mm_set1_ps(nmz);
            emx = _mm_sub_ps(_mm_mul_ps(ny4, ez), _mm_mul_ps(nz4, ey));
            emy = _mm_sub_ps(_mm_mul_ps(nz4, ex), _mm_mul_ps(nx4, ez));
            emz = _mm_sub_ps(_mm_mul_ps(nx4, ey), _mm_mul_ps(ny4, ex));
            const __m128 len = _mm_sqrt_ps(
                _mm_add_ps(_mm_add_ps(_mm_mul_ps(emx, emx), _mm_mul_ps(emy, emy)), _mm_mul_ps(emz, emz)));
            emlim = _mm_sub_ps(
                _mm_add_ps(_mm_add_ps(_mm_mul_ps(emx, ox), _mm_mul_ps(emy, oy)), _mm_mul_ps(emz, oz)),
                _mm_mul_ps(_mm_set1_ps(kEps_mm), len));
            // A sliver's float normal may point anywhere: no edge filter unless the corner angle at a has
            // sin ≥ 1e-3 (then the normal's direction is good to ≈ 1e-4).
            if (nmx * nmx + nmy * nmy + nmz * nmz <
                1e-6f * (e1x * e1x + e1y * e1y + e1z * e1z) * (e2x * e2x + e2y * e2y + e2z * e2z))
                emlim = _mm_set1_ps(-kInf);
#endif
        }
        // Plane filter (float, conservative margin): the membrane triangle strictly on one side of the instrument
        // triangle's plane → disjoint. (The converse, the instrument triangle against the membrane's plane, ended
        // 2 % of the pairs that reach here, dense scene: not worth its instructions.)
        const float nx = T.n.x(), ny = T.n.y(), nz = T.n.z();
        const float da = nx * ax + ny * ay + nz * az - T.d, db = nx * bx + ny * by + nz * bz - T.d,
                    dc = nx * cx + ny * cy + nz * cz - T.d;
        if (((da > kEps_mm) & (db > kEps_mm) & (dc > kEps_mm)) | ((da < -kEps_mm) & (db < -kEps_mm) & (dc < -kEps_mm)))
            return false;
#if defined(__SSE2__)
        // Edge-plane filter: the instrument triangle wholly outside one of the membrane triangle's edge planes (by
        // the margin) misses it. Most pairs that reach here straddle both planes but cross the membrane's plane
        // beside the triangle; this ends ≈ 40 % of them before the double-precision test (dense scene). The lambdas
        // are forced inline: out of line, their captured state is read through memory and the filter costs more
        // than it saves.
        auto outside = [&](const Vec3f& p) {
            return _mm_cmplt_ps(_mm_add_ps(_mm_add_ps(_mm_mul_ps(emx, _mm_set1_ps(p.x())), _mm_mul_ps(emy, _mm_set1_ps(p.y()))),
                                           _mm_mul_ps(emz, _mm_set1_ps(p.z()))),
                                emlim);
        };
        if (_mm_movemask_ps(_mm_and_ps(_mm_and_ps(outside(T.a), outside(T.b)), outside(T.c)))) return false;
#endif
        ++result_.pair_tests;
        const int fast = interval_test(a, b, c, T.a, T.b, T.c);
        return fast == 1 || (fast < 0 && triangles_intersect(a, b, c, T.a, T.b, T.c));
    };
#if defined(__SSE2__)
    const __m128 tlo = _mm_setr_ps(lox, loy, loz, 0.0f), thi = _mm_setr_ps(hix, hiy, hiz, 0.0f);
#endif
    auto pair_hits = [&](const InstTri& T) __attribute__((always_inline)) {
#if defined(__SSE2__)
        // T.lo and T.hi are adjacent (InstTri starts with them): four-wide loads, the fourth lane ignored.
        static_assert(sizeof(Vec3f) == 12 && offsetof(InstTri, hi) == 12 && offsetof(InstTri, n) == 24);
        if (_mm_movemask_ps(_mm_or_ps(_mm_cmplt_ps(thi, _mm_loadu_ps(T.lo.data())),
                                      _mm_cmpgt_ps(tlo, _mm_loadu_ps(T.hi.data())))) &
            7)
            return false;
#else
        if ((hix < T.lo.x()) | (hiy < T.lo.y()) | (hiz < T.lo.z()) | (lox > T.hi.x()) | (loy > T.hi.y()) |
            (loz > T.hi.z()))
            return false;
#endif
        return pair_after_bounds(T);
    };
    // Coherence: first the instrument triangle that hit this membrane triangle in the previous query (small
    // motion between frames), then the one that hit the previous membrane triangle (neighbours in the mesh).
    // Any intersecting pair decides, so this only saves the grid walk.
    const uint32_t nit = uint32_t(tris_.size());
    if (hint_[mt] < nit && pair_hits(tris_[hint_[mt]])) {
        last_hit_ = hint_[mt];
        return true;
    }
    if (last_hit_ < nit && last_hit_ != hint_[mt] && pair_hits(tris_[last_hit_])) {
        hint_[mt] = last_hit_;
        return true;
    }
    const size_t np = grids_.size();
    for (size_t p = 0; p < np; ++p) {
#if defined(__SSE2__)
        // The part's bounds (lanes x, y, z, 0 = 0): any lane apart → skip.
        const float* pb = &part_box_[p * 8];
        if (_mm_movemask_ps(_mm_or_ps(_mm_cmplt_ps(thi, _mm_loadu_ps(pb)), _mm_cmpgt_ps(tlo, _mm_loadu_ps(pb + 4)))))
            continue;
#else
        if ((hix < part_lo_[p].x()) | (hiy < part_lo_[p].y()) | (hiz < part_lo_[p].z()) | (lox > part_hi_[p].x()) |
            (loy > part_hi_[p].y()) | (loz > part_hi_[p].z()))
            continue;
#endif
        const PartGrid& g = grids_[p];
        // The walk's box in the grid's frame: the triangle's own, or its corners mapped there (a moved part).
        float wlo[3] = {lox, loy, loz}, whi[3] = {hix, hiy, hiz};
        if (g.moved) {
            const Vec3f corners[3] = {a, b, c};
            g.mapped_box(corners, 3, kEps_mm, wlo, whi);
        }
        const int x0 = g.cell(wlo[0], 0), x1 = g.cell(whi[0], 0), y0 = g.cell(wlo[1], 1), y1 = g.cell(whi[1], 1),
                  z0 = g.cell(wlo[2], 2), z1 = g.cell(whi[2], 2);
#if defined(__SSE2__)
        const __m128 vwlo = _mm_setr_ps(wlo[0], wlo[1], wlo[2], 0.0f), vwhi = _mm_setr_ps(whi[0], whi[1], whi[2], 0.0f);
#endif
        // The cells x0..x1 of a grid row are adjacent in the item list: one run of items per row.
        for (int z = z0; z <= z1; ++z)
            for (int y = y0; y <= y1; ++y) {
                const size_t row = g.index(0, y, z);
                const uint32_t end = g.cell_begin[row + size_t(x1) + 1];
                for (uint32_t k = g.cell_begin[row + size_t(x0)]; k < end; ++k) {
                    const float* box = &g.cell_box[size_t(k) * 6];
#if defined(__SSE2__)
                    // lo xyz from box[0..2], hi xyz from box[3..5] (the list is padded so box + 3 reads four floats).
                    if (_mm_movemask_ps(_mm_or_ps(_mm_cmplt_ps(vwhi, _mm_loadu_ps(box)),
                                                  _mm_cmpgt_ps(vwlo, _mm_loadu_ps(box + 3)))) &
                        7)
                        continue;
#else
                    // One branch, not six (the outcome is hard to predict).
                    if ((whi[0] < box[0]) | (whi[1] < box[1]) | (whi[2] < box[2]) | (wlo[0] > box[3]) |
                        (wlo[1] > box[4]) | (wlo[2] > box[5]))
                        continue;
#endif
                    const uint32_t it = g.cell_items[k];
                    if (inst_stamp_[it] == q) continue;
                    inst_stamp_[it] = q;
                    if (pair_after_bounds(tris_[it])) {
                        hint_[mt] = last_hit_ = it;
                        return true;
                    }
                }
            }
    }
    return false;
}

bool ExactContact::inside_any_part(const Vec3f& p) {
    ++result_.inside_tests;
    // Ray parity along an almost axis-aligned direction (+x with a tiny skew against hits on the edges of
    // regular meshes): in a part's grid frame the ray stays within one or two grid rows (a moved part: within
    // the box of the mapped segment). Per part: parts may overlap.
    const double sy = 1.37e-4, sz = 0.71e-4;
    const Eigen::Vector3d dir(1.0, sy, sz);
    const Eigen::Vector3d o = p.cast<double>();
    for (size_t part = 0; part < grids_.size(); ++part) {
        if ((p.array() < part_lo_[part].array()).any() || (p.array() > part_hi_[part].array()).any()) continue;
        const PartGrid& g = grids_[part];
        const float run = part_hi_[part].x() - p.x();
        const Vec3f end(part_hi_[part].x(), p.y() + float(sy) * run, p.z() + float(sz) * run);
        float wlo[3] = {p.x(), p.y(), p.z()}, whi[3] = {end.x(), end.y(), end.z()};
        if (g.moved) {
            const Vec3f seg[2] = {p, end};
            g.mapped_box(seg, 2, kEps_mm, wlo, whi);
        }
        const int x0 = g.cell(wlo[0], 0), x1 = g.cell(whi[0], 0);
        const int y0 = g.cell(wlo[1], 1), y1 = g.cell(whi[1], 1);
        const int z0 = g.cell(wlo[2], 2), z1 = g.cell(whi[2], 2);
        const uint32_t q = bump(inst_query_, inst_stamp_);
        int crossings = 0;
        for (int z = z0; z <= z1; ++z)
            for (int y = y0; y <= y1; ++y) {
                const size_t row = g.index(0, y, z);
                const uint32_t stop = g.cell_begin[row + size_t(x1) + 1];
                for (uint32_t k = g.cell_begin[row + size_t(x0)]; k < stop; ++k) {
                    const uint32_t it = g.cell_items[k];
                    if (inst_stamp_[it] == q) continue;
                    inst_stamp_[it] = q;
                    const InstTri& T = tris_[it];
                    if (T.hi.x() < p.x()) continue;
                    crossings += ray_crosses_triangle(o, dir, T.a, T.b, T.c);
                }
            }
        if (crossings & 1) return true;
    }
    return false;
}

void ExactContact::compute_deformation(std::span<const Vec3f> verts_eye, const Eigen::Isometry3f& to_eye,
                                       const Vec3f& pi_eye) {
    // π and a basis of the plane ⊥ π, in the instrument frame.
    ps_ = (to_eye.linear().transpose() * pi_eye).normalized();
    const Vec3f hint = std::fabs(ps_.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY();
    pu_ = ps_.cross(hint).normalized();
    pw_ = ps_.cross(pu_);
    const float ux = pu_.x(), uy = pu_.y(), uz = pu_.z(), wx = pw_.x(), wy = pw_.y(), wz = pw_.z();
    const float sx = ps_.x(), sy = ps_.y(), sz = ps_.z();
    // Sample points: the colliding triangles' corners (once per vertex) and centroids, on u, w and π. The region
    // ⊥ π they cover and their deepest point along π (the corners' bounds hold the centroids).
    const size_t nout = out_.size();
    for (auto* a : {&pt_u_, &pt_w_, &pt_s_}) a->resize(4 * nout);  // at most three corners and a centroid each
    float* __restrict pu = pt_u_.data();
    float* __restrict pw = pt_w_.data();
    float* __restrict pz = pt_s_.data();
    uint32_t np = 0;
    auto add_point = [&](const Vec3f& p) {
        pu[np] = ux * p.x() + uy * p.y() + uz * p.z();
        pw[np] = wx * p.x() + wy * p.y() + wz * p.z();
        pz[np] = sx * p.x() + sy * p.y() + sz * p.z();
        return np++;
    };
    float u_lo = kInf, u_hi = -kInf, w_lo = kInf, w_hi = -kInf, s_hi = -kInf;
    for (uint32_t t : out_)
        for (uint32_t v : triangles_[t]) {
            if (vdepth_stamp_[v] == query_) continue;
            vdepth_stamp_[v] = query_;
            const uint32_t k = vpoint_[v] = add_point(local(v));
            u_lo = std::min(u_lo, pu[k]);
            u_hi = std::max(u_hi, pu[k]);
            w_lo = std::min(w_lo, pw[k]);
            w_hi = std::max(w_hi, pw[k]);
            s_hi = std::max(s_hi, pz[k]);
        }
    const uint32_t centroids = np;  // the centroid of out_[i] is point centroids + i
    for (uint32_t t : out_) {
        const auto& tr = triangles_[t];
        add_point((local(tr[0]) + local(tr[1]) + local(tr[2])) / 3.0f);
    }
    // Cull by bounding spheres: only triangles facing the camera (−π; the first surface a line along π meets on
    // a closed part with outward normals faces it) over the region and reaching in front of the deepest sample.
    const uint32_t nit = uint32_t(tris_.size());
    kept_.clear();
    {
        const float* __restrict cx = tcx_.data();
        const float* __restrict cy = tcy_.data();
        const float* __restrict cz = tcz_.data();
        const float* __restrict rad = trad_.data();
        const float* __restrict nx = tnx_.data();
        const float* __restrict ny = tny_.data();
        const float* __restrict nz = tnz_.data();
        uint32_t t = 0;
#if defined(__SSE2__)
        // Four triangles per step; the kept ones are listed straight from the lane mask.
        const __m128 vux = _mm_set1_ps(ux), vuy = _mm_set1_ps(uy), vuz = _mm_set1_ps(uz);
        const __m128 vwx = _mm_set1_ps(wx), vwy = _mm_set1_ps(wy), vwz = _mm_set1_ps(wz);
        const __m128 vsx = _mm_set1_ps(sx), vsy = _mm_set1_ps(sy), vsz = _mm_set1_ps(sz);
        const __m128 vulo = _mm_set1_ps(u_lo), vuhi = _mm_set1_ps(u_hi), vwlo = _mm_set1_ps(w_lo),
                     vwhi = _mm_set1_ps(w_hi), vshi = _mm_set1_ps(s_hi), zero = _mm_setzero_ps();
        for (; t + 4 <= nit; t += 4) {
            const __m128 X = _mm_loadu_ps(cx + t), Y = _mm_loadu_ps(cy + t), Z = _mm_loadu_ps(cz + t);
            const __m128 r = _mm_loadu_ps(rad + t);
            const __m128 facing =
                _mm_add_ps(_mm_add_ps(_mm_mul_ps(vsx, _mm_loadu_ps(nx + t)), _mm_mul_ps(vsy, _mm_loadu_ps(ny + t))),
                           _mm_mul_ps(vsz, _mm_loadu_ps(nz + t)));
            __m128 keep = _mm_cmplt_ps(facing, zero);
            const __m128 u = _mm_add_ps(_mm_add_ps(_mm_mul_ps(vux, X), _mm_mul_ps(vuy, Y)), _mm_mul_ps(vuz, Z));
            keep = _mm_and_ps(keep,
                              _mm_and_ps(_mm_cmpge_ps(_mm_add_ps(u, r), vulo), _mm_cmple_ps(_mm_sub_ps(u, r), vuhi)));
            const __m128 w = _mm_add_ps(_mm_add_ps(_mm_mul_ps(vwx, X), _mm_mul_ps(vwy, Y)), _mm_mul_ps(vwz, Z));
            keep = _mm_and_ps(keep,
                              _mm_and_ps(_mm_cmpge_ps(_mm_add_ps(w, r), vwlo), _mm_cmple_ps(_mm_sub_ps(w, r), vwhi)));
            const __m128 s = _mm_add_ps(_mm_add_ps(_mm_mul_ps(vsx, X), _mm_mul_ps(vsy, Y)), _mm_mul_ps(vsz, Z));
            keep = _mm_and_ps(keep, _mm_cmple_ps(_mm_sub_ps(s, r), vshi));
            for (int m = _mm_movemask_ps(keep); m; m &= m - 1)
                kept_.push_back(t + uint32_t(__builtin_ctz(unsigned(m))));
        }
#endif
        for (; t < nit; ++t) {
            const float u = ux * cx[t] + uy * cy[t] + uz * cz[t], w = wx * cx[t] + wy * cy[t] + wz * cz[t];
            const float s = sx * cx[t] + sy * cy[t] + sz * cz[t], r = rad[t];
            const float facing = sx * nx[t] + sy * ny[t] + sz * nz[t];
            if ((facing < 0.0f) & (u + r >= u_lo) & (u - r <= u_hi) & (w + r >= w_lo) & (w - r <= w_hi) &
                (s - r <= s_hi))
                kept_.push_back(t);
        }
    }
    // ZI at each sample point: the smallest depth along π of the front triangles over it. The points are binned
    // over (u, w) and each front triangle visits the bins its bounds cover, four points at a time. Cost: per
    // (triangle, bin) pair plus per point slot visited, so the bin count that balances them grows as
    // √(points × candidate front triangles): coarse for a few points, finer for a dense contact. The constant is
    // the fewest instructions on the benchmark scenes.
    const int bins =
        std::clamp(int(std::sqrt(kBinsPerRootWork * std::sqrt(double(np) * double(kept_.size())))), 1, kMaxBins);
    const float eu = std::max(u_hi - u_lo, 1e-6f), ew = std::max(w_hi - w_lo, 1e-6f);
    const float binv_u = float(bins) / eu * (1.0f - 1e-6f), binv_w = float(bins) / ew * (1.0f - 1e-6f);
    const float top = float(bins - 1);
    const size_t nb = size_t(bins) * size_t(bins);
    constexpr uint32_t kNoBin = 0xFFFFFFFFu;
    bin_begin_.assign(nb + 1, 0);
    pt_bin_.resize(np);
    for (uint32_t k = 0; k < np; ++k) {
        const int bu = int((pu[k] - u_lo) * binv_u), bw = int((pw[k] - w_lo) * binv_w);
        if (bu < 0 || bw < 0 || bu >= bins || bw >= bins) {
            pt_bin_[k] = kNoBin;  // no instrument surface looked up (the region holds every corner and centroid)
            continue;
        }
        pt_bin_[k] = uint32_t(bw) * uint32_t(bins) + uint32_t(bu);
        ++bin_begin_[pt_bin_[k] + 1];
    }
    // Each bin padded to a multiple of four slots (padding: u NaN, never inside a triangle).
    for (size_t b = 0; b < nb; ++b) bin_begin_[b + 1] = bin_begin_[b] + ((bin_begin_[b + 1] + 3u) & ~3u);
    const uint32_t slots = bin_begin_[nb];
    sl_u_.assign(slots, std::numeric_limits<float>::quiet_NaN());
    sl_w_.assign(slots, 0.0f);
    sl_best_.assign(slots, kInf);
    sl_point_.resize(np);
    bin_fill_.assign(bin_begin_.begin(), bin_begin_.end() - 1);
    for (uint32_t k = 0; k < np; ++k) {
        if (pt_bin_[k] == kNoBin) continue;
        const uint32_t slot = bin_fill_[pt_bin_[k]]++;
        sl_u_[slot] = pu[k];
        sl_w_[slot] = pw[k];
        sl_point_[k] = slot;
    }
    constexpr float kTol = -1e-6f;  // closed triangles: a line through a shared edge meets both
    float* __restrict best = sl_best_.data();
    const float* __restrict su = sl_u_.data();
    const float* __restrict sw = sl_w_.data();
    // One front triangle: corner a at (u0, w0) with depth s0, (u, w) → barycentric (l1, l2) by [a11 a12; a21 a22],
    // depth s0 + l1 ds1 + l2 ds2, over bins x0..x1 × y0..y1.
    auto sweep = [&](float u0, float w0, float a11, float a12, float a21, float a22, float s0, float ds1, float ds2,
                     int x0, int x1, int y0, int y1) __attribute__((always_inline)) {
#if defined(__SSE2__)
        const __m128 vu0 = _mm_set1_ps(u0), vw0 = _mm_set1_ps(w0), va11 = _mm_set1_ps(a11),
                     va12 = _mm_set1_ps(a12), va21 = _mm_set1_ps(a21), va22 = _mm_set1_ps(a22),
                     vs0 = _mm_set1_ps(s0), vds1 = _mm_set1_ps(ds1), vds2 = _mm_set1_ps(ds2);
        const __m128 tol = _mm_set1_ps(kTol), one = _mm_set1_ps(1.0f), inf = _mm_set1_ps(kInf);
#endif
        for (int y = y0; y <= y1; ++y) {
            // The bins x0..x1 of a row are adjacent slots: one run.
            const size_t row = size_t(y) * size_t(bins);
            const uint32_t end = bin_begin_[row + size_t(x1) + 1];
            uint32_t k = bin_begin_[row + size_t(x0)];
#if defined(__SSE2__)
            // The same single-precision operations as the scalar loop below (so the same values).
            for (; k < end; k += 4) {
                const __m128 du = _mm_sub_ps(_mm_loadu_ps(su + k), vu0), dw = _mm_sub_ps(_mm_loadu_ps(sw + k), vw0);
                const __m128 l1 = _mm_add_ps(_mm_mul_ps(va11, du), _mm_mul_ps(va12, dw));
                const __m128 l2 = _mm_add_ps(_mm_mul_ps(va21, du), _mm_mul_ps(va22, dw));
                const __m128 l3 = _mm_sub_ps(_mm_sub_ps(one, l1), l2);
                const __m128 in =
                    _mm_and_ps(_mm_and_ps(_mm_cmpge_ps(l1, tol), _mm_cmpge_ps(l2, tol)), _mm_cmpge_ps(l3, tol));
                const __m128 sv = _mm_add_ps(_mm_add_ps(vs0, _mm_mul_ps(l1, vds1)), _mm_mul_ps(l2, vds2));
                _mm_storeu_ps(best + k, _mm_min_ps(_mm_loadu_ps(best + k),
                                                   _mm_or_ps(_mm_and_ps(in, sv), _mm_andnot_ps(in, inf))));
            }
#endif
            for (; k < end; ++k) {
                const float du = su[k] - u0, dw = sw[k] - w0;
                const float l1 = a11 * du + a12 * dw, l2 = a21 * du + a22 * dw;
                if (l1 < kTol || l2 < kTol || 1.0f - l1 - l2 < kTol) continue;
                best[k] = std::min(best[k], s0 + l1 * ds1 + l2 * ds2);
            }
        }
    };
    // A bin coordinate clamped in float (then truncated): the same bin as truncating first, without overflow (NaN
    // gives bin 0).
    auto bin_at = [&](float v, float origin, float inv) {
        const float x = (v - origin) * inv;
        return int(x > 0.0f ? std::min(x, top) : 0.0f);
    };
    // The kept triangles' corners on u, w and π, their exact bounds test (the sphere test above is coarser), the
    // (u, w) → barycentric map, then the sweep.
    size_t first = 0, front = 0;  // kept triangles before `first` went through the SIMD path
#if defined(__SSE2__)
    {
        // Four kept triangles per step (the same single-precision operations as the scalar loop below, so the
        // same values).
        const __m128 vux = _mm_set1_ps(ux), vuy = _mm_set1_ps(uy), vuz = _mm_set1_ps(uz);
        const __m128 vwx = _mm_set1_ps(wx), vwy = _mm_set1_ps(wy), vwz = _mm_set1_ps(wz);
        const __m128 vsx = _mm_set1_ps(sx), vsy = _mm_set1_ps(sy), vsz = _mm_set1_ps(sz);
        const __m128 vulo = _mm_set1_ps(u_lo), vuhi = _mm_set1_ps(u_hi), vwlo = _mm_set1_ps(w_lo),
                     vwhi = _mm_set1_ps(w_hi), vshi = _mm_set1_ps(s_hi);
        const __m128 vbinu = _mm_set1_ps(binv_u), vbinw = _mm_set1_ps(binv_w), vtop = _mm_set1_ps(top);
        const __m128 tiny = _mm_set1_ps(1e-12f), one = _mm_set1_ps(1.0f), sign = _mm_set1_ps(-0.0f),
                     zero = _mm_setzero_ps();
        // std::min(a, b) is (b < a ? b : a), which is MINPS with the operands swapped; likewise for max.
        auto mn3 = [](__m128 a, __m128 b, __m128 c) { return _mm_min_ps(c, _mm_min_ps(b, a)); };
        auto mx3 = [](__m128 a, __m128 b, __m128 c) { return _mm_max_ps(c, _mm_max_ps(b, a)); };
        auto dot = [](__m128 x, __m128 y, __m128 z, __m128 X, __m128 Y, __m128 Z) {
            return _mm_add_ps(_mm_add_ps(_mm_mul_ps(x, X), _mm_mul_ps(y, Y)), _mm_mul_ps(z, Z));
        };
        auto bin4 = [&](__m128 v, __m128 origin, __m128 inv) {
            return _mm_cvttps_epi32(_mm_min_ps(_mm_max_ps(_mm_mul_ps(_mm_sub_ps(v, origin), inv), zero), vtop));
        };
        const size_t nk = kept_.size();
        for (; first + 4 <= nk; first += 4) {
            const InstTri& T0 = tris_[kept_[first]];
            const InstTri& T1 = tris_[kept_[first + 1]];
            const InstTri& T2 = tris_[kept_[first + 2]];
            const InstTri& T3 = tris_[kept_[first + 3]];
            // Corner `corner` (0 a, 1 b, 2 c), coordinate `axis` of the four triangles.
            auto lanes = [&](int corner, int axis) {
                auto get = [&](const InstTri& T) { return (corner == 0 ? T.a : corner == 1 ? T.b : T.c)[axis]; };
                return _mm_setr_ps(get(T0), get(T1), get(T2), get(T3));
            };
            const __m128 a0 = lanes(0, 0), a1 = lanes(0, 1), a2 = lanes(0, 2);
            const __m128 b0 = lanes(1, 0), b1 = lanes(1, 1), b2 = lanes(1, 2);
            const __m128 c0 = lanes(2, 0), c1 = lanes(2, 1), c2 = lanes(2, 2);
            const __m128 u0 = dot(vux, vuy, vuz, a0, a1, a2), w0 = dot(vwx, vwy, vwz, a0, a1, a2);
            const __m128 u1 = dot(vux, vuy, vuz, b0, b1, b2), w1 = dot(vwx, vwy, vwz, b0, b1, b2);
            const __m128 u2 = dot(vux, vuy, vuz, c0, c1, c2), w2 = dot(vwx, vwy, vwz, c0, c1, c2);
            const __m128 s0 = dot(vsx, vsy, vsz, a0, a1, a2), s1 = dot(vsx, vsy, vsz, b0, b1, b2),
                         s2 = dot(vsx, vsy, vsz, c0, c1, c2);
            const __m128 ulo = mn3(u0, u1, u2), uhi = mx3(u0, u1, u2), wlo = mn3(w0, w1, w2), whi = mx3(w0, w1, w2);
            __m128 out = _mm_or_ps(_mm_or_ps(_mm_cmpgt_ps(mn3(s0, s1, s2), vshi), _mm_cmplt_ps(uhi, vulo)),
                                   _mm_or_ps(_mm_cmpgt_ps(ulo, vuhi), _mm_cmplt_ps(whi, vwlo)));
            out = _mm_or_ps(out, _mm_cmpgt_ps(wlo, vwhi));
            const __m128 m00 = _mm_sub_ps(u1, u0), m01 = _mm_sub_ps(u2, u0), m10 = _mm_sub_ps(w1, w0),
                         m11 = _mm_sub_ps(w2, w0);
            const __m128 det = _mm_sub_ps(_mm_mul_ps(m00, m11), _mm_mul_ps(m01, m10));
            out = _mm_or_ps(out, _mm_cmplt_ps(_mm_andnot_ps(sign, det), tiny));
            int keep = ~_mm_movemask_ps(out) & 0xF;
            if (!keep) continue;
            const __m128 inv = _mm_div_ps(one, det);
            alignas(16) float f[9][4];
            alignas(16) int box[4][4];
            _mm_store_ps(f[0], u0);
            _mm_store_ps(f[1], w0);
            _mm_store_ps(f[2], _mm_mul_ps(m11, inv));
            _mm_store_ps(f[3], _mm_mul_ps(_mm_xor_ps(m01, sign), inv));
            _mm_store_ps(f[4], _mm_mul_ps(_mm_xor_ps(m10, sign), inv));
            _mm_store_ps(f[5], _mm_mul_ps(m00, inv));
            _mm_store_ps(f[6], s0);
            _mm_store_ps(f[7], _mm_sub_ps(s1, s0));
            _mm_store_ps(f[8], _mm_sub_ps(s2, s0));
            _mm_store_si128(reinterpret_cast<__m128i*>(box[0]), bin4(ulo, vulo, vbinu));
            _mm_store_si128(reinterpret_cast<__m128i*>(box[1]), bin4(uhi, vulo, vbinu));
            _mm_store_si128(reinterpret_cast<__m128i*>(box[2]), bin4(wlo, vwlo, vbinw));
            _mm_store_si128(reinterpret_cast<__m128i*>(box[3]), bin4(whi, vwlo, vbinw));
            for (; keep; keep &= keep - 1) {
                const int l = __builtin_ctz(unsigned(keep));
                ++front;
                sweep(f[0][l], f[1][l], f[2][l], f[3][l], f[4][l], f[5][l], f[6][l], f[7][l], f[8][l], box[0][l],
                      box[1][l], box[2][l], box[3][l]);
            }
        }
    }
#endif
    for (size_t k = first; k < kept_.size(); ++k) {
        const InstTri& T = tris_[kept_[k]];
        const float a0 = T.a.x(), a1 = T.a.y(), a2 = T.a.z(), b0 = T.b.x(), b1 = T.b.y(), b2 = T.b.z();
        const float c0 = T.c.x(), c1 = T.c.y(), c2 = T.c.z();
        const float u0 = ux * a0 + uy * a1 + uz * a2, w0 = wx * a0 + wy * a1 + wz * a2;
        const float u1 = ux * b0 + uy * b1 + uz * b2, w1 = wx * b0 + wy * b1 + wz * b2;
        const float u2 = ux * c0 + uy * c1 + uz * c2, w2 = wx * c0 + wy * c1 + wz * c2;
        const float s0 = sx * a0 + sy * a1 + sz * a2, s1 = sx * b0 + sy * b1 + sz * b2, s2 = sx * c0 + sy * c1 + sz * c2;
        const float ulo = min3(u0, u1, u2), uhi = max3(u0, u1, u2), wlo = min3(w0, w1, w2), whi = max3(w0, w1, w2);
        if (min3(s0, s1, s2) > s_hi || uhi < u_lo || ulo > u_hi || whi < w_lo || wlo > w_hi) continue;
        const float m00 = u1 - u0, m01 = u2 - u0, m10 = w1 - w0, m11 = w2 - w0;
        const float det = m00 * m11 - m01 * m10;
        if (std::fabs(det) < 1e-12f) continue;  // seen edge-on: its neighbours cover the line
        const float inv = 1.0f / det;
        ++front;
        sweep(u0, w0, m11 * inv, -m01 * inv, -m10 * inv, m00 * inv, s0, s1 - s0, s2 - s0, bin_at(ulo, u_lo, binv_u),
              bin_at(uhi, u_lo, binv_u), bin_at(wlo, w_lo, binv_w), bin_at(whi, w_lo, binv_w));
    }
    result_.front_triangles = front;
    // ZI − ZM at a sample point (≤ 0): the front-most instrument surface on its line minus its own depth.
    auto delta = [&](uint32_t k) { return pt_bin_[k] == kNoBin ? 0.0f : std::min(0.0f, best[sl_point_[k]] - pz[k]); };
    for (size_t i = 0; i < nout; ++i) {
        const auto& tr = triangles_[out_[i]];
        TriangleContact c;
        c.triangle = out_[i];
        c.depth_delta_mm = 0.0f;
        c.point_eye_mm = (verts_eye[tr[0]] + verts_eye[tr[1]] + verts_eye[tr[2]]) / 3.0f;
        for (uint32_t v : tr) {
            const float d = delta(vpoint_[v]);
            if (d < c.depth_delta_mm) {
                c.depth_delta_mm = d;
                c.point_eye_mm = verts_eye[v];
            }
        }
        const float centre = delta(centroids + uint32_t(i));
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
    switch (instrument_change(instrument, part_triangle_begin)) {
        case InstrumentChange::Topology:
            build_instrument(instrument, part_triangle_begin);
            result_.rebuilt = true;
            break;
        case InstrumentChange::Vertices: move_instrument(instrument); break;
        case InstrumentChange::None: break;
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
    float* __restrict ox = lx_.data();
    float* __restrict oy = ly_.data();
    float* __restrict oz = lz_.data();
    uint8_t* __restrict code = code_.data();
    size_t i = 0;
#if defined(__SSE2__)
    {
        // Four vertices per step: three loads de-interleaved into x, y, z lanes; the same single-precision
        // operations in the same order as the scalar loop below.
        const __m128 R00 = _mm_set1_ps(r00), R01 = _mm_set1_ps(r01), R02 = _mm_set1_ps(r02);
        const __m128 R10 = _mm_set1_ps(r10), R11 = _mm_set1_ps(r11), R12 = _mm_set1_ps(r12);
        const __m128 R20 = _mm_set1_ps(r20), R21 = _mm_set1_ps(r21), R22 = _mm_set1_ps(r22);
        const __m128 T0 = _mm_set1_ps(t0), T1 = _mm_set1_ps(t1), T2 = _mm_set1_ps(t2);
        const __m128 LX = _mm_set1_ps(lx), LY = _mm_set1_ps(ly), LZ = _mm_set1_ps(lz);
        const __m128 HX = _mm_set1_ps(hx), HY = _mm_set1_ps(hy), HZ = _mm_set1_ps(hz);
        const __m128i b0 = _mm_set1_epi32(1), b1 = _mm_set1_epi32(2), b2 = _mm_set1_epi32(4), b3 = _mm_set1_epi32(8),
                      b4 = _mm_set1_epi32(16), b5 = _mm_set1_epi32(32);
        auto bit = [](__m128 mask, __m128i b) { return _mm_and_si128(_mm_castps_si128(mask), b); };
        for (; i + 4 <= nv; i += 4) {
            const __m128 v0 = _mm_loadu_ps(in + 3 * i), v1 = _mm_loadu_ps(in + 3 * i + 4),
                         v2 = _mm_loadu_ps(in + 3 * i + 8);
            const __m128 xy = _mm_shuffle_ps(v1, v2, _MM_SHUFFLE(2, 1, 3, 2));  // x2 y2 x3 y3
            const __m128 yz = _mm_shuffle_ps(v0, v1, _MM_SHUFFLE(1, 0, 2, 1));  // y0 z0 y1 z1
            const __m128 X = _mm_shuffle_ps(v0, xy, _MM_SHUFFLE(2, 0, 3, 0));
            const __m128 Y = _mm_shuffle_ps(yz, xy, _MM_SHUFFLE(3, 1, 2, 0));
            const __m128 Z = _mm_shuffle_ps(yz, v2, _MM_SHUFFLE(3, 0, 3, 1));
            auto row = [&](__m128 a, __m128 b, __m128 c, __m128 t) {
                return _mm_add_ps(_mm_add_ps(_mm_add_ps(_mm_mul_ps(a, X), _mm_mul_ps(b, Y)), _mm_mul_ps(c, Z)), t);
            };
            const __m128 px = row(R00, R01, R02, T0), py = row(R10, R11, R12, T1), pz = row(R20, R21, R22, T2);
            _mm_storeu_ps(ox + i, px);
            _mm_storeu_ps(oy + i, py);
            _mm_storeu_ps(oz + i, pz);
            const __m128i c = _mm_or_si128(
                _mm_or_si128(_mm_or_si128(bit(_mm_cmplt_ps(px, LX), b0), bit(_mm_cmpgt_ps(px, HX), b1)),
                             _mm_or_si128(bit(_mm_cmplt_ps(py, LY), b2), bit(_mm_cmpgt_ps(py, HY), b3))),
                _mm_or_si128(bit(_mm_cmplt_ps(pz, LZ), b4), bit(_mm_cmpgt_ps(pz, HZ), b5)));
            const __m128i c16 = _mm_packs_epi32(c, c);
            const int c8 = _mm_cvtsi128_si32(_mm_packus_epi16(c16, c16));
            std::memcpy(code + i, &c8, 4);
        }
    }
#endif
    for (; i < nv; ++i) {
        const float x = in[3 * i], y = in[3 * i + 1], z = in[3 * i + 2];
        const float px = r00 * x + r01 * y + r02 * z + t0;
        const float py = r10 * x + r11 * y + r12 * z + t1;
        const float pz = r20 * x + r21 * y + r22 * z + t2;
        ox[i] = px;
        oy[i] = py;
        oz[i] = pz;
        code[i] = uint8_t((px < lx) | ((px > hx) << 1) | ((py < ly) << 2) | ((py > hy) << 3) | ((pz < lz) << 4) |
                          ((pz > hz) << 5));
    }
    const uint32_t q = query_;
    const size_t nt = triangles_.size();
    // kOutside: reached the grid but lies outside options.within (as if culled). `within` is asked lazily, of the
    // hits and of the triangles the containment growth reaches, not of every triangle near the instrument.
    enum : uint8_t { kMiss = 0, kHit = 1, kInside = 2, kVisited = 3, kOutside = 4 };
    // box_overlaps_aabb(*options.within, triangle bounds), with the box's own terms computed once per query and
    // the same single-precision operations in the same order (Eigen sums a 3-term dot product as p0 + (p1 + p2)).
    const OrientedBox* vbox = options.within;
    float ar[3][3] = {}, rb[3] = {}, rc[3][3] = {}, he[3] = {}, bc[3] = {};
    if (vbox) {
        for (int row = 0; row < 3; ++row) {
            he[row] = vbox->half_extent_mm[row];
            bc[row] = vbox->centre_eye_mm[row];
            for (int col = 0; col < 3; ++col) {
                rc[row][col] = vbox->box_to_eye(row, col);
                ar[row][col] = std::fabs(rc[row][col]);
            }
        }
        for (int k = 0; k < 3; ++k) rb[k] = ar[k][0] * he[0] + (ar[k][1] * he[1] + ar[k][2] * he[2]);
    }
    // Quick accept: a corner inside the box by `inner` along each box axis puts the triangle's bounds and the box
    // `inner` deep into each other on every separating axis, far beyond the test's float rounding (≈ 1e-6 of the
    // coordinates' size), so the full test below would say the same. Asked once per vertex and query.
    const float inner =
        1e-5f * (1.0f + std::max({std::fabs(bc[0]), std::fabs(bc[1]), std::fabs(bc[2])}) + he[0] + he[1] + he[2]);
    auto deep_inside = [&](uint32_t v) {
        if (vin_stamp_[v] != query_) {
            vin_stamp_[v] = query_;
            const Vec3f& p = verts[v];
            const float d0 = p.x() - bc[0], d1 = p.y() - bc[1], d2 = p.z() - bc[2];
            bool deep = true;
            for (int k = 0; k < 3; ++k)
                deep &= std::fabs(rc[0][k] * d0 + rc[1][k] * d1 + rc[2][k] * d2) <= he[k] - inner;
            vin_[v] = deep;
        }
        return vin_[v] != 0;
    };
    auto within = [&](uint32_t t) {
        if (!vbox) return true;
        const auto& tri = triangles_[t];
        if (deep_inside(tri[0])) return true;
        const Vec3f &a = verts[tri[0]], &b = verts[tri[1]], &c = verts[tri[2]];
        float h[3], d[3];
        for (int k = 0; k < 3; ++k) {
            const float lo = std::min(std::min(a[k], b[k]), c[k]), hi = std::max(std::max(a[k], b[k]), c[k]);
            h[k] = 0.5f * (hi - lo);
            d[k] = bc[k] - 0.5f * (lo + hi);
            if (std::fabs(d[k]) > h[k] + rb[k]) return false;
        }
        for (int k = 0; k < 3; ++k) {
            const float ra = ar[0][k] * h[0] + (ar[1][k] * h[1] + ar[2][k] * h[2]);
            const float dk = rc[0][k] * d[0] + (rc[1][k] * d[1] + rc[2][k] * d[2]);
            if (std::fabs(dk) > ra + he[k]) return false;
        }
        return true;
    };
    for (size_t mt = 0; mt < nt; ++mt) {
        const auto& tri = triangles_[mt];
        if (code[tri[0]] & code[tri[1]] & code[tri[2]]) continue;
        ++result_.candidate_triangles;
        tri_stamp_[mt] = q;
        const bool hit = intersects_any(uint32_t(mt));
        if (hit && !within(uint32_t(mt))) {
            tri_state_[mt] = kOutside;
            continue;
        }
        tri_state_[mt] = hit ? kHit : kMiss;
        if (hit) out_.push_back(uint32_t(mt));
    }
    if (options.include_contained && !out_.empty()) {
        // A membrane triangle inside a part without touching its surface shares a vertex with a hit or another
        // such triangle: grow from the hits. A triangle that meets no instrument triangle is wholly inside or
        // wholly outside, and so are its vertices: one parity test classifies a whole run of neighbours.
        const size_t hits = out_.size();  // ascending
        queue_.assign(out_.begin(), out_.end());
        for (size_t qi = 0; qi < queue_.size(); ++qi) {
            for (uint32_t v : triangles_[queue_[qi]]) {
                // A vertex's triangles need one look: none of them can become undecided again.
                if (vscan_stamp_[v] == q) continue;
                vscan_stamp_[v] = q;
                for (uint32_t k = vt_begin_[v]; k < vt_begin_[v + 1]; ++k) {
                    const uint32_t t = vt_items_[k];
                    if (tri_stamp_[t] != q || tri_state_[t] != kMiss) continue;  // outside the bounds, or decided
                    if (!within(t)) {
                        tri_state_[t] = kOutside;
                        continue;
                    }
                    tri_state_[t] = kVisited;
                    const auto& tri = triangles_[t];
                    int known = -1;
                    for (uint32_t w : tri)
                        if (vert_stamp_[w] == q) known = vert_inside_[w];
                    if (known < 0) known = inside_any_part(local(tri[0])) ? 1 : 0;
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
        if (out_.size() > hits) {  // merge the contained ones into the ascending hits
            std::sort(out_.begin() + std::ptrdiff_t(hits), out_.end());
            merged_.resize(out_.size());
            const auto mid = out_.begin() + std::ptrdiff_t(hits);
            std::merge(out_.begin(), mid, mid, out_.end(), merged_.begin());
            out_.swap(merged_);
        }
    }
    result_.colliding_triangles = out_;
    result_.colliding = !out_.empty();
    if (options.deformation && !out_.empty()) compute_deformation(verts, instrument.to_eye, pi_eye);
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
    if (options.deformation && !out_.empty()) {
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
        eq1_node_pushes(nodes_, node_sum_, node_max_, push_);
        result_.pushed_nodes = nodes_;
        result_.node_push_eye_mm = push_;
    }
    return result_;
}

}  // namespace eyesim::sim::collision
