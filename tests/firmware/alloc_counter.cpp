// Replaces the global operator new/delete to count allocations (the core must make none after start-up).
// Under AddressSanitizer the sanitizer owns operator new (mixing would be reported as a mismatch), so counting is
// unavailable there and allocation_count() returns -1.
#include "alloc_counter.hpp"

#if defined(__SANITIZE_ADDRESS__)

long eyesim::test::allocation_count() { return -1; }

#else

#include <atomic>
#include <cstdlib>
#include <new>

namespace {
std::atomic<long> g_allocations{0};
}

long eyesim::test::allocation_count() { return g_allocations.load(); }

void* operator new(std::size_t n) {
    ++g_allocations;
    if (void* p = std::malloc(n ? n : 1)) return p;
    throw std::bad_alloc();
}
void* operator new[](std::size_t n) { return operator new(n); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }

#endif
