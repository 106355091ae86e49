#include "eyesim/sim/tissue/spring_schedule.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>

#if defined(__x86_64__) && defined(__SSE2__)
#include <immintrin.h>
#define EYESIM_SPRING_SSE 1
#endif

namespace eyesim::sim::tissue {

void SpringSchedule::build(std::span<const Spring> springs, size_t node_count) {
    constexpr uint32_t kMaxColours = 64;
    const size_t ns = springs.size();
    used_.assign(node_count, 0);
    colour_.resize(ns);
    std::array<uint32_t, kMaxColours + 1> count{};
    colours = 0;
    for (size_t k = 0; k < ns; ++k) {
        const Spring& s = springs[k];
        const uint64_t free = ~(used_[s.a] | used_[s.b]);
        // Past 64 colours (a node with more than 32 springs) the last class takes the rest: still correct,
        // only those updates wait on each other.
        const uint32_t c = free ? uint32_t(std::countr_zero(free)) : kMaxColours - 1;
        colour_[k] = uint8_t(c);
        used_[s.a] |= uint64_t{1} << c;
        used_[s.b] |= uint64_t{1} << c;
        ++count[c + 1];
        colours = std::max(colours, c + 1);
    }
    // Counting sort by colour, stable: within a class springs keep mesh order (and its locality).
    start_.assign(count.begin(), count.begin() + colours + 1);
    for (uint32_t c = 0; c < colours; ++c) start_[c + 1] += start_[c];
    class_begin.assign(start_.begin(), start_.end());
    const size_t slots = (ns + 3) & ~size_t{3};
    a.assign(slots, 0);
    b.assign(slots, 0);
    rest_mm.assign(slots, 0.0f);
    stiffness_nN_per_mm.assign(slots, 0.0f);
    damping_nN_s_per_mm.assign(slots, 0.0f);
    spring.assign(slots, kNoIndex);
    for (size_t k = 0; k < ns; ++k) {
        const uint32_t j = start_[colour_[k]]++;
        const Spring& s = springs[k];
        a[j] = s.a;
        b[j] = s.b;
        rest_mm[j] = s.rest_mm;
        stiffness_nN_per_mm[j] = s.stiffness_nN_per_mm;
        damping_nN_s_per_mm[j] = s.damping_nN_s_per_mm;
        spring[j] = uint32_t(k);
    }
}

bool SpringSchedule::matches(std::span<const Spring> springs) const {
    if (spring.size() != ((springs.size() + 3) & ~size_t{3})) return false;
    size_t seen = 0;
    for (size_t j = 0; j < spring.size(); ++j) {
        if (spring[j] == kNoIndex) {
            if (a[j] != 0 || b[j] != 0 || stiffness_nN_per_mm[j] != 0.0f || damping_nN_s_per_mm[j] != 0.0f)
                return false;
            continue;
        }
        if (spring[j] >= springs.size()) return false;
        const Spring& s = springs[spring[j]];
        if (a[j] != s.a || b[j] != s.b || rest_mm[j] != s.rest_mm || stiffness_nN_per_mm[j] != s.stiffness_nN_per_mm ||
            damping_nN_s_per_mm[j] != s.damping_nN_s_per_mm)
            return false;
        ++seen;
    }
    return seen == springs.size();  // with equal slot counts and matching records, each spring appears once
}

namespace {

// The same arithmetic, one spring at a time, in the same association order as the vector path.
void portable_kernel(const SpringSchedule& s, const Float4* x, const Float4* v, Float4* f) {
    for (size_t k = 0; k < s.a.size(); ++k) {
        const float* xa = x[s.a[k]].v;
        const float* xb = x[s.b[k]].v;
        const float* va = v[s.a[k]].v;
        const float* vb = v[s.b[k]].v;
        const float d[3] = {xb[0] - xa[0], xb[1] - xa[1], xb[2] - xa[2]};
        const float u[3] = {vb[0] - va[0], vb[1] - va[1], vb[2] - va[2]};
        // "+ 0.0f" is the padding lane's product the vector path adds (it can turn −0 into +0).
        const float len2 = (d[0] * d[0] + d[2] * d[2]) + (d[1] * d[1] + 0.0f);
        const float dot_du = (d[0] * u[0] + d[2] * u[2]) + (d[1] * u[1] + 0.0f);
        const bool ok = len2 > 1e-24f;
        const float inv_len = 1.0f / std::sqrt(ok ? len2 : 1e-24f);
        const float mag = s.stiffness_nN_per_mm[k] * (len2 * inv_len - s.rest_mm[k]) +
                          s.damping_nN_s_per_mm[k] * (dot_du * inv_len);
        const float scale = ok ? mag * inv_len : 0.0f;
        float* fa = f[s.a[k]].v;
        float* fb = f[s.b[k]].v;
        for (int i = 0; i < 3; ++i) {
            fa[i] += d[i] * scale;
            fb[i] -= d[i] * scale;
        }
    }
}

#if EYESIM_SPRING_SSE
// Four horizontal sums of (x, y, z, w) vectors whose w is 0: lane i = (p_i.x + p_i.z) + (p_i.y + p_i.w).
__attribute__((always_inline)) inline __m128 sum_xyz4(__m128 p0, __m128 p1, __m128 p2, __m128 p3) {
    const __m128 t0 = _mm_add_ps(_mm_unpacklo_ps(p0, p1), _mm_unpackhi_ps(p0, p1));
    const __m128 t1 = _mm_add_ps(_mm_unpacklo_ps(p2, p3), _mm_unpackhi_ps(p2, p3));
    return _mm_add_ps(_mm_movelh_ps(t0, t1), _mm_movehl_ps(t1, t0));
}

__attribute__((always_inline)) inline void sse_body(const SpringSchedule& s, const Float4* x, const Float4* v,
                                                    Float4* f) {
    // Local copies of the schedule's pointers: stores into f could alias them as far as the compiler knows.
    const size_t slots = s.a.size();
    const uint32_t* __restrict A = s.a.data();
    const uint32_t* __restrict B = s.b.data();
    const float* __restrict rest = s.rest_mm.data();
    const float* __restrict stiff = s.stiffness_nN_per_mm.data();
    const float* __restrict damp = s.damping_nN_s_per_mm.data();
    const __m128 tiny = _mm_set1_ps(1e-24f), one = _mm_set1_ps(1.0f);
    for (size_t k = 0; k < slots; k += 4) {
        const uint32_t a0 = A[k], a1 = A[k + 1], a2 = A[k + 2], a3 = A[k + 3];
        const uint32_t b0 = B[k], b1 = B[k + 1], b2 = B[k + 2], b3 = B[k + 3];
        const __m128 d0 = _mm_sub_ps(_mm_load_ps(x[b0].v), _mm_load_ps(x[a0].v));
        const __m128 d1 = _mm_sub_ps(_mm_load_ps(x[b1].v), _mm_load_ps(x[a1].v));
        const __m128 d2 = _mm_sub_ps(_mm_load_ps(x[b2].v), _mm_load_ps(x[a2].v));
        const __m128 d3 = _mm_sub_ps(_mm_load_ps(x[b3].v), _mm_load_ps(x[a3].v));
        const __m128 u0 = _mm_sub_ps(_mm_load_ps(v[b0].v), _mm_load_ps(v[a0].v));
        const __m128 u1 = _mm_sub_ps(_mm_load_ps(v[b1].v), _mm_load_ps(v[a1].v));
        const __m128 u2 = _mm_sub_ps(_mm_load_ps(v[b2].v), _mm_load_ps(v[a2].v));
        const __m128 u3 = _mm_sub_ps(_mm_load_ps(v[b3].v), _mm_load_ps(v[a3].v));
        const __m128 len2 = sum_xyz4(_mm_mul_ps(d0, d0), _mm_mul_ps(d1, d1), _mm_mul_ps(d2, d2), _mm_mul_ps(d3, d3));
        const __m128 dot_du = sum_xyz4(_mm_mul_ps(d0, u0), _mm_mul_ps(d1, u1), _mm_mul_ps(d2, u2), _mm_mul_ps(d3, u3));
        const __m128 ok = _mm_cmpgt_ps(len2, tiny);  // false for coincident nodes and NaN
        // max() keeps the root finite for those (and maps NaN to tiny); their force is masked off below.
        const __m128 inv_len = _mm_div_ps(one, _mm_sqrt_ps(_mm_max_ps(len2, tiny)));
        const __m128 stretch = _mm_sub_ps(_mm_mul_ps(len2, inv_len), _mm_loadu_ps(rest + k));
        const __m128 mag = _mm_add_ps(_mm_mul_ps(_mm_loadu_ps(stiff + k), stretch),
                                      _mm_mul_ps(_mm_loadu_ps(damp + k), _mm_mul_ps(dot_du, inv_len)));
        const __m128 scale = _mm_and_ps(ok, _mm_mul_ps(mag, inv_len));  // F = scale · d
        const __m128 f0 = _mm_mul_ps(d0, _mm_shuffle_ps(scale, scale, 0x00));
        const __m128 f1 = _mm_mul_ps(d1, _mm_shuffle_ps(scale, scale, 0x55));
        const __m128 f2 = _mm_mul_ps(d2, _mm_shuffle_ps(scale, scale, 0xaa));
        const __m128 f3 = _mm_mul_ps(d3, _mm_shuffle_ps(scale, scale, 0xff));
        _mm_store_ps(f[a0].v, _mm_add_ps(_mm_load_ps(f[a0].v), f0));
        _mm_store_ps(f[b0].v, _mm_sub_ps(_mm_load_ps(f[b0].v), f0));
        _mm_store_ps(f[a1].v, _mm_add_ps(_mm_load_ps(f[a1].v), f1));
        _mm_store_ps(f[b1].v, _mm_sub_ps(_mm_load_ps(f[b1].v), f1));
        _mm_store_ps(f[a2].v, _mm_add_ps(_mm_load_ps(f[a2].v), f2));
        _mm_store_ps(f[b2].v, _mm_sub_ps(_mm_load_ps(f[b2].v), f2));
        _mm_store_ps(f[a3].v, _mm_add_ps(_mm_load_ps(f[a3].v), f3));
        _mm_store_ps(f[b3].v, _mm_sub_ps(_mm_load_ps(f[b3].v), f3));
    }
}
void sse2_kernel(const SpringSchedule& s, const Float4* x, const Float4* v, Float4* f) { sse_body(s, x, v, f); }

// The same instructions in VEX encoding (three operands, fewer register copies); no FMA, so the results are
// bitwise those of the SSE2 and portable kernels.
__attribute__((target("avx"))) void avx_kernel(const SpringSchedule& s, const Float4* x, const Float4* v, Float4* f) {
    sse_body(s, x, v, f);
}
#endif

}  // namespace

SpringKernel best_spring_kernel() {
#if EYESIM_SPRING_SSE
    static const SpringKernel best = __builtin_cpu_supports("avx") ? SpringKernel::kAvx : SpringKernel::kSse2;
    return best;
#else
    return SpringKernel::kPortable;
#endif
}

bool spring_kernel_available(SpringKernel kernel) {
    switch (kernel) {
        case SpringKernel::kPortable: return true;
#if EYESIM_SPRING_SSE
        case SpringKernel::kSse2: return true;
        case SpringKernel::kAvx: return __builtin_cpu_supports("avx");
#else
        case SpringKernel::kSse2:
        case SpringKernel::kAvx: return false;
#endif
    }
    return false;
}

const char* to_string(SpringKernel kernel) {
    switch (kernel) {
        case SpringKernel::kPortable: return "portable";
        case SpringKernel::kSse2: return "sse2";
        case SpringKernel::kAvx: return "avx";
    }
    return "?";
}

namespace {

void run_kernel(SpringKernel kernel, const SpringSchedule& schedule, const Float4* x, const Float4* v, Float4* f) {
    switch (kernel) {
#if EYESIM_SPRING_SSE
        case SpringKernel::kSse2: sse2_kernel(schedule, x, v, f); return;
        case SpringKernel::kAvx: avx_kernel(schedule, x, v, f); return;
#endif
        default: portable_kernel(schedule, x, v, f); return;
    }
}

}  // namespace

void accumulate_scheduled_spring_forces(const SpringSchedule& schedule, const Float4* x_mm, const Float4* v_mm_per_s,
                                        Float4* f_nN, SpringKernel kernel) {
    run_kernel(spring_kernel_available(kernel) ? kernel : best_spring_kernel(), schedule, x_mm, v_mm_per_s, f_nN);
}

// The per-step path: the best kernel is known to be available (chosen once).
void accumulate_scheduled_spring_forces(const SpringSchedule& schedule, const Float4* x_mm, const Float4* v_mm_per_s,
                                        Float4* f_nN) {
    run_kernel(best_spring_kernel(), schedule, x_mm, v_mm_per_s, f_nN);
}

}  // namespace eyesim::sim::tissue
