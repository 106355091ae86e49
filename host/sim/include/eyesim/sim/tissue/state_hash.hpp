#pragma once
/// \file
/// Bytewise hash of a tissue state, for golden determinism tests.

#include "eyesim/sim/tissue/mass_spring.hpp"

#include <cstdint>

namespace eyesim::sim::tissue {

/// FNV-1a (64 bit) over the bytes of positions, velocities, node states and the live springs.
uint64_t state_hash(const MassSpringSystem& sys);

}  // namespace eyesim::sim::tissue
