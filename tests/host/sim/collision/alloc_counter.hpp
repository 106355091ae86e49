#pragma once
// Counts global operator new calls in this test program (replaced in alloc_counter.cpp).
namespace eyesim::sim::collision::testing {
/// Number of global allocations so far.
long allocation_count();
}  // namespace eyesim::sim::collision::testing
