#pragma once
// `require(cond)` for libFuzzer targets: aborts with the failed condition and its line, so libFuzzer keeps the
// input and the report says why (assert() would vanish under NDEBUG).
#include <cstdio>
#include <cstdlib>

#define require(...)                                                                            \
    do {                                                                                        \
        if (!(__VA_ARGS__)) {                                                                   \
            std::fprintf(stderr, "fuzz check failed at line %d: %s\n", __LINE__, #__VA_ARGS__); \
            std::abort();                                                                       \
        }                                                                                       \
    } while (0)
