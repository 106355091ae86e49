#pragma once
// Heap allocations of this test program so far (global operator new is replaced in alloc_counter.cpp); -1 when
// counting is unavailable (AddressSanitizer builds).
namespace eyesim::test {
long allocation_count();
}
