#pragma once
/// \file
/// Springs: a 20-byte record per spring (the force kernel reads a copy in its own order, spring_schedule.hpp),
/// and cold bookkeeping for topology changes.

#include <cstdint>

namespace eyesim::sim::tissue {

/// "No index" marker for node, spring and triangle references.
inline constexpr uint32_t kNoIndex = 0xffffffffu;

/// Spring data. Force on a (b gets the opposite):
/// f_a = k (|d| − L) d̂ + c ((v_b − v_a)·d̂) d̂ with d = x_b − x_a.
struct Spring {
    uint32_t a;                      ///< first node
    uint32_t b;                      ///< second node
    float rest_mm;                   ///< rest length L
    float stiffness_nN_per_mm;       ///< k
    float damping_nN_s_per_mm;       ///< c, along the spring axis
};
static_assert(sizeof(Spring) == 20, "spring record must stay 20 bytes");

/// Why a spring exists; decides when topology changes remove it.
enum class SpringKind : uint8_t {
    kEdge = 0,     ///< along a triangle edge; lives while at least one of its triangles lives
    kBending = 1,  ///< joins the opposite vertices of two triangles sharing an edge; lives while both live
    kFree = 2,     ///< added directly (chains, tests); only tearing or node removal deletes it
};

/// Cold spring data, parallel to the hot array.
struct SpringInfo {
    SpringKind kind = SpringKind::kFree;  ///< origin of the spring
    uint32_t tri[2] = {kNoIndex, kNoIndex};  ///< triangles it belongs to (edge: 1 or 2; bending: exactly 2)
};

}  // namespace eyesim::sim::tissue
