#pragma once
/// \file
/// Node vectors stored 16 bytes apart with the fourth lane held at 0, behind an interface of Vec3f views.
///
/// Why: the force kernel gathers both end points of four springs a block and scatters their forces back; with a
/// 16-byte stride every gather and every scatter is one aligned vector load or store, and the integrators update
/// a node with four-lane arithmetic. Element access returns an Eigen map of the first three lanes, so code that
/// reads or writes `x_mm[i]` as a Vec3f keeps working; the padding lane is never visible through it.

#include <Eigen/Core>

#include <algorithm>
#include <cstddef>
#include <span>
#include <vector>

namespace eyesim::sim::tissue {

/// Three floats padded to 16 bytes: one aligned vector load per node.
struct alignas(16) Float4 {
    float v[4];
};

/// A resizable array of 3-vectors with a 16-byte stride (fourth lane 0).
class PaddedVec3Array {
public:
    using Ref = Eigen::Map<Eigen::Vector3f, Eigen::Aligned16>;
    using ConstRef = Eigen::Map<const Eigen::Vector3f, Eigen::Aligned16>;

    PaddedVec3Array() = default;
    PaddedVec3Array(size_t n, const Eigen::Vector3f& value) { assign(n, value); }

    /// n copies of value.
    void assign(size_t n, const Eigen::Vector3f& value) {
        lanes_.assign(n, Float4{{value.x(), value.y(), value.z(), 0.0f}});
    }
    /// A copy of the vectors in v.
    void assign(std::span<const Eigen::Vector3f> v) {
        lanes_.resize(v.size());
        for (size_t i = 0; i < v.size(); ++i) lanes_[i] = Float4{{v[i].x(), v[i].y(), v[i].z(), 0.0f}};
    }
    /// Sets every vector to zero (capacity kept).
    void set_zero() { std::fill(lanes_.begin(), lanes_.end(), Float4{{0.0f, 0.0f, 0.0f, 0.0f}}); }

    size_t size() const { return lanes_.size(); }
    bool empty() const { return lanes_.empty(); }

    Ref operator[](size_t i) { return Ref(lanes_[i].v); }
    ConstRef operator[](size_t i) const { return ConstRef(lanes_[i].v); }

    /// The vectors as a plain array (allocates; for tests, snapshots and meshes).
    std::vector<Eigen::Vector3f> to_vector() const {
        std::vector<Eigen::Vector3f> out(lanes_.size());
        for (size_t i = 0; i < lanes_.size(); ++i) out[i] = (*this)[i];
        return out;
    }
    operator std::vector<Eigen::Vector3f>() const { return to_vector(); }  // NOLINT: snapshots read naturally

    /// Raw padded storage for vector kernels. Writers must keep the fourth lane at 0.
    Float4* lanes() { return lanes_.data(); }
    const Float4* lanes() const { return lanes_.data(); }

private:
    std::vector<Float4> lanes_;
};

}  // namespace eyesim::sim::tissue
