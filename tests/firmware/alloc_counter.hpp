#pragma once
// Heap allocations of this test program so far (global operator new is replaced in alloc_counter.cpp).
namespace eyesim::test {
long allocation_count();
}
