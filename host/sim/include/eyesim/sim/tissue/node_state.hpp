#pragma once
/// \file
/// Simulation state of one tissue node (paper §4.5: fixed rim nodes, grabbed nodes, retina nodes attached to the
/// choroid until an injection detaches them).

#include <cstdint>

namespace eyesim::sim::tissue {

/// What moves a node. Only kFree and kDetached nodes are integrated; the others are kinematic or gone.
enum class NodeState : uint8_t {
    kFree = 0,      ///< integrated by the mass-spring model
    kFixed = 1,     ///< never moves (membrane rim fixed to the retina); its load raises the lift-off warning
    kGrabbed = 2,   ///< bound to the closed forceps tip, moved kinematically with it
    kAttached = 3,  ///< retina node fixed on the choroid (rear hemisphere)
    kDetached = 4,  ///< retina node lifted off by an injection: integrated like kFree
    kRemoved = 5,   ///< cut away or left without any triangle: no springs, not integrated, not rendered
};

/// True for the states the integrators move.
constexpr bool is_dynamic(NodeState s) { return s == NodeState::kFree || s == NodeState::kDetached; }

}  // namespace eyesim::sim::tissue
