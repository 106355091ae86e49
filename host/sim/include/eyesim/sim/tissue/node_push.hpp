#pragma once
/// \file
/// Interface to collision detection: per-node push vectors (paper Eq. 1, computed from ZCOLL deformation vectors).

#include <Eigen/Core>

#include <cstdint>

namespace eyesim::sim::tissue {

/// One colliding node and the vector v_i to add to its position (paper §3.3.1: "the membrane is pushed away by
/// adding a vector v_i to the position of each colliding node i"). Node indices are the TriangleMesh vertex indices
/// the tissue was built from; the vector is in the tissue's frame (eye frame), mm.
struct NodePush {
    uint32_t node;          ///< vertex index
    Eigen::Vector3f push_mm;  ///< v_i, added to the node's position before the next substep
};

}  // namespace eyesim::sim::tissue
