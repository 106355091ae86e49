#include "eyesim/sim/collision/exact.hpp"

#include "eyesim/sim/collision/tri_tri.hpp"

#include <algorithm>
#include <cmath>

namespace eyesim::sim::collision {

ExactNarrowPhase::ExactNarrowPhase(size_t membrane_triangles, size_t instrument_triangles) {
    inst_eye_.reserve(instrument_triangles * 3);
    tri_lo_.reserve(instrument_triangles);
    tri_hi_.reserve(instrument_triangles);
    stamp_.assign(instrument_triangles, 0);
    out_.reserve(membrane_triangles);
    cell_begin_.reserve(16 * 16 * 16 + 1);
    cell_items_.reserve(instrument_triangles * 8);
}

std::span<const uint32_t> ExactNarrowPhase::colliding_triangles(const MeshRef& membrane, const MeshRef& instrument,
                                                                std::span<const uint32_t> part_triangle_begin,
                                                                const ExactOptions& options) {
    out_.clear();
    pair_tests_ = 0;
    const size_t nit = instrument.triangles.size();
    // Instrument in the eye frame, per-triangle bounds, overall bounds.
    inst_eye_.resize(instrument.vertices_mm.size());
    for (size_t i = 0; i < inst_eye_.size(); ++i) inst_eye_[i] = instrument.to_eye * instrument.vertices_mm[i];
    tri_lo_.resize(nit);
    tri_hi_.resize(nit);
    Vec3f lo = Vec3f::Constant(1e30f), hi = Vec3f::Constant(-1e30f);
    for (size_t t = 0; t < nit; ++t) {
        const auto& tr = instrument.triangles[t];
        const Vec3f &a = inst_eye_[tr[0]], &b = inst_eye_[tr[1]], &c = inst_eye_[tr[2]];
        tri_lo_[t] = a.cwiseMin(b).cwiseMin(c);
        tri_hi_[t] = a.cwiseMax(b).cwiseMax(c);
        lo = lo.cwiseMin(tri_lo_[t]);
        hi = hi.cwiseMax(tri_hi_[t]);
    }
    if (nit == 0) return out_;
    // Grid over the instrument bounds (a few cells per axis; the instrument is long and thin).
    const Vec3f ext = (hi - lo).cwiseMax(Vec3f::Constant(1e-4f));
    const float cell = std::max(ext.maxCoeff() / 48.0f, std::cbrt(ext.prod() / float(nit)) * 1.5f);
    int dims[3];
    for (int k = 0; k < 3; ++k) dims[k] = std::clamp(int(std::ceil(ext[k] / cell)), 1, 48);
    const Vec3f inv_cell{float(dims[0]) / ext.x(), float(dims[1]) / ext.y(), float(dims[2]) / ext.z()};
    auto cell_of = [&](const Vec3f& p, int k) {
        return std::clamp(int((p[k] - lo[k]) * inv_cell[k]), 0, dims[k] - 1);
    };
    const size_t ncell = size_t(dims[0]) * size_t(dims[1]) * size_t(dims[2]);
    cell_begin_.assign(ncell + 1, 0);
    auto for_cells = [&](const Vec3f& a, const Vec3f& b, auto&& fn) {
        const int x0 = cell_of(a, 0), x1 = cell_of(b, 0), y0 = cell_of(a, 1), y1 = cell_of(b, 1), z0 = cell_of(a, 2),
                  z1 = cell_of(b, 2);
        for (int z = z0; z <= z1; ++z)
            for (int y = y0; y <= y1; ++y)
                for (int x = x0; x <= x1; ++x) fn(size_t(z) * size_t(dims[1]) * size_t(dims[0]) + size_t(y) * size_t(dims[0]) + size_t(x));
    };
    for (size_t t = 0; t < nit; ++t) for_cells(tri_lo_[t], tri_hi_[t], [&](size_t c) { ++cell_begin_[c + 1]; });
    for (size_t c = 0; c < ncell; ++c) cell_begin_[c + 1] += cell_begin_[c];
    cell_items_.resize(cell_begin_[ncell]);
    cell_fill_.assign(cell_begin_.begin(), cell_begin_.end() - 1);
    for (size_t t = 0; t < nit; ++t)
        for_cells(tri_lo_[t], tri_hi_[t], [&](size_t c) { cell_items_[cell_fill_[c]++] = uint32_t(t); });
    if (stamp_.size() < nit) stamp_.assign(nit, 0);

    // Per-part bounds for the containment test.
    const size_t nparts = part_triangle_begin.size() > 1 ? part_triangle_begin.size() - 1 : 0;
    part_lo_.resize(nparts);
    part_hi_.resize(nparts);
    for (size_t p = 0; p < nparts; ++p) {
        part_lo_[p] = Vec3f::Constant(1e30f);
        part_hi_[p] = Vec3f::Constant(-1e30f);
        for (uint32_t t = part_triangle_begin[p]; t < part_triangle_begin[p + 1]; ++t) {
            part_lo_[p] = part_lo_[p].cwiseMin(tri_lo_[t]);
            part_hi_[p] = part_hi_[p].cwiseMax(tri_hi_[t]);
        }
    }
    for (size_t mt = 0; mt < membrane.triangles.size(); ++mt) {
        const auto& tr = membrane.triangles[mt];
        const Vec3f &a = membrane.vertices_mm[tr[0]], &b = membrane.vertices_mm[tr[1]], &c = membrane.vertices_mm[tr[2]];
        const Vec3f mlo = a.cwiseMin(b).cwiseMin(c), mhi = a.cwiseMax(b).cwiseMax(c);
        if ((mhi.array() < lo.array()).any() || (mlo.array() > hi.array()).any()) continue;
        if (options.within && !box_overlaps_aabb(*options.within, mlo, mhi)) continue;
        ++query_;
        if (query_ == 0) {  // stamp wrap-around
            std::fill(stamp_.begin(), stamp_.end(), 0);
            query_ = 1;
        }
        bool hit = false;
        for_cells(mlo, mhi, [&](size_t cidx) {
            if (hit) return;
            for (uint32_t k = cell_begin_[cidx]; k < cell_begin_[cidx + 1] && !hit; ++k) {
                const uint32_t it = cell_items_[k];
                if (stamp_[it] == query_) continue;
                stamp_[it] = query_;
                if ((mhi.array() < tri_lo_[it].array()).any() || (mlo.array() > tri_hi_[it].array()).any()) continue;
                ++pair_tests_;
                const auto& q = instrument.triangles[it];
                hit = triangles_intersect(a, b, c, inst_eye_[q[0]], inst_eye_[q[1]], inst_eye_[q[2]]);
            }
        });
        if (!hit && options.include_contained) {
            for (size_t p = 0; p < nparts && !hit; ++p) {
                const uint32_t t0 = part_triangle_begin[p], t1 = part_triangle_begin[p + 1];
                if ((mlo.array() < part_lo_[p].array()).any() || (mhi.array() > part_hi_[p].array()).any()) continue;
                hit = point_inside_closed_mesh(a, inst_eye_, instrument.triangles.subspan(t0, t1 - t0));
            }
        }
        if (hit) out_.push_back(uint32_t(mt));
    }
    return out_;
}

}  // namespace eyesim::sim::collision
