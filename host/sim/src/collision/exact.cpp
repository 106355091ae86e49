#include "eyesim/sim/collision/exact.hpp"

#include "eyesim/sim/collision/tri_tri.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Geometry>

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
    int* dims = dims_;
    for (int k = 0; k < 3; ++k) dims[k] = std::clamp(int(std::ceil(ext[k] / cell)), 1, 48);
    const Vec3f inv_cell{float(dims[0]) / ext.x(), float(dims[1]) / ext.y(), float(dims[2]) / ext.z()};
    grid_lo_ = lo;
    grid_ext_ = ext;
    inv_cell_ = inv_cell;
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

    auto next_query = [&]() {
        if (++query_ == 0) {  // stamp wrap-around
            std::fill(stamp_.begin(), stamp_.end(), 0u);
            query_ = 1;
        }
    };
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
    const size_t nmt = membrane.triangles.size();
    if (mem_stamp_.size() < nmt) mem_stamp_.assign(nmt, 0);
    const uint32_t mem_query = ++mem_query_;
    const bool flood = options.include_contained && !options.vertex_triangle_begin.empty();
    for (size_t mt = 0; mt < nmt; ++mt) {
        if (!candidate(membrane, uint32_t(mt), lo, hi, options)) continue;
        const auto& tr = membrane.triangles[mt];
        const Vec3f &a = membrane.vertices_mm[tr[0]], &b = membrane.vertices_mm[tr[1]], &c = membrane.vertices_mm[tr[2]];
        const Vec3f mlo = a.cwiseMin(b).cwiseMin(c), mhi = a.cwiseMax(b).cwiseMax(c);
        next_query();
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
        if (!hit && options.include_contained && !flood) {
            for (size_t p = 0; p < nparts && !hit; ++p) {
                if ((mlo.array() < part_lo_[p].array()).any() || (mhi.array() > part_hi_[p].array()).any()) continue;
                hit = inside_part(a, instrument, part_triangle_begin[p], part_triangle_begin[p + 1]);
            }
        }
        if (hit) {
            out_.push_back(uint32_t(mt));
            mem_stamp_[mt] = mem_query;
        }
    }
    if (flood) {
        // A triangle inside the instrument that touches no instrument triangle shares vertices with a hit or
        // another contained triangle: grow from the hits, testing one vertex per reached triangle.
        queue_.assign(out_.begin(), out_.end());
        for (size_t qi = 0; qi < queue_.size(); ++qi) {
            for (uint32_t v : membrane.triangles[queue_[qi]]) {
                for (uint32_t k = options.vertex_triangle_begin[v]; k < options.vertex_triangle_begin[v + 1]; ++k) {
                    const uint32_t t = options.vertex_triangles[k];
                    if (mem_stamp_[t] == mem_query) continue;
                    mem_stamp_[t] = mem_query;
                    if (!candidate(membrane, t, lo, hi, options)) continue;
                    const auto& tr = membrane.triangles[t];
                    const Vec3f &a = membrane.vertices_mm[tr[0]], &b = membrane.vertices_mm[tr[1]],
                                &c = membrane.vertices_mm[tr[2]];
                    const Vec3f mlo = a.cwiseMin(b).cwiseMin(c), mhi = a.cwiseMax(b).cwiseMax(c);
                    bool inside = false;
                    for (size_t p = 0; p < nparts && !inside; ++p) {
                        if ((mlo.array() < part_lo_[p].array()).any() || (mhi.array() > part_hi_[p].array()).any())
                            continue;
                        inside = inside_part(a, instrument, part_triangle_begin[p], part_triangle_begin[p + 1]);
                    }
                    if (inside) {
                        out_.push_back(t);
                        queue_.push_back(t);
                    }
                }
            }
        }
        std::sort(out_.begin(), out_.end());
    }
    return out_;
}

bool ExactNarrowPhase::candidate(const MeshRef& membrane, uint32_t t, const Vec3f& lo, const Vec3f& hi,
                                 const ExactOptions& o) const {
    const auto& tr = membrane.triangles[t];
    const Vec3f &a = membrane.vertices_mm[tr[0]], &b = membrane.vertices_mm[tr[1]], &c = membrane.vertices_mm[tr[2]];
    const Vec3f mlo = a.cwiseMin(b).cwiseMin(c), mhi = a.cwiseMax(b).cwiseMax(c);
    if ((mhi.array() < lo.array()).any() || (mlo.array() > hi.array()).any()) return false;
    return o.within == nullptr || box_overlaps_aabb(*o.within, mlo, mhi);
}

bool ExactNarrowPhase::inside_part(const Vec3f& p, const MeshRef& instrument, uint32_t t0, uint32_t t1) {
    // Ray parity along an almost axis-aligned direction (+x with a tiny skew against hits on the edges of
    // regular meshes). The ray stays within one or two grid rows, so only those cells are visited.
    const double sy = 1.37e-4, sz = 0.71e-4;
    const Eigen::Vector3d dir(1.0, sy, sz);
    const Eigen::Vector3d o = p.cast<double>();
    auto cell = [&](float x, int k) { return std::clamp(int((x - grid_lo_[k]) * inv_cell_[k]), 0, dims_[k] - 1); };
    if ((p.array() < grid_lo_.array()).any() || (p.array() > (grid_lo_ + grid_ext_).array()).any()) return false;
    const float run = grid_lo_.x() + grid_ext_.x() - p.x();
    const int x0 = cell(p.x(), 0);
    const int y0 = cell(p.y(), 1), y1 = cell(p.y() + float(sy) * run, 1);
    const int z0 = cell(p.z(), 2), z1 = cell(p.z() + float(sz) * run, 2);
    if (++query_ == 0) {
        std::fill(stamp_.begin(), stamp_.end(), 0u);
        query_ = 1;
    }
    int crossings = 0;
    for (int z = z0; z <= z1; ++z)
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x < dims_[0]; ++x) {
                const size_t c = size_t(z) * size_t(dims_[1]) * size_t(dims_[0]) + size_t(y) * size_t(dims_[0]) + size_t(x);
                for (uint32_t k = cell_begin_[c]; k < cell_begin_[c + 1]; ++k) {
                    const uint32_t it = cell_items_[k];
                    if (it < t0 || it >= t1 || stamp_[it] == query_) continue;
                    stamp_[it] = query_;
                    if (tri_hi_[it].x() < p.x()) continue;
                    const auto& t = instrument.triangles[it];
                    crossings += ray_crosses_triangle(o, dir, inst_eye_[t[0]], inst_eye_[t[1]], inst_eye_[t[2]]);
                }
            }
    return (crossings & 1) != 0;
}

}  // namespace eyesim::sim::collision
