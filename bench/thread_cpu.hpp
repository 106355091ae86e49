#pragma once
// The clock every benchmark times with: CPU time of the calling thread, so that time a busy shared machine gives
// to other processes does not count (caches and memory bandwidth still do).

#include <ctime>

namespace eyesim::bench {

/// CPU time of the calling thread, s.
inline double thread_cpu_s() {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

/// CPU time of the calling thread, µs.
inline double thread_cpu_us() { return thread_cpu_s() * 1e6; }

}  // namespace eyesim::bench
