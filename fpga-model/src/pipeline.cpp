#include "eyesim/fpga/pipeline.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>

#if defined(__SSE2__)
#include <emmintrin.h>
#include <xmmintrin.h>
#endif
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define EYESIM_FPGA_AVX2 1
#endif

namespace eyesim::fpga {
namespace {

constexpr double kTwoPi = 6.283185307179586;
constexpr int kPairs = static_cast<int>(kActivePixelsPerLine / 2);
constexpr int kBgCellPairs = kBgCellPixels / 2;
constexpr int kBgCellLog2 = 2;  // log2(kBgCellPairs)
static_assert(kBgCellPairs == 1 << kBgCellLog2 && kBgCells * kBgCellPixels == static_cast<int>(kActivePixelsPerLine));

// Hue distance in 1/256 turns, wrapped to [-128, 128).
double hue_delta(double a, double b) {
    double d = std::fmod(a - b, 256.0);
    if (d < -128.0) d += 256.0;
    if (d >= 128.0) d -= 256.0;
    return d;
}

// Bits needed to hold values 0..n.
uint64_t bits_for(uint64_t n) {
    uint64_t b = 1;
    while ((n >> b) != 0) ++b;
    return b;
}

// Where pixel x's background comes from: linear between the centres of the two nearest cells (a cell's chroma
// samples are co-sited with its even pixels: centre 8·j + 3), the end cells' values beyond the outer centres.
// i, i1: Cb indices of the left and right cell (Cr follows each); f: weight of the right cell in 1/8.
struct CellLerp {
    size_t i, i1;
    int f;
};
constexpr CellLerp cell_lerp(int x) {
    const int u = x - (kBgCellPairs - 1);
    int j0 = u >= 0 ? u / kBgCellPixels : 0, f = u >= 0 ? u - kBgCellPixels * j0 : 0;
    if (j0 >= kBgCells - 1) {
        j0 = kBgCells - 1;
        f = 0;
    }
    const size_t i = static_cast<size_t>(2 * j0);
    return {i, f != 0 ? i + 2 : i, f};
}

// cell_lerp of every pixel as cell · 8 + weight of the right cell.
constexpr std::array<uint16_t, kActivePixelsPerLine> make_cell_lerp() {
    std::array<uint16_t, kActivePixelsPerLine> t{};
    for (int x = 0; x < static_cast<int>(kActivePixelsPerLine); ++x) {
        const CellLerp l = cell_lerp(x);
        t[static_cast<size_t>(x)] = static_cast<uint16_t>(l.i / 2 * kBgCellPixels + static_cast<size_t>(l.f));
    }
    return t;
}
constexpr std::array<uint16_t, kActivePixelsPerLine> kCellLerp = make_cell_lerp();

// Line scans (Pipeline::LineScan): per 8-px cell the sums of its four Cb and four Cr samples and whether any of
// them lies outside the grey box |C - 128| <= T. Three implementations with identical results.
constexpr int kCellBytes = 2 * kBgCellPixels;

void scan_cells_scalar(const uint8_t* line, int T, uint32_t* sums, uint64_t* out, int j0) {
    for (int j = j0; j < kBgCells; ++j) {
        const uint8_t* q = line + kCellBytes * j;
        uint32_t cb = 0, cr = 0;
        bool outside = false;
        for (int k = 0; k < kBgCellPairs; ++k) {
            cb += q[4 * k];
            cr += q[4 * k + 2];
            outside = outside || std::abs(q[4 * k] - 128) > T || std::abs(q[4 * k + 2] - 128) > T;
        }
        sums[j] = cb | cr << 16;
        if (outside) out[j >> 6] |= 1ull << (j & 63);
    }
}

void scan_line_scalar(const uint8_t* line, int T, uint32_t* sums, uint64_t* out) {
    out[0] = out[1] = 0;
    scan_cells_scalar(line, T, sums, out, 0);
}

#if defined(__SSE2__)
// Four cells (64 bytes) per step. Box test per byte: (c - lo) mod 256 <= range; chroma bytes lo = 128 - T,
// range 2T; luma bytes always pass. Sums: the chroma bytes as 16-bit lanes (Cb, Cr of a pair), added across the
// cell's four pairs, so each cell's 32-bit result is Cb | Cr << 16.
void scan_line_sse2(const uint8_t* line, int T, uint32_t* sums, uint64_t* out) {
    const __m128i lo = _mm_set1_epi16(static_cast<short>(128 - T));
    const __m128i range = _mm_set1_epi16(static_cast<short>(0xFF00 | (2 * T)));
    const __m128i zero = _mm_setzero_si128();
    const __m128i low_bytes = _mm_set1_epi16(0x00FF);
    out[0] = out[1] = 0;
    // Steps of four cells; the last one starts at kBgCells - 4 (repeating cells 86, 87 of a 90-cell line).
    static_assert(kBgCells > 4 && (kBgCells - 4) / 64 == (kBgCells - 1) / 64);
    for (int j = 0; j < kBgCells; j = std::min(j + 4, kBgCells - 4)) {
        const __m128i* p = reinterpret_cast<const __m128i*>(line + kCellBytes * j);
        const __m128i v0 = _mm_loadu_si128(p), v1 = _mm_loadu_si128(p + 1), v2 = _mm_loadu_si128(p + 2),
                      v3 = _mm_loadu_si128(p + 3);
        const __m128i e0 = _mm_subs_epu8(_mm_sub_epi8(v0, lo), range), e1 = _mm_subs_epu8(_mm_sub_epi8(v1, lo), range),
                      e2 = _mm_subs_epu8(_mm_sub_epi8(v2, lo), range), e3 = _mm_subs_epu8(_mm_sub_epi8(v3, lo), range);
        const __m128i e = _mm_or_si128(_mm_or_si128(e0, e1), _mm_or_si128(e2, e3));
        if (_mm_movemask_epi8(_mm_cmpeq_epi8(e, zero)) != 0xFFFF) {  // some cell of the four is out of the box
            auto out_of_box = [&](__m128i ei) {
                return static_cast<uint64_t>(_mm_movemask_epi8(_mm_cmpeq_epi8(ei, zero)) != 0xFFFF);
            };
            const uint64_t bits =
                out_of_box(e0) | out_of_box(e1) << 1 | out_of_box(e2) << 2 | out_of_box(e3) << 3;
            out[j >> 6] |= bits << (j & 63);
        }
        const __m128i a0 = _mm_and_si128(v0, low_bytes), a1 = _mm_and_si128(v1, low_bytes),
                      a2 = _mm_and_si128(v2, low_bytes), a3 = _mm_and_si128(v3, low_bytes);
        const __m128i u = _mm_add_epi16(_mm_unpacklo_epi64(a0, a1), _mm_unpackhi_epi64(a0, a1));
        const __m128i w = _mm_add_epi16(_mm_unpacklo_epi64(a2, a3), _mm_unpackhi_epi64(a2, a3));
        const __m128 uf = _mm_castsi128_ps(u), wf = _mm_castsi128_ps(w);
        const __m128i s4 = _mm_add_epi16(_mm_castps_si128(_mm_shuffle_ps(uf, wf, _MM_SHUFFLE(2, 0, 2, 0))),
                                         _mm_castps_si128(_mm_shuffle_ps(uf, wf, _MM_SHUFFLE(3, 1, 3, 1))));
        _mm_storeu_si128(reinterpret_cast<__m128i*>(sums + j), s4);
        if (j == kBgCells - 4) break;
    }
}
#endif

#if defined(EYESIM_FPGA_AVX2)
// Two cells per vector of box-test results (nonzero bytes: out of the box): bit 0 for the low 16 bytes, bit 1 for
// the high 16.
__attribute__((target("avx2"))) inline uint64_t outside2_avx2(__m256i e, __m256i zero) {
    const uint32_t m = static_cast<uint32_t>(~_mm256_movemask_epi8(_mm256_cmpeq_epi8(e, zero)));
    return static_cast<uint64_t>((m & 0xFFFFu) != 0) | static_cast<uint64_t>((m >> 16) != 0) << 1;
}

// Eight cells (128 bytes) per step, the same arithmetic as the SSE2 scan in 32-byte vectors (two cells each).
__attribute__((target("avx2"))) void scan_line_avx2(const uint8_t* line, int T, uint32_t* sums, uint64_t* out) {
    const __m256i lo = _mm256_set1_epi16(static_cast<short>(128 - T));
    const __m256i range = _mm256_set1_epi16(static_cast<short>(0xFF00 | (2 * T)));
    const __m256i zero = _mm256_setzero_si256();
    const __m256i low_bytes = _mm256_set1_epi16(0x00FF);
    const __m256i order = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
    out[0] = out[1] = 0;
    // Steps of eight cells; the last one starts at kBgCells - 8 and repeats a few cells (same sums, same bits).
    static_assert(kBgCells % 8 != 0 && kBgCells > 8 && (kBgCells - 8) / 64 == (kBgCells - 1) / 64);
    for (int j = 0; j < kBgCells; j = std::min(j + 8, kBgCells - 8)) {
        const __m256i* p = reinterpret_cast<const __m256i*>(line + kCellBytes * j);
        const __m256i v0 = _mm256_loadu_si256(p), v1 = _mm256_loadu_si256(p + 1), v2 = _mm256_loadu_si256(p + 2),
                      v3 = _mm256_loadu_si256(p + 3);
        // Bytes as offsets from the box's low edge; the largest of the four vectors' (same byte kind in every
        // lane) beyond the range means some byte is out of the box.
        const __m256i d0 = _mm256_sub_epi8(v0, lo), d1 = _mm256_sub_epi8(v1, lo), d2 = _mm256_sub_epi8(v2, lo),
                      d3 = _mm256_sub_epi8(v3, lo);
        const __m256i e = _mm256_subs_epu8(_mm256_max_epu8(_mm256_max_epu8(d0, d1), _mm256_max_epu8(d2, d3)), range);
        if (!_mm256_testz_si256(e, e)) {  // some cell of the eight is out of the box (rare): which ones
            const uint64_t bits = outside2_avx2(_mm256_subs_epu8(d0, range), zero) |
                                  outside2_avx2(_mm256_subs_epu8(d1, range), zero) << 2 |
                                  outside2_avx2(_mm256_subs_epu8(d2, range), zero) << 4 |
                                  outside2_avx2(_mm256_subs_epu8(d3, range), zero) << 6;
            out[j >> 6] |= bits << (j & 63);
        }
        const __m256i a0 = _mm256_and_si256(v0, low_bytes), a1 = _mm256_and_si256(v1, low_bytes),
                      a2 = _mm256_and_si256(v2, low_bytes), a3 = _mm256_and_si256(v3, low_bytes);
        // Within each 128-bit lane as in the SSE2 scan: lane 0 gives cells 0, 2, 4, 6; lane 1 cells 1, 3, 5, 7.
        const __m256i u = _mm256_add_epi16(_mm256_unpacklo_epi64(a0, a1), _mm256_unpackhi_epi64(a0, a1));
        const __m256i w = _mm256_add_epi16(_mm256_unpacklo_epi64(a2, a3), _mm256_unpackhi_epi64(a2, a3));
        const __m256 uf = _mm256_castsi256_ps(u), wf = _mm256_castsi256_ps(w);
        const __m256i s8 =
            _mm256_add_epi16(_mm256_castps_si256(_mm256_shuffle_ps(uf, wf, _MM_SHUFFLE(2, 0, 2, 0))),
                             _mm256_castps_si256(_mm256_shuffle_ps(uf, wf, _MM_SHUFFLE(3, 1, 3, 1))));
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(sums + j), _mm256_permutevar8x32_epi32(s8, order));
        if (j == kBgCells - 8) break;
    }
    // Clean upper halves before returning to SSE code (dirty upper halves slow every later SSE instruction).
    _mm256_zeroupper();
}
#endif

#if defined(EYESIM_FPGA_AVX2)
#define EYESIM_FPGA_AVX512_TARGET __attribute__((target("avx512f,avx512bw,avx512vl")))
// Full-mask forms of unpack (the plain ones trip GCC 12's -Wuninitialized in its own headers).
EYESIM_FPGA_AVX512_TARGET inline __m512i unpacklo64(__m512i x, __m512i y) { return _mm512_maskz_unpacklo_epi64(0xFF, x, y); }
EYESIM_FPGA_AVX512_TARGET inline __m512i unpackhi64(__m512i x, __m512i y) { return _mm512_maskz_unpackhi_epi64(0xFF, x, y); }

// Sixteen cells (256 bytes) per step in 64-byte vectors (four cells each), the same arithmetic as the AVX2 scan;
// the last step starts at kBgCells - 16 and repeats a few cells (same sums, same bits).
EYESIM_FPGA_AVX512_TARGET void scan_line_avx512(const uint8_t* line, int T, uint32_t* sums, uint64_t* out) {
    const __m512i lo = _mm512_set1_epi16(static_cast<short>(128 - T));
    const __m512i range = _mm512_set1_epi16(static_cast<short>(0xFF00 | (2 * T)));
    const __m512i low_bytes = _mm512_set1_epi16(0x00FF);
    // Lane i of the sums vector holds cells i, 4 + i, 8 + i, 12 + i: cell c comes from dword 4·(c mod 4) + c / 4.
    const __m512i order = _mm512_setr_epi32(0, 4, 8, 12, 1, 5, 9, 13, 2, 6, 10, 14, 3, 7, 11, 15);
    out[0] = out[1] = 0;
    static_assert(kBgCells % 16 != 0 && kBgCells > 16 && (kBgCells - 16) / 64 == (kBgCells - 1) / 64 && 48 + 16 <= 64);
    // One bit per 16-byte cell of a 64-bit byte mask: set when any of its bytes is.
    auto cell_bits = [](uint64_t m) {
        return static_cast<uint64_t>((m & 0xFFFFu) != 0) | static_cast<uint64_t>(((m >> 16) & 0xFFFFu) != 0) << 1 |
               static_cast<uint64_t>(((m >> 32) & 0xFFFFu) != 0) << 2 | static_cast<uint64_t>((m >> 48) != 0) << 3;
    };
    for (int j = 0; j < kBgCells; j = std::min(j + 16, kBgCells - 16)) {
        const uint8_t* p = line + kCellBytes * j;
        const __m512i v0 = _mm512_loadu_si512(p), v1 = _mm512_loadu_si512(p + 64), v2 = _mm512_loadu_si512(p + 128),
                      v3 = _mm512_loadu_si512(p + 192);
        const __m512i d0 = _mm512_sub_epi8(v0, lo), d1 = _mm512_sub_epi8(v1, lo), d2 = _mm512_sub_epi8(v2, lo),
                      d3 = _mm512_sub_epi8(v3, lo);
        const __m512i dmax = _mm512_max_epu8(_mm512_max_epu8(d0, d1), _mm512_max_epu8(d2, d3));
        if (_mm512_cmpgt_epu8_mask(dmax, range) != 0) {  // some cell of the sixteen is out of the box (rare)
            const uint64_t bits = cell_bits(_mm512_cmpgt_epu8_mask(d0, range)) |
                                  cell_bits(_mm512_cmpgt_epu8_mask(d1, range)) << 4 |
                                  cell_bits(_mm512_cmpgt_epu8_mask(d2, range)) << 8 |
                                  cell_bits(_mm512_cmpgt_epu8_mask(d3, range)) << 12;
            out[j >> 6] |= bits << (j & 63);
        }
        const __m512i a0 = _mm512_and_si512(v0, low_bytes), a1 = _mm512_and_si512(v1, low_bytes),
                      a2 = _mm512_and_si512(v2, low_bytes), a3 = _mm512_and_si512(v3, low_bytes);
        const __m512i u = _mm512_add_epi16(unpacklo64(a0, a1), unpackhi64(a0, a1));
        const __m512i w = _mm512_add_epi16(unpacklo64(a2, a3), unpackhi64(a2, a3));
        const __m512 uf = _mm512_castsi512_ps(u), wf = _mm512_castsi512_ps(w);
        const __m512i s16 =
            _mm512_add_epi16(_mm512_castps_si512(_mm512_shuffle_ps(uf, wf, _MM_SHUFFLE(2, 0, 2, 0))),
                             _mm512_castps_si512(_mm512_shuffle_ps(uf, wf, _MM_SHUFFLE(3, 1, 3, 1))));
        _mm512_storeu_si512(sums + j, _mm512_maskz_permutexvar_epi32(0xFFFF, order, s16));
        if (j == kBgCells - 16) break;
    }
    _mm256_zeroupper();
}
#endif

// Background step of every cell (Pipeline::update_background's arithmetic, 16-bit lanes: Cb, Cr interleaved as in
// the cell sums): bg += (4 · sum − bg + 2^(n−1)) >> n.
inline void bg_step_cell(int16_t* bg, const uint32_t* sums, int j, int n) {
    const int half = 1 << (n - 1);
    const int mcb = static_cast<int>(sums[j] & 0xFFFFu) << (4 - kBgCellLog2);  // cell mean ×16
    const int mcr = static_cast<int>(sums[j] >> 16) << (4 - kBgCellLog2);
    bg[2 * j] = static_cast<int16_t>(bg[2 * j] + ((mcb - bg[2 * j] + half) >> n));
    bg[2 * j + 1] = static_cast<int16_t>(bg[2 * j + 1] + ((mcr - bg[2 * j + 1] + half) >> n));
}

void bg_step_scalar(int16_t* bg, const uint32_t* sums, int n) {
    for (int j = 0; j < kBgCells; ++j) bg_step_cell(bg, sums, j, n);
}

#if defined(__SSE2__)
void bg_step_sse2(int16_t* bg, const uint32_t* sums, int n) {
    static_assert(kBgCells % 2 == 0);
    const __m128i v_half = _mm_set1_epi16(static_cast<short>(1 << (n - 1)));
    const __m128i v_shift = _mm_cvtsi32_si128(n);
    auto step = [&](__m128i s, __m128i b) {
        return _mm_add_epi16(b, _mm_sra_epi16(_mm_add_epi16(_mm_sub_epi16(_mm_slli_epi16(s, 4 - kBgCellLog2), b), v_half), v_shift));
    };
    int j = 0;
    for (; j + 4 <= kBgCells; j += 4) {
        __m128i* bp = reinterpret_cast<__m128i*>(bg + 2 * j);
        _mm_storeu_si128(bp, step(_mm_loadu_si128(reinterpret_cast<const __m128i*>(sums + j)), _mm_loadu_si128(bp)));
    }
    for (; j < kBgCells; j += 2) {  // two cells in the low 64 bits
        __m128i* bp = reinterpret_cast<__m128i*>(bg + 2 * j);
        _mm_storel_epi64(bp, step(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(sums + j)), _mm_loadl_epi64(bp)));
    }
}
#endif

#if defined(EYESIM_FPGA_AVX2)
// Eight cells' step from their sums s and values b (16-bit lanes).
__attribute__((target("avx2"))) inline __m256i bg_step8_avx2(__m256i s, __m256i b, __m256i v_half, __m128i v_shift) {
    const __m256i m = _mm256_slli_epi16(s, 4 - kBgCellLog2);
    return _mm256_add_epi16(b, _mm256_sra_epi16(_mm256_add_epi16(_mm256_sub_epi16(m, b), v_half), v_shift));
}

__attribute__((target("avx2"))) void bg_step_avx2(int16_t* bg, const uint32_t* sums, int n) {
    static_assert(kBgCells % 2 == 0);
    const __m256i v_half = _mm256_set1_epi16(static_cast<short>(1 << (n - 1)));
    const __m128i v_shift = _mm_cvtsi32_si128(n);
    int j = 0;
    for (; j + 8 <= kBgCells; j += 8) {
        __m256i* bp = reinterpret_cast<__m256i*>(bg + 2 * j);
        _mm256_storeu_si256(bp, bg_step8_avx2(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(sums + j)),
                                              _mm256_loadu_si256(bp), v_half, v_shift));
    }
    _mm256_zeroupper();
    for (; j < kBgCells; j += 2) {  // two cells in the low 64 bits
        __m128i* bp = reinterpret_cast<__m128i*>(bg + 2 * j);
        const __m128i b = _mm_loadl_epi64(bp);
        const __m128i m = _mm_slli_epi16(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(sums + j)), 4 - kBgCellLog2);
        _mm_storel_epi64(bp, _mm_add_epi16(b, _mm_sra_epi16(_mm_add_epi16(_mm_sub_epi16(m, b), _mm256_castsi256_si128(v_half)), v_shift)));
    }
}
#endif

#if defined(EYESIM_FPGA_AVX2)
// Sixteen cells (32 lanes) per step; the last ten cells in masked lanes.
EYESIM_FPGA_AVX512_TARGET inline __m512i bg_step16_avx512(__m512i s, __m512i b, __m512i v_half, __m128i v_shift) {
    return _mm512_add_epi16(b, _mm512_sra_epi16(_mm512_add_epi16(_mm512_sub_epi16(_mm512_slli_epi16(s, 4 - kBgCellLog2), b), v_half), v_shift));
}

EYESIM_FPGA_AVX512_TARGET void bg_step_avx512(int16_t* bg, const uint32_t* sums, int n) {
    const __m512i v_half = _mm512_set1_epi16(static_cast<short>(1 << (n - 1)));
    const __m128i v_shift = _mm_cvtsi32_si128(n);
    int j = 0;
    for (; j + 16 <= kBgCells; j += 16)
        _mm512_storeu_si512(bg + 2 * j, bg_step16_avx512(_mm512_loadu_si512(sums + j), _mm512_loadu_si512(bg + 2 * j), v_half, v_shift));
    static_assert(kBgCells % 16 != 0);
    const __mmask32 m = (1u << (2 * (kBgCells % 16))) - 1;
    _mm512_mask_storeu_epi16(bg + 2 * j, m, bg_step16_avx512(_mm512_maskz_loadu_epi16(m, sums + j), _mm512_maskz_loadu_epi16(m, bg + 2 * j), v_half, v_shift));
    _mm256_zeroupper();
}

// bg_step_avx2 that leaves the held cells (bit j of held: cell j) as they are, by a blend.
__attribute__((target("avx2"))) void bg_step_held_avx2(int16_t* bg, const uint32_t* sums, int n, const uint64_t* held) {
    const __m256i v_half = _mm256_set1_epi16(static_cast<short>(1 << (n - 1)));
    const __m128i v_shift = _mm_cvtsi32_si128(n);
    // 16-bit lane l holds cell l / 2's Cb or Cr: its bit of the group's held mask.
    const __m256i lane_bit = _mm256_setr_epi16(1, 1, 2, 2, 4, 4, 8, 8, 16, 16, 32, 32, 64, 64, 128, 128);
    static_assert(kBgCells % 8 == 2 && 64 % 8 == 0);
    int j = 0;
    for (; j + 8 <= kBgCells; j += 8) {
        __m256i* bp = reinterpret_cast<__m256i*>(bg + 2 * j);
        const __m256i b = _mm256_loadu_si256(bp);
        const __m256i stepped = bg_step8_avx2(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(sums + j)), b, v_half, v_shift);
        const short h = static_cast<short>((held[j >> 6] >> (j & 63)) & 0xFFu);
        const __m256i keep = _mm256_cmpeq_epi16(_mm256_and_si256(_mm256_set1_epi16(h), lane_bit), lane_bit);
        _mm256_storeu_si256(bp, _mm256_blendv_epi8(stepped, b, keep));
    }
    _mm256_zeroupper();
    for (; j < kBgCells; ++j)  // the last two cells one by one
        if (((held[j >> 6] >> (j & 63)) & 1) == 0) bg_step_cell(bg, sums, j, n);
}

// bg_step_avx512 that leaves the held cells (bit j of held: cell j) as they are, by the store's lane mask.
EYESIM_FPGA_AVX512_TARGET void bg_step_held_avx512(int16_t* bg, const uint32_t* sums, int n, const uint64_t* held) {
    const __m512i v_half = _mm512_set1_epi16(static_cast<short>(1 << (n - 1)));
    const __m128i v_shift = _mm_cvtsi32_si128(n);
    // 16-bit lane l holds cell l / 2's Cb or Cr: its bit of the group's held mask.
    const __m512i lane_bit = _mm512_set_epi16(-32768, -32768, 16384, 16384, 8192, 8192, 4096, 4096, 2048, 2048, 1024, 1024,
                                              512, 512, 256, 256, 128, 128, 64, 64, 32, 32, 16, 16, 8, 8, 4, 4, 2, 2, 1, 1);
    for (int j = 0; j < kBgCells; j += 16) {
        const int h = static_cast<int>((held[j >> 6] >> (j & 63)) & 0xFFFFu);
        const __mmask32 keep = _mm512_test_epi16_mask(_mm512_set1_epi16(static_cast<short>(h)), lane_bit);
        const __mmask32 in_line = j + 16 <= kBgCells ? ~0u : (1u << (2 * (kBgCells - j))) - 1;
        const __m512i b = _mm512_maskz_loadu_epi16(in_line, bg + 2 * j);
        const __m512i s = _mm512_maskz_loadu_epi16(in_line, sums + j);
        _mm512_mask_storeu_epi16(bg + 2 * j, in_line & ~keep, bg_step16_avx512(s, b, v_half, v_shift));
    }
    _mm256_zeroupper();
}
#endif

// The scan for a requested instruction set, falling back to what this build and CPU have.
Pipeline::LineScan select_scan(ScanIsa want, ScanIsa& got, Pipeline::BgStep& bg_step) {
#if defined(EYESIM_FPGA_AVX2)
    if ((want == ScanIsa::kAuto || want == ScanIsa::kAvx512) && __builtin_cpu_supports("avx512f") &&
        __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx2")) {
        got = ScanIsa::kAvx512;
        bg_step = bg_step_avx512;
        return scan_line_avx512;
    }
    if ((want == ScanIsa::kAuto || want == ScanIsa::kAvx2 || want == ScanIsa::kAvx512) && __builtin_cpu_supports("avx2")) {
        got = ScanIsa::kAvx2;
        bg_step = bg_step_avx2;
        return scan_line_avx2;
    }
#endif
#if defined(__SSE2__)
    if (want != ScanIsa::kScalar) {
        got = ScanIsa::kSse2;
        bg_step = bg_step_sse2;
        return scan_line_sse2;
    }
#endif
    (void)want;
    got = ScanIsa::kScalar;
    bg_step = bg_step_scalar;
    return scan_line_scalar;
}

}  // namespace

Pipeline::Pipeline(const RegisterMap& snapshot, const PipelineConfig& config) : own_(snapshot) { init(config); }

Pipeline::Pipeline(const RegisterMap* live, const PipelineConfig& config) : live_(live) { init(config); }

void Pipeline::init(const PipelineConfig& config) {
    config_ = config;
    config_.blob_table_capacity = std::clamp(config_.blob_table_capacity, 1, kMaxBlobSlots);
    n_free_ = 0;
    for (int i = config_.blob_table_capacity - 1; i >= 0; --i) free_list_[n_free_++] = static_cast<uint16_t>(i);
    scan_ = select_scan(config_.scan_isa, scan_isa_, bg_step_);
    compile();
}

void Pipeline::set_registers(const RegisterMap& snapshot) {
    own_ = snapshot;
    snapshot_dirty_ = true;
}

void Pipeline::set_sink(BlobSink sink, void* context) {
    sink_ = sink;
    sink_ctx_ = context;
}

// Compiles the register map into the datapath tables: class LUT, weight directions, luma bands, fast-path box.
void Pipeline::compile() {
    const RegisterMap& m = live_ ? *live_ : own_;
    // Live map: recompile when its write counter moved. Snapshot: when set_registers replaced it.
    if (compiled_once_ && (live_ ? m.generation() == compiled_generation_ : !snapshot_dirty_)) return;
    snapshot_dirty_ = false;
    compiled_generation_ = m.generation();
    compiled_once_ = true;
    params_ = decode(m);
    const PipelineParams& p = params_;

    constexpr int kCells = 1 << kLutChromaBits;
    constexpr double kStep = 256.0 / kCells;
    for (int qb = 0; qb < kCells; ++qb) {
        for (int qr = 0; qr < kCells; ++qr) {
            // A cell is classified by its centre chroma.
            const double cb = qb * kStep + (kStep - 1) / 2.0, cr = qr * kStep + (kStep - 1) / 2.0;
            const double dcb = cb - 128.0, dcr = cr - 128.0;
            const double sat = std::hypot(dcb, dcr);
            double hue = std::atan2(dcr, dcb) / kTwoPi * 256.0;
            if (hue < 0) hue += 256.0;
            uint8_t cls = 0;
            for (int c = 1; c <= kNumClasses && cls == 0; ++c) {
                if (!(p.class_enable & (1u << (c - 1)))) continue;
                const int i = c - 1;
                if (std::fabs(hue_delta(hue, p.hue_centre[i])) <= p.hue_half_width[i] && sat >= p.sat_min[i] &&
                    sat <= p.sat_max[i])
                    cls = static_cast<uint8_t>(c);
            }
            lut_[static_cast<size_t>(qb << kLutChromaBits | qr)] = cls;
        }
    }
    luma_min_[0] = 0;
    luma_max_[0] = 255;
    for (int c = 1; c <= kNumClasses; ++c) {
        const double a = p.hue_centre[c - 1] * kTwoPi / 256.0;
        dir_cb_ref_[c] = std::cos(a);
        dir_cr_ref_[c] = std::sin(a);
        dir_cb_q9_[c] = static_cast<int16_t>(std::lround(512.0 * dir_cb_ref_[c]));
        dir_cr_q9_[c] = static_cast<int16_t>(std::lround(512.0 * dir_cr_ref_[c]));
        luma_min_[c] = p.luma_min[c - 1];
        luma_max_[c] = p.luma_max[c - 1];
    }

    // AVX2 chunk weights' tables: the class LUT with each class's luma band, and per class the direction pair and
    // level (classes 0 and 5..7 weigh nothing).
    for (size_t i = 0; i < lut_band_.size(); ++i) {
        const uint8_t c = lut_[i];
        lut_band_[i] = c | static_cast<uint32_t>(luma_min_[c]) << 8 | static_cast<uint32_t>(luma_max_[c]) << 16;
    }
    dir_pair_.fill(0);
    level_.fill(0);
    for (int c = 1; c <= kNumClasses; ++c) {
        dir_pair_[static_cast<size_t>(c)] = static_cast<int32_t>(static_cast<uint16_t>(dir_cb_q9_[c]) |
                                                                 static_cast<uint32_t>(static_cast<uint16_t>(dir_cr_q9_[c])) << 16);
        level_[static_cast<size_t>(c)] = p.weight_bg[c];
    }

    // Fast path: the largest grey box |Cb-128|, |Cr-128| ≤ T whose LUT cells are all background. Chroma of an
    // odd pixel is the mean of two in-box pairs, hence in the box too: skipping is exact.
    fast_half_width_ = 0;
    if (p.fast_path) {
        for (int t = 1; t <= 127; ++t) {
            bool all_bg = true;
            const int q0 = (128 - t) >> 2, q1 = (128 + t) >> 2;
            for (int qb = q0; qb <= q1 && all_bg; ++qb)
                for (int qr = q0; qr <= q1 && all_bg; ++qr)
                    all_bg = lut_[static_cast<size_t>(qb << kLutChromaBits | qr)] == 0;
            if (!all_bg) break;
            fast_half_width_ = t;
        }
    }
}

uint8_t Pipeline::lut_class(uint8_t cb, uint8_t cr) const {
    return lut_[static_cast<size_t>((cb >> (8 - kLutChromaBits)) << kLutChromaBits | (cr >> (8 - kLutChromaBits)))];
}

uint8_t Pipeline::classify(uint8_t y, uint8_t cb, uint8_t cr) const {
    const uint8_t c = lut_class(cb, cr);
    return (c != 0 && y >= luma_min_[c] && y <= luma_max_[c]) ? c : 0;
}

uint16_t Pipeline::weight2(uint8_t cls, int y, int cb2, int cr2) const {
    return weight2_bg(cls, y, cb2, cr2, 128 * 128, 128 * 128);
}

uint16_t Pipeline::weight2_bg(uint8_t cls, int y, int cb2, int cr2, int bg_cb_q7, int bg_cr_q7) const {
    if (params_.weight_mode == 0) return 1;
    // Mode 1: projection of the chroma minus the background on the class hue direction, Q1.9 coefficients,
    // rounded (chroma ×2 as the datapath keeps it, scaled to the background's ×128). Mode 2: luma. Both minus
    // the background level WEIGHT_BG, clamped to 0..255.
    return weight_from_value(cls, params_.weight_mode == 2 ? y : band_residual(cls, cb2, cr2, bg_cb_q7, bg_cr_q7));
}

int Pipeline::band_residual(uint8_t cls, int cb2, int cr2, int bg_cb_q7, int bg_cr_q7) const {
    return ((64 * cb2 - bg_cb_q7) * dir_cb_q9_[cls] + (64 * cr2 - bg_cr_q7) * dir_cr_q9_[cls] + (1 << 15)) >> 16;
}

// Background chroma ×128 (×16 per cell, ×8 from the interpolation) at pixel x.
// cell_lerp from a table (cell · 8 + weight per pixel); the right cell is read even where its weight is 0 (the last
// cell's right neighbour is bg_q4_'s padding).
inline void Pipeline::background_at(int x, int& cb_q7, int& cr_q7) const {
    const int e = kCellLerp[static_cast<size_t>(x)], f = e & (kBgCellPixels - 1);
    const int16_t* b = bg_q4_.data() + 2 * (e >> 3);
    cb_q7 = b[0] * (kBgCellPixels - f) + b[2] * f;
    cr_q7 = b[1] * (kBgCellPixels - f) + b[3] * f;
}

void Pipeline::background_reference_at(int x, double& cb, double& cr) const {
    const CellLerp l = cell_lerp(x);
    cb = (bg_ref_[l.i] * (kBgCellPixels - l.f) + bg_ref_[l.i1] * l.f) / kBgCellPixels;
    cr = (bg_ref_[l.i + 1] * (kBgCellPixels - l.f) + bg_ref_[l.i1 + 1] * l.f) / kBgCellPixels;
}

// band_residual against the tracked background at pixel x.
inline int Pipeline::background_residual_at(uint8_t cls, int cb2, int cr2, int x) const {
    int bcb, bcr;
    background_at(x, bcb, bcr);
    return band_residual(cls, cb2, cr2, bcb, bcr);
}

// weight2_bg's level, clamp and width for a projection or luma value v.
inline uint16_t Pipeline::weight_from_value(uint8_t cls, int v) const {
    const int w = std::clamp(v - static_cast<int>(params_.weight_bg[cls]), 0, 255);
    return static_cast<uint16_t>(w >> (8 - params_.weight_bits));
}

// Pixel weight against the tracked background at pixel x (with BG_TRACK off the cells hold neutral 128): what
// weight2_bg gives with background_at(x), inlined for the datapath's loops.
inline uint16_t Pipeline::weight_at(uint8_t cls, int luma, int cb2, int cr2, int x) const {
    if (params_.weight_mode == 1) return weight_from_value(cls, background_residual_at(cls, cb2, cr2, x));
    if (params_.weight_mode == 0) return 1;
    return weight_from_value(cls, luma);
}

double Pipeline::weight_reference(uint8_t cls, double y, double cb, double cr) const {
    if (params_.weight_mode == 0) return 1.0;
    const double v =
        params_.weight_mode == 2 ? y : (cb - 128.0) * dir_cb_ref_[cls] + (cr - 128.0) * dir_cr_ref_[cls];
    return std::clamp(v - params_.weight_bg[cls], 0.0, 255.0);
}

double Pipeline::weight_reference_at(uint8_t cls, double luma, double cb, double cr, int x) const {
    if (params_.weight_mode != 1) return weight_reference(cls, luma, cb, cr);
    double bcb, bcr;
    background_reference_at(x, bcb, bcr);
    const double v = (cb - bcb) * dir_cb_ref_[cls] + (cr - bcr) * dir_cr_ref_[cls];
    return std::clamp(v - params_.weight_bg[cls], 0.0, 255.0);
}

PipelineStatus Pipeline::begin_field(uint32_t field_counter, uint8_t parity) {
    if (in_field_) return PipelineStatus::kAlreadyInField;
    compile();
    in_field_ = true;
    field_counter_ = field_counter;
    parity_ = parity;
    last_line_ = -1;
    prev_line_ = nullptr;
    next_index_ = 0;
    next_emit_free_cycle_ = 0;
    n_runs_ = {0, 0};
    stats_ = FieldStats{};
    stats_.field_counter = field_counter;
    bg_q4_.fill(128 << kBgFracBits);
    bg_ref_.fill(128.0);
    bg_seeded_ = {};
    bg_all_seeded_ = false;
    occupied_older_ = {};
    n_runs_older_ = 0;
    occupied_ = {};  // the first line's "line above" masks are empty, not the previous field's
    claimed_ = {};
    claimed_dirty_ = {};
    hold_cells_ = {};
    hold_cells_older_ = {};
    cells_path_ = fast_half_width_ > 0 && params_.roi_enable == 0 && !config_.float_reference;
    simd_weights_ = cells_path_ && (scan_isa_ == ScanIsa::kAvx2 || scan_isa_ == ScanIsa::kAvx512) && params_.weight_mode == 1;
    simd16_ = simd_weights_ && scan_isa_ == ScanIsa::kAvx512;
    return PipelineStatus::kOk;
}

PipelineStatus Pipeline::push_line(const uint8_t* uyvy_line, int y) { return push_line_impl(uyvy_line, y, false); }

PipelineStatus Pipeline::push_line_impl(const uint8_t* uyvy_line, int y, bool stable) {
    if (!in_field_) return PipelineStatus::kNotInField;
    if (y < 0 || y >= kMaxFieldLines) return PipelineStatus::kLineOutOfRange;
    if (y <= last_line_) return PipelineStatus::kLineOutOfOrder;
    if (uyvy_line == nullptr) return PipelineStatus::kNullLine;
    if (!params_.enable) {
        last_line_ = y;
        ++stats_.lines;
        return PipelineStatus::kOk;
    }
    // A gap: the line after the previous one is background, which completes every blob still open.
    if (last_line_ >= 0 && y > last_line_ + 1) {
        cur_buf_ ^= 1;
        if (n_runs_[cur_buf_] != 0) {
            occupied_[cur_buf_] = {};
            hold_cells_[cur_buf_] = {};
        }
        n_runs_[cur_buf_] = 0;
        label_line(last_line_ + 1, false, nullptr);
        prev_line_ = nullptr;
    }
    cur_buf_ ^= 1;
    // The buffer's masks have bits only where its line had runs (occupied, held cells) or ring claims: most lines
    // have none, and nothing is copied or cleared.
    n_runs_older_ = n_runs_[cur_buf_];
    if (n_runs_older_ != 0) {
        occupied_older_ = occupied_[cur_buf_];
        hold_cells_older_ = hold_cells_[cur_buf_];
        occupied_[cur_buf_] = {};
        hold_cells_[cur_buf_] = {};
    }
    if (claimed_dirty_[cur_buf_]) {
        claimed_[cur_buf_] = {};
        claimed_dirty_[cur_buf_] = false;
    }
    if (cells_path_)
        classify_line_cells(uyvy_line);
    else if (config_.float_reference)
        classify_line<true>(uyvy_line, y);
    else
        classify_line<false>(uyvy_line, y);
    finish_line(uyvy_line, y, stable);
    return PipelineStatus::kOk;
}

// After line y is classified: labelling and ring, the background's step from the previous line, the line buffer.
void Pipeline::finish_line(const uint8_t* uyvy_line, int y, bool stable) {
    // Nothing to connect, ring or complete when neither this line nor the previous one has a run (most lines).
    if (n_runs_[0] != 0 || n_runs_[1] != 0) label_line(y, false, uyvy_line);
    // The background learns from the previous line once this line has shown which of its pixels are next to a
    // blob; this line's weights were computed from lines up to y - 2.
    if (params_.bg_track_shift != 0 && params_.weight_mode == 1 && prev_line_ != nullptr && last_line_ == y - 1) {
        if (cells_path_)
            update_background_cells();
        else
            update_background(prev_line_, y - 1);
    }
    // The hardware keeps the previous line in a line buffer for the ring above new blobs; callers of push_line
    // may reuse their buffer, so it is copied unless the whole field is in memory (process_field).
    if ((params_.edge_ring || params_.bg_track_shift != 0) && !stable) {
        std::memcpy(prev_line_copy_.data(), uyvy_line, kLineBytes);
        prev_line_ = prev_line_copy_.data();
    } else {
        prev_line_ = uyvy_line;
    }
    last_line_ = y;
    ++stats_.lines;
}

// Line y of a field in memory (process_field) where neither of the two lines before had a run, on the fast line
// path: what push_line_impl does, with the line scan's result tested first. A line whose cells are all inside the
// grey box (most lines) has no run and holds no cell: it ends with the background's step from the previous line.
void Pipeline::push_quiet_line(const uint8_t* uyvy_line, int y) {
    cur_buf_ ^= 1;
    n_runs_older_ = 0;  // the buffer's line had no run: its masks are clear
    if (claimed_dirty_[cur_buf_]) {
        claimed_[cur_buf_] = {};
        claimed_dirty_[cur_buf_] = false;
    }
    uint64_t out[2];
    scan_(uyvy_line, fast_half_width_, cell_sums_[cur_buf_].data(), out);
    if ((out[0] | out[1]) != 0) {
        classify_cells(uyvy_line, out);
        finish_line(uyvy_line, y, true);
        return;
    }
    n_runs_[cur_buf_] = 0;
    stats_.fast_path_pixels += static_cast<uint32_t>(kActivePixelsPerLine);
    if (params_.bg_track_shift != 0 && params_.weight_mode == 1) {
        if (bg_all_seeded_)  // no cell is held: no run on this line or the two before
            bg_step_(bg_q4_.data(), cell_sums_[cur_buf_ ^ 1].data(), params_.bg_track_shift);
        else
            update_background_cells();
    }
    prev_line_ = uyvy_line;
    last_line_ = y;
    ++stats_.lines;
}

PipelineStatus Pipeline::end_field() {
    if (!in_field_) return PipelineStatus::kNotInField;
    if (params_.enable && last_line_ >= 0) {
        cur_buf_ ^= 1;
        n_runs_[cur_buf_] = 0;
        label_line(last_line_, true, nullptr);
    }
    prev_line_ = nullptr;
    stats_.last_active_line_end_cycle = active_line_end_cycle(static_cast<uint32_t>(std::max(last_line_, 0)));
    stats_.last_blob_latency_cycles = stats_.last_emit_cycle > stats_.last_active_line_end_cycle
                                          ? stats_.last_emit_cycle - stats_.last_active_line_end_cycle
                                          : 0;
    in_field_ = false;
    return PipelineStatus::kOk;
}

namespace {
// Requests a line's cache lines (Locality: __builtin_prefetch's, a constant there).
template <int Locality>
inline void prefetch_line(const char* q) {
    for (size_t b = 0; b < kLineBytes; b += 64) __builtin_prefetch(q + b, 0, Locality);
    __builtin_prefetch(q + kLineBytes - 1, 0, Locality);
}
}  // namespace

PipelineStatus Pipeline::process_field(const uint8_t* uyvy_field, int lines, uint32_t field_counter, uint8_t parity,
                                       size_t stride_bytes) {
    PipelineStatus s = begin_field(field_counter, parity);
    if (s != PipelineStatus::kOk) return s;
    if (uyvy_field == nullptr && lines > 0) {
        end_field();
        return PipelineStatus::kNullLine;
    }
    // The field is in memory: each line's bytes are requested PipelineConfig::prefetch_lines lines ahead, so the
    // memory reads of later lines overlap the work on this one (a model option; the hardware streams).
    const int ahead = config_.prefetch_lines;
    for (int y = 0; y < lines; ++y) {
        if (ahead > 0 && y + ahead < lines) {
            const char* q = reinterpret_cast<const char*>(uyvy_field + static_cast<size_t>(y + ahead) * stride_bytes);
            if (config_.prefetch_l1)
                prefetch_line<3>(q);  // prefetcht0
            else
                prefetch_line<2>(q);  // prefetcht1
        }
        const uint8_t* line = uyvy_field + static_cast<size_t>(y) * stride_bytes;
        if (cells_path_ && params_.enable && y > 0 && n_runs_[0] == 0 && n_runs_[1] == 0) {
            push_quiet_line(line, y);
            continue;
        }
        s = push_line_impl(line, y, true);
        if (s != PipelineStatus::kOk) {
            end_field();
            return s;
        }
    }
    return end_field();
}

namespace {
// Sets bits [b0, b1] (at most 64 of them) of a mask with a spare word after the last one it needs: one two-word window.
inline void mark_bits_window(uint64_t* mask, int b0, int b1) {
    const size_t w0 = static_cast<size_t>(b0 >> 6);
    const int sh = b0 & 63;
    const uint64_t bits = ~0ull >> (63 - (b1 - b0));
    mask[w0] |= bits << sh;
    mask[w0 + 1] |= (bits >> 1) >> (63 - sh);
}

// Sets bits [b0, b1] of a multi-word mask.
inline void mark_bits(uint64_t* mask, int b0, int b1) {
    for (int b = b0; b <= b1;) {
        const int wi = b >> 6, l0 = b & 63, l1 = std::min(63, l0 + (b1 - b));
        mask[wi] |= (l1 - l0 == 63) ? ~0ull : (((1ull << (l1 - l0 + 1)) - 1) << l0);
        b += l1 - l0 + 1;
    }
}
}  // namespace

// Ends the open run (if any) at x_end: appends it to the line's runs and marks its pixels occupied.
inline void Pipeline::close_run(OpenRun& o, int x_end, Run* runs, int& n) {
    if (o.cls != 0) {
        Run& r = runs[n++];
        r.x0 = static_cast<uint16_t>(o.x0);
        r.x1 = static_cast<uint16_t>(x_end);
        r.label = kNoLabel;
        r.cls = o.cls;
        r.sum_w = o.sw;
        r.sum_wx = o.swx;
        r.sum_wxx = o.swxx;
        r.pos_n = o.pn;
        r.pos_sx = o.psx;
        r.ref_w = o.rw;
        r.ref_wx = o.rwx;
        r.ref_wxx = o.rwxx;
        if (x_end - o.x0 < 64)
            mark_bits_window(occupied_[cur_buf_].data(), o.x0, x_end);
        else
            mark_bits(occupied_[cur_buf_].data(), o.x0, x_end);
        // Cells with a pixel within kBgHoldColumns of the run: 8j - H ≤ x_end and 8j + 7 + H ≥ x0.
        constexpr int kLo = kBgHoldColumns + kBgCellPixels - 1;
        const int j0 = o.x0 <= kLo ? 0 : (o.x0 - kLo + kBgCellPixels - 1) / kBgCellPixels;
        const int j1 = std::min(kBgCells - 1, (x_end + kBgHoldColumns) / kBgCellPixels);
        if (j1 - j0 < 64)
            mark_bits_window(hold_cells_[cur_buf_].data(), j0, j1);
        else
            mark_bits(hold_cells_[cur_buf_].data(), j0, j1);
    }
    o.cls = 0;
}

// Pixel px of class c (0: background) with weight w: extends, closes or opens the line's open run, adds w.
inline void Pipeline::run_pixel(OpenRun& o, uint8_t c, uint32_t w, int px, Run* runs, int& n) {
    if (c != o.cls) {
        close_run(o, px - 1, runs, n);
        if (c != 0) {
            o = OpenRun{};
            o.cls = c;
            o.x0 = px;
        }
    }
    if (c != 0) {
        o.sw += w;
        o.swx += w * static_cast<uint32_t>(px);
        o.swxx += static_cast<uint64_t>(w) * static_cast<uint32_t>(px * px);
        if (w != 0) {
            ++o.pn;
            o.psx += static_cast<uint32_t>(px);
        }
    }
}

// The datapath for pixel px: classify (LUT + luma band), extend, close or open the run, add the weight.
template <bool kRef>
inline void Pipeline::classify_pixel(const uint8_t* line, int px, OpenRun& o, Run* runs, int& n) {
    const int k = px >> 1;
    const uint8_t* q = line + 4 * k;
    int cb = q[0], cr = q[2];
    const int luma = q[1 + 2 * (px & 1)];
    int cb2 = 2 * cb, cr2 = 2 * cr;  // chroma ×2: exact for the interpolated odd pixels
    if ((px & 1) && k < kPairs - 1) {  // odd pixel: chroma interpolated between co-sited neighbours
        cb2 = cb + q[4];
        cr2 = cr + q[6];
        cb = (cb2 + 1) >> 1;
        cr = (cr2 + 1) >> 1;
    }
    uint8_t c = lut_[static_cast<size_t>((cb >> 2) << kLutChromaBits | (cr >> 2))];
    if (c != 0 && (luma < luma_min_[c] || luma > luma_max_[c])) c = 0;
    run_pixel(o, c, c != 0 ? weight_at(c, luma, cb2, cr2, px) : 0, px, runs, n);
    if constexpr (kRef) {
        if (c != 0) {
            const double wr = weight_reference_at(c, luma, 0.5 * cb2, 0.5 * cr2, px);
            o.rw += wr;
            o.rwx += wr * px;
            o.rwxx += wr * px * px;
        }
    }
}

template <bool kRef>
void Pipeline::classify_line(const uint8_t* line, int y) {
    Run* runs = runs_[cur_buf_].data();
    int n = 0;

    // Processed spans of this line: the whole line, or the union of the ROI windows containing it.
    uint16_t span_x0[kNumRoiWindows + 1], span_x1[kNumRoiWindows + 1];
    const int n_spans = processed_spans(y, span_x0, span_x1);

    const int T = fast_half_width_;
    // Box test per byte: (c - lo) mod 256 ≤ range. Chroma lanes (even bytes): lo = 128-T, range = 2T; luma lanes
    // (odd bytes) always pass (lo = 0, range = 255).
#if defined(__SSE2__)
    const __m128i lo = _mm_set1_epi16(static_cast<short>(128 - T));
    const __m128i range = _mm_set1_epi16(static_cast<short>(0xFF00 | (2 * T)));
    const __m128i zero = _mm_setzero_si128();
    auto outside = [&](const uint8_t* p) {  // nonzero lanes: out of the box
        return _mm_subs_epu8(_mm_sub_epi8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)), lo), range);
    };
    // True when the 4 pairs starting at pixel x (even) are all inside the grey box.
    auto chunk_in_box = [&](int x) { return _mm_movemask_epi8(_mm_cmpeq_epi8(outside(line + 2 * x), zero)) == 0xFFFF; };
    // Same for 16 pairs (32 pixels).
    auto chunk4_in_box = [&](int x) {
        const uint8_t* p = line + 2 * x;
        const __m128i e = _mm_or_si128(_mm_or_si128(outside(p), outside(p + 16)), _mm_or_si128(outside(p + 32), outside(p + 48)));
        return _mm_movemask_epi8(_mm_cmpeq_epi8(e, zero)) == 0xFFFF;
    };
#else
    auto pair_in_box = [&](int k) {
        const uint8_t* q = line + 4 * k;
        return std::abs(q[0] - 128) <= T && std::abs(q[2] - 128) <= T;
    };
    auto chunk_in_box = [&](int x) {
        const int k = x >> 1;
        return pair_in_box(k) && pair_in_box(k + 1) && pair_in_box(k + 2) && pair_in_box(k + 3);
    };
    auto chunk4_in_box = [&](int x) {
        return chunk_in_box(x) && chunk_in_box(x + 8) && chunk_in_box(x + 16) && chunk_in_box(x + 24);
    };
#endif

    for (int s = 0; s < n_spans; ++s) {
        const int xe = span_x1[s];
        int x = span_x0[s];
        OpenRun o;
        auto pixel = [&](int px) { classify_pixel<kRef>(line, px, o, runs, n); };
        auto close = [&](int x_end) { close_run(o, x_end, runs, n); };

        // Scalar head up to an even pixel.
        if (x & 1) pixel(x++);
        while (x <= xe) {
            if (T > 0) {
                // Fast path: skip whole chunks of in-box pairs. Their pixels are background, except possibly the
                // last (odd) one, whose interpolated chroma also depends on the next pair: it is re-examined.
                const int xs = x;
                while (x + 31 <= xe && chunk4_in_box(x)) x += 32;
                while (x + 7 <= xe && chunk_in_box(x)) x += 8;
                if (x != xs) {
                    close(xs - 1);
                    stats_.fast_path_pixels += static_cast<uint32_t>(x - xs - 1);
                    pixel(x - 1);
                    continue;
                }
            }
            const int stop = std::min(x + 7, xe);
            for (; x <= stop; ++x) pixel(x);
        }
        close(xe);
    }
    n_runs_[cur_buf_] = n;
    stats_.runs += static_cast<uint32_t>(n);
    stats_.max_runs_per_line = std::max(stats_.max_runs_per_line, static_cast<uint32_t>(n));
}

// Chunks of the AVX2 weights: eight pixels from an even x0; their chroma reads reach 24 bytes past pixel x0, and
// the last chunk must not hold the line's last pixel (its odd chroma has no right neighbour).
constexpr int kSimdChunkMaxX = static_cast<int>(kActivePixelsPerLine) - 16;

#if defined(EYESIM_FPGA_AVX2)
// weight_at's residual before the projection for eight pixels from x0 (even): 64·(Cb×2, Cr×2) of each pixel (c2,
// 16-bit halves) minus the tracked background interpolated at it. Each pixel's cell and weight come from the
// cell_lerp table; the cells' (Cb, Cr) pairs from eight consecutive cells (the first pixel's cell is the smallest).
__attribute__((target("avx2"))) inline __m256i bg_residual8(__m256i c2, int x0, const int16_t* bg_q4) {
    const __m256i e = _mm256_cvtepu16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(kCellLerp.data() + x0)));
    const __m256i f = _mm256_and_si256(e, _mm256_set1_epi32(kBgCellPixels - 1));
    const int jb = kCellLerp[static_cast<size_t>(x0)] >> 3;
    const __m256i cells = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(bg_q4 + 2 * jb));
    const __m256i rel = _mm256_sub_epi32(_mm256_srli_epi32(e, 3), _mm256_set1_epi32(jb));
    const __m256i g0 = _mm256_permutevar8x32_epi32(cells, rel);
    const __m256i g1 = _mm256_permutevar8x32_epi32(cells, _mm256_add_epi32(rel, _mm256_set1_epi32(1)));
    const __m256i nf = _mm256_sub_epi32(_mm256_set1_epi32(kBgCellPixels), f);
    const __m256i bg = _mm256_add_epi16(_mm256_mullo_epi16(g0, _mm256_or_si256(nf, _mm256_slli_epi32(nf, 16))),
                                        _mm256_mullo_epi16(g1, _mm256_or_si256(f, _mm256_slli_epi32(f, 16))));
    return _mm256_sub_epi16(_mm256_slli_epi16(c2, 6), bg);
}

#if !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
// bg_residual8 for sixteen pixels from x0 (AVX-512); the cells past the table's end read as zero (weight 0).
EYESIM_FPGA_AVX512_TARGET inline __m512i bg_residual16(__m512i c2, int x0, const int16_t* bg_q4) {
    const __m512i e = _mm512_cvtepu16_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(kCellLerp.data() + x0)));
    const __m512i f = _mm512_and_si512(e, _mm512_set1_epi32(kBgCellPixels - 1));
    const int jb = kCellLerp[static_cast<size_t>(x0)] >> 3;
    const __mmask16 in_table = static_cast<__mmask16>(jb + 16 <= kBgCells ? 0xFFFFu : (1u << (kBgCells - jb)) - 1);
    const __m512i cells = _mm512_maskz_loadu_epi32(in_table, bg_q4 + 2 * jb);
    const __m512i rel = _mm512_sub_epi32(_mm512_srli_epi32(e, 3), _mm512_set1_epi32(jb));
    const __m512i g0 = _mm512_maskz_permutexvar_epi32(0xFFFF, rel, cells);
    const __m512i g1 = _mm512_maskz_permutexvar_epi32(0xFFFF, _mm512_add_epi32(rel, _mm512_set1_epi32(1)), cells);
    const __m512i nf = _mm512_sub_epi32(_mm512_set1_epi32(kBgCellPixels), f);
    const __m512i bg = _mm512_add_epi16(_mm512_mullo_epi16(g0, _mm512_or_si512(nf, _mm512_slli_epi32(nf, 16))),
                                        _mm512_mullo_epi16(g1, _mm512_or_si512(f, _mm512_slli_epi32(f, 16))));
    return _mm512_sub_epi16(_mm512_slli_epi16(c2, 6), bg);
}

// (Cb×2, Cr×2) of sixteen pixels from an even x0 in 16-bit halves, from `bytes` (the pairs from x0 / 2 on): a
// pixel's own pair plus its own again (even pixel) or the next pair (odd pixel).
EYESIM_FPGA_AVX512_TARGET inline __m512i chroma2_16(__m512i bytes, __m512i lane, __m512i& own) {
    own = _mm512_maskz_permutexvar_epi32(0xFFFF, _mm512_srli_epi32(lane, 1), bytes);
    const __m512i next = _mm512_maskz_permutexvar_epi32(0xFFFF, _mm512_srli_epi32(_mm512_add_epi32(lane, _mm512_set1_epi32(1)), 1), bytes);
    const __m512i chroma = _mm512_set1_epi32(0x00FF00FF);
    return _mm512_add_epi16(_mm512_and_si512(own, chroma), _mm512_and_si512(next, chroma));
}
#if !defined(__clang__)
#pragma GCC diagnostic pop
#endif
#endif

#if defined(EYESIM_FPGA_AVX2)
// Pixels x0..x0+7 (x0 even, x0 <= kSimdChunkMaxX): their classes from the LUT and its luma band (classify_pixel)
// and chroma weights against the tracked background (weight_at with WEIGHT_MODE 1), the same integer arithmetic
// in eight lanes.
__attribute__((target("avx2"))) void Pipeline::chunk_weights(const uint8_t* line, int x0, ChunkOut& out) const {
    const uint8_t* q = line + 2 * x0;
    const __m128i lo = _mm_loadu_si128(reinterpret_cast<const __m128i*>(q));  // pixels x0..x0+7: pairs and lumas
    const __m256i both = _mm256_inserti128_si256(_mm256_castsi128_si256(lo), _mm_loadu_si128(reinterpret_cast<const __m128i*>(q + 8)), 1);
    // Per pixel (16-bit Cb, Cr) of its own pair plus (Cb, Cr) of its own (even pixel) or the next pair (odd):
    // chroma ×2 as the datapath keeps it. Lane 0 holds pixels x0..x0+3, lane 1 x0+4..x0+7 (from byte 8).
    const __m256i own = _mm256_setr_epi8(0, -1, 2, -1, 0, -1, 2, -1, 4, -1, 6, -1, 4, -1, 6, -1,
                                         0, -1, 2, -1, 0, -1, 2, -1, 4, -1, 6, -1, 4, -1, 6, -1);
    const __m256i next = _mm256_setr_epi8(0, -1, 2, -1, 4, -1, 6, -1, 4, -1, 6, -1, 8, -1, 10, -1,
                                          0, -1, 2, -1, 4, -1, 6, -1, 4, -1, 6, -1, 8, -1, 10, -1);
    const __m256i c2 = _mm256_add_epi16(_mm256_shuffle_epi8(both, own), _mm256_shuffle_epi8(both, next));
    const __m256i zero = _mm256_setzero_si256();
    // LUT cell ((cb2 + 1) >> 3, (cr2 + 1) >> 3): the rounded odd-pixel chroma's top kLutChromaBits bits.
    const __m256i r = _mm256_srli_epi16(_mm256_add_epi16(c2, _mm256_set1_epi16(1)), 8 - kLutChromaBits + 1);
    const __m256i idx = _mm256_or_si256(_mm256_slli_epi32(_mm256_and_si256(r, _mm256_set1_epi32(0xFFFF)), kLutChromaBits),
                                        _mm256_srli_epi32(r, 16));
    const __m256i band = _mm256_i32gather_epi32(reinterpret_cast<const int*>(lut_band_.data()), idx, 4);
    const __m256i luma = _mm256_cvtepu8_epi32(
        _mm_shuffle_epi8(lo, _mm_setr_epi8(1, 3, 5, 7, 9, 11, 13, 15, -1, -1, -1, -1, -1, -1, -1, -1)));
    const __m256i byte = _mm256_set1_epi32(0xFF);
    const __m256i outside = _mm256_or_si256(_mm256_cmpgt_epi32(_mm256_and_si256(_mm256_srli_epi32(band, 8), byte), luma),
                                            _mm256_cmpgt_epi32(luma, _mm256_srli_epi32(band, 16)));
    const __m256i c = _mm256_andnot_si256(outside, _mm256_and_si256(band, byte));
    // band_residual: ((64·cb2 − bcb)·dcb + (64·cr2 − bcr)·dcr + 2^15) >> 16, then level, clamp and width.
    const __m256i d = bg_residual8(c2, x0, bg_q4_.data());
    const __m256i dir = _mm256_permutevar8x32_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(dir_pair_.data())), c);
    const __m256i level = _mm256_permutevar8x32_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(level_.data())), c);
    const __m256i v = _mm256_srai_epi32(_mm256_add_epi32(_mm256_madd_epi16(d, dir), _mm256_set1_epi32(1 << 15)), 16);
    __m256i w = _mm256_min_epi32(_mm256_max_epi32(_mm256_sub_epi32(v, level), zero), _mm256_set1_epi32(255));
    w = _mm256_srl_epi32(w, _mm_cvtsi32_si128(8 - params_.weight_bits));
    out.any = _mm256_movemask_epi8(_mm256_cmpeq_epi32(c, zero)) != -1;
    _mm256_store_si256(reinterpret_cast<__m256i*>(out.cls), c);
    _mm256_store_si256(reinterpret_cast<__m256i*>(out.w), w);
    _mm256_zeroupper();
}
#else
void Pipeline::chunk_weights(const uint8_t*, int, ChunkOut&) const {}
#endif

// Sixteen-pixel chunks (AVX-512): x0 + 15 stays off the line's last pixel and the 36-byte read stays in the line.
constexpr int kSimdChunk16MaxX = static_cast<int>(kActivePixelsPerLine) - 24;
// The ring sums over x of a span's free pixels from the sums over offsets o = x - xe the vector weights keep (exact
// integers): sum_p = Σw | Σo₊ << 16 (o₊: pixels of positive weight), Σw·o, Σw·o² and the count of positive weights.
// Inline: an out-of-line call from the AVX-512 code cost ≈ 4 µs a field (measured).
inline void Pipeline::add_offset_sums(RingSums& r, int xe, uint32_t sum_p, uint64_t swo, uint64_t swoo, uint32_t pn,
                                      uint64_t free) {
    const uint64_t sw = sum_p & 0xFFFFu, so = sum_p >> 16, ux = static_cast<uint64_t>(xe);
    r.sw += sw;
    r.swx += swo + ux * sw;
    r.swxx += swoo + 2 * ux * swo + ux * ux * sw;
    r.psx += so + ux * pn;
    r.pn += pn;
    r.count += static_cast<uint32_t>(__builtin_popcountll(free));
}

// Ring spans whose pixels all lie at or before this x take the vector weights: their 36-byte reads stay in the
// line, and none of them holds the line's last pixel (whose odd chroma has no right neighbour).
constexpr int kSimdRingMaxX = static_cast<int>(kActivePixelsPerLine) - 18;

#if defined(EYESIM_FPGA_AVX2)
// GCC 12's AVX-512 headers fill unused lanes from a self-initialised variable, which -Wuninitialized flags.
#if !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
// chunk_weights for pixels x0..x0+15 (x0 even, x0 <= kSimdChunk16MaxX) in sixteen 32-bit lanes: the same integers.
EYESIM_FPGA_AVX512_TARGET void Pipeline::chunk_weights16(const uint8_t* line, int x0, ChunkOut& out) const {
    const __m512i lane = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    const __m512i bytes = _mm512_maskz_loadu_epi8(0xFFFFFFFFFull, line + 2 * x0);  // pairs x0/2 .. x0/2 + 8
    const __m512i byte = _mm512_set1_epi32(0xFF);
    __m512i own;
    const __m512i c2 = chroma2_16(bytes, lane, own);
    // An even pixel's luma is its pair's byte 1, an odd one's byte 3.
    const __m512i luma = _mm512_and_si512(
        _mm512_srlv_epi32(own, _mm512_add_epi32(_mm512_set1_epi32(8), _mm512_slli_epi32(_mm512_and_si512(lane, _mm512_set1_epi32(1)), 4))), byte);
    const __m512i r = _mm512_srli_epi16(_mm512_add_epi16(c2, _mm512_set1_epi16(1)), 8 - kLutChromaBits + 1);
    const __m512i idx = _mm512_or_si512(_mm512_slli_epi32(_mm512_and_si512(r, _mm512_set1_epi32(0xFFFF)), kLutChromaBits),
                                        _mm512_srli_epi32(r, 16));
    const __m512i band = _mm512_i32gather_epi32(idx, lut_band_.data(), 4);
    const __mmask16 outside = _mm512_cmpgt_epi32_mask(_mm512_and_si512(_mm512_srli_epi32(band, 8), byte), luma) |
                              _mm512_cmpgt_epi32_mask(luma, _mm512_srli_epi32(band, 16));
    const __m512i c = _mm512_maskz_mov_epi32(static_cast<__mmask16>(~outside), _mm512_and_si512(band, byte));
    const __m512i d = bg_residual16(c2, x0, bg_q4_.data());
    const __m512i dir = _mm512_maskz_permutexvar_epi32(0xFFFF, c, _mm512_maskz_loadu_epi32(0xFF, dir_pair_.data()));
    const __m512i level = _mm512_maskz_permutexvar_epi32(0xFFFF, c, _mm512_maskz_loadu_epi32(0xFF, level_.data()));
    const __m512i v = _mm512_srai_epi32(_mm512_add_epi32(_mm512_madd_epi16(d, dir), _mm512_set1_epi32(1 << 15)), 16);
    const __m512i w = _mm512_min_epi32(_mm512_max_epi32(_mm512_sub_epi32(v, level), _mm512_setzero_si512()), _mm512_set1_epi32(255));
    out.any = _mm512_test_epi32_mask(c, c) != 0;
    _mm512_store_si512(out.cls, c);
    _mm512_store_si512(out.w, _mm512_srl_epi32(w, _mm_cvtsi32_si128(8 - params_.weight_bits)));
    _mm256_zeroupper();
}

// add_ring_span's weights and sums for the free pixels of a span from xa (bit i of `free`: pixel xa + i; fewer
// than 64 pixels, the last at most kSimdRingMaxX) for class cls: chunk_weights' arithmetic (weight_at with
// WEIGHT_MODE 1) in sixteen 32-bit lanes from the even pixel at or before xa, the same integers.
EYESIM_FPGA_AVX512_TARGET void Pipeline::ring_weights_simd(const uint8_t* line, uint8_t cls, int xa, uint64_t free,
                                                           RingSums& r) const {
    const int xe = xa & ~1;
    uint64_t m = free << (xa - xe);  // bit i: pixel xe + i
    const __m512i zero = _mm512_setzero_si512();
    const __m512i dir = _mm512_set1_epi32(dir_pair_[cls]), level = _mm512_set1_epi32(level_[cls]);
    const __m128i shift = _mm_cvtsi32_si128(8 - params_.weight_bits);
    const __m512i lane = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    // Sums over offsets o = x - xe (< 64), which keep every lane and total within 32 bits: Σw ≤ 16 320,
    // Σ o over positive weights ≤ 4 032 (both in one lane: Σw | Σo << 16), Σw·o ≤ 1 028 160, Σw·o² ≤ 64.8 M.
    __m512i swo = zero, swoo = zero, sp = zero;
    uint32_t pn = 0;
    for (int base = xe; m != 0; base += 16, m >>= 16) {
        const __mmask16 k = static_cast<__mmask16>(m & 0xFFFFu);
        if (k == 0) continue;
        const __m512i bytes = _mm512_maskz_loadu_epi8(0xFFFFFFFFFull, line + 2 * base);  // pairs base/2 .. base/2 + 8
        __m512i own;
        const __m512i d = bg_residual16(chroma2_16(bytes, lane, own), base, bg_q4_.data());
        const __m512i v = _mm512_srai_epi32(_mm512_add_epi32(_mm512_madd_epi16(d, dir), _mm512_set1_epi32(1 << 15)), 16);
        __m512i w = _mm512_min_epi32(_mm512_max_epi32(_mm512_sub_epi32(v, level), zero), _mm512_set1_epi32(255));
        w = _mm512_maskz_mov_epi32(k, _mm512_srl_epi32(w, shift));
        const __m512i o = _mm512_add_epi32(_mm512_set1_epi32(base - xe), lane);
        const __m512i wo = _mm512_mullo_epi32(w, o);
        swo = _mm512_add_epi32(swo, wo);
        swoo = _mm512_add_epi32(swoo, _mm512_mullo_epi32(wo, o));
        const __mmask16 nz = _mm512_mask_cmpneq_epi32_mask(k, w, zero);
        pn += static_cast<uint32_t>(__builtin_popcount(nz));
        sp = _mm512_add_epi32(sp, _mm512_add_epi32(w, _mm512_maskz_slli_epi32(nz, o, 16)));
    }
    add_offset_sums(r, xe, static_cast<uint32_t>(_mm512_reduce_add_epi32(sp)),
                    static_cast<uint32_t>(_mm512_reduce_add_epi32(swo)), static_cast<uint32_t>(_mm512_reduce_add_epi32(swoo)),
                    pn, free);
    _mm256_zeroupper();
}
#if !defined(__clang__)
#pragma GCC diagnostic pop
#endif

// ring_weights_simd in eight lanes (AVX2): the same integers. Its 32-byte reads from pixel base (<= kSimdRingMaxX)
// stay in the line, and the eight cells it reads from bg_q4_ stay in its padding.
__attribute__((target("avx2"))) void Pipeline::ring_weights_avx2(const uint8_t* line, uint8_t cls, int xa, uint64_t free,
                                                                RingSums& r) const {
    const int xe = xa & ~1;
    uint64_t m = free << (xa - xe);  // bit i: pixel xe + i
    const __m256i zero = _mm256_setzero_si256();
    const __m256i dir = _mm256_set1_epi32(dir_pair_[cls]), level = _mm256_set1_epi32(level_[cls]);
    const __m128i shift = _mm_cvtsi32_si128(8 - params_.weight_bits);
    const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    const __m256i bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
    const __m256i own_pair = _mm256_srli_epi32(lane, 1), next_pair = _mm256_srli_epi32(_mm256_add_epi32(lane, _mm256_set1_epi32(1)), 1);
    const __m256i chroma = _mm256_set1_epi32(0x00FF00FF);
    __m256i swo = zero, swoo = zero, sp = zero;  // as in ring_weights_simd
    uint32_t pn = 0;
    for (int base = xe; m != 0; base += 8, m >>= 8) {
        const int k = static_cast<int>(m & 0xFFu);
        if (k == 0) continue;
        const __m256i sel = _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(k), bit), bit);
        const __m256i bytes = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(line + 2 * base));
        const __m256i c2 = _mm256_add_epi16(_mm256_and_si256(_mm256_permutevar8x32_epi32(bytes, own_pair), chroma),
                                            _mm256_and_si256(_mm256_permutevar8x32_epi32(bytes, next_pair), chroma));
        const __m256i d = bg_residual8(c2, base, bg_q4_.data());
        const __m256i v = _mm256_srai_epi32(_mm256_add_epi32(_mm256_madd_epi16(d, dir), _mm256_set1_epi32(1 << 15)), 16);
        __m256i w = _mm256_min_epi32(_mm256_max_epi32(_mm256_sub_epi32(v, level), zero), _mm256_set1_epi32(255));
        w = _mm256_and_si256(sel, _mm256_srl_epi32(w, shift));
        const __m256i o = _mm256_add_epi32(_mm256_set1_epi32(base - xe), lane);
        const __m256i wo = _mm256_mullo_epi32(w, o);
        swo = _mm256_add_epi32(swo, wo);
        swoo = _mm256_add_epi32(swoo, _mm256_mullo_epi32(wo, o));
        const __m256i nz = _mm256_andnot_si256(_mm256_cmpeq_epi32(w, zero), sel);
        pn += static_cast<uint32_t>(__builtin_popcount(_mm256_movemask_ps(_mm256_castsi256_ps(nz))));
        sp = _mm256_add_epi32(sp, _mm256_add_epi32(w, _mm256_slli_epi32(_mm256_and_si256(nz, o), 16)));
    }
    auto total = [](__m256i u) __attribute__((target("avx2"))) {  // the eight 32-bit lanes, summed (mod 2^32)
        __m128i t = _mm_add_epi32(_mm256_castsi256_si128(u), _mm256_extracti128_si256(u, 1));
        t = _mm_add_epi32(t, _mm_shuffle_epi32(t, _MM_SHUFFLE(1, 0, 3, 2)));
        t = _mm_add_epi32(t, _mm_shuffle_epi32(t, _MM_SHUFFLE(2, 3, 0, 1)));
        return static_cast<uint32_t>(_mm_cvtsi128_si32(t));
    };
    add_offset_sums(r, xe, total(sp), total(swo), total(swoo), pn, free);
    _mm256_zeroupper();
}
#else
void Pipeline::chunk_weights16(const uint8_t*, int, ChunkOut&) const {}
void Pipeline::ring_weights_simd(const uint8_t*, uint8_t, int, uint64_t, RingSums&) const {}
void Pipeline::ring_weights_avx2(const uint8_t*, uint8_t, int, uint64_t, RingSums&) const {}
#endif

// classify_pixel over [x0, x1] with the classes and weights of AVX2 chunks (the line's last pixels one by one).
void Pipeline::classify_span_simd(const uint8_t* line, int x0, int x1, Run* runs, int& n) {
    OpenRun o;
    ChunkOut c;
    int x = x0;
    if (x & 1) classify_pixel<false>(line, x++, o, runs, n);  // a span's odd first pixel: then whole cells
    while (x <= x1) {
        const int xe = x & ~1;
        if (xe > kSimdChunkMaxX) {
            for (; x <= x1; ++x) classify_pixel<false>(line, x, o, runs, n);
            break;
        }
        int last = xe + 7;
        if (simd16_ && xe <= kSimdChunk16MaxX && x1 > xe + 7) {  // sixteen at a time (AVX-512)
            chunk_weights16(line, xe, c);
            last = xe + 15;
        } else {
            chunk_weights(line, xe, c);
        }
        if (c.any == 0 && o.cls == 0) {  // background pixels only and no run open: nothing to extend or add
            x = std::min(x1, last) + 1;
            continue;
        }
        for (const int end = std::min(x1, last); x <= end; ++x)
            run_pixel(o, static_cast<uint8_t>(c.cls[x - xe]), static_cast<uint32_t>(c.w[x - xe]), x, runs, n);
    }
    close_run(o, x1, runs, n);
}

// The fast line path (whole field, fast path on): one scan gives every 8-px cell's chroma sums and whether any of
// its samples lies outside the grey box. A cell inside the box holds only background pixels, except possibly its
// last (odd) pixel, whose chroma is interpolated with the next cell's first pair. So only the pixels of out-of-box
// cells and the last pixel before each are classified, one by one; everything else is background by construction.
void Pipeline::classify_line_cells(const uint8_t* line) {
    uint64_t out[2];
    scan_(line, fast_half_width_, cell_sums_[cur_buf_].data(), out);
    classify_cells(line, out);
}

// classify_line_cells after its line scan: `out` has a bit per out-of-box cell.
void Pipeline::classify_cells(const uint8_t* line, const uint64_t* out) {
    Run* runs = runs_[cur_buf_].data();
    int n = 0;
    uint32_t examined = 0;
    auto classify_span = [&](int x0, int x1) {
        if (simd_weights_) {
            classify_span_simd(line, x0, x1, runs, n);
        } else {
            OpenRun o;
            for (int x = x0; x <= x1; ++x) classify_pixel<false>(line, x, o, runs, n);
            close_run(o, x1, runs, n);
        }
        examined += static_cast<uint32_t>(x1 - x0 + 1);
    };
    int s0 = -1, s1 = -1;  // span being collected
    for (int w = 0; w < 2; ++w) {
        for (uint64_t bits = out[w]; bits != 0; bits &= bits - 1) {
            const int j = 64 * w + __builtin_ctzll(bits);
            const int x0 = std::max(0, kBgCellPixels * j - 1), x1 = kBgCellPixels * j + kBgCellPixels - 1;
            if (s0 >= 0 && x0 <= s1 + 1) {
                s1 = x1;
                continue;
            }
            if (s0 >= 0) classify_span(s0, s1);
            s0 = x0;
            s1 = x1;
        }
    }
    if (s0 >= 0) classify_span(s0, s1);
    stats_.fast_path_pixels += static_cast<uint32_t>(kActivePixelsPerLine) - examined;
    n_runs_[cur_buf_] = n;
    stats_.runs += static_cast<uint32_t>(n);
    stats_.max_runs_per_line = std::max(stats_.max_runs_per_line, static_cast<uint32_t>(n));
}

// Spans of line y the datapath processes: the whole line, or the union of the ROI windows containing it, sorted
// and merged. Returns their number.
int Pipeline::processed_spans(int y, uint16_t* x0, uint16_t* x1) const {
    int n_spans = 0;
    if (params_.roi_enable == 0) {
        x0[0] = 0;
        x1[0] = kActivePixelsPerLine - 1;
        n_spans = 1;
    } else {
        for (int w = 0; w < kNumRoiWindows; ++w) {
            if (!(params_.roi_enable & (1u << w)) || y < params_.roi_y0[w] || y > params_.roi_y1[w]) continue;
            int i = n_spans++;  // insertion sort by x0
            while (i > 0 && x0[i - 1] > params_.roi_x0[w]) {
                x0[i] = x0[i - 1];
                x1[i] = x1[i - 1];
                --i;
            }
            x0[i] = params_.roi_x0[w];
            x1[i] = params_.roi_x1[w];
        }
        int m = 0;  // merge overlapping or touching spans
        for (int i = 0; i < n_spans; ++i) {
            if (m > 0 && x0[i] <= x1[m - 1] + 1) {
                x1[m - 1] = std::max(x1[m - 1], x1[i]);
            } else {
                x0[m] = x0[i];
                x1[m] = x1[i];
                ++m;
            }
        }
        n_spans = m;
    }

    return n_spans;
}

// Pixels of the line the background learns from (the previous one) within kBgHoldColumns of a classified pixel on
// it or the lines above and below; `any` is nonzero when there is one.
void Pipeline::background_hold_mask(std::array<uint64_t, kMaskWords>& near, uint64_t& any) const {
    const std::array<uint64_t, kMaskWords>& a = occupied_[cur_buf_];
    const std::array<uint64_t, kMaskWords>& b = occupied_[cur_buf_ ^ 1];
    std::array<uint64_t, kMaskWords> m;
    any = 0;
    const uint64_t older = n_runs_older_ != 0 ? ~0ull : 0;  // the older copy is stale when its line had no run
    for (size_t i = 0; i < static_cast<size_t>(kMaskWords); ++i) {
        m[i] = a[i] | b[i] | (occupied_older_[i] & older);
        any |= m[i];
    }
    if (any == 0) {  // nothing classified on the three lines (most lines)
        near.fill(0);
        return;
    }
    for (int i = 0; i < kMaskWords; ++i) {  // m dilated by kBgHoldColumns (nothing to dilate on most lines)
        const size_t u = static_cast<size_t>(i);
        uint64_t v = m[u];
        for (int d = 1; any != 0 && d <= kBgHoldColumns; ++d) {
            v |= m[u] << d | m[u] >> d;
            if (i > 0) v |= m[u - 1] >> (64 - d);
            if (i + 1 < kMaskWords) v |= m[u + 1] << (64 - d);
        }
        near[u] = v;
    }
}

// The background update of update_background on the fast line path: the same arithmetic on the previous line's
// cell sums kept from its line scan (whole field, no floating reference), so the line is not read again. Every
// cell steps at once in 16-bit lanes; held cells are then put back and unseeded ones seeded, one by one.
void Pipeline::update_background_cells() {
    const uint32_t* sums = cell_sums_[cur_buf_ ^ 1].data();  // the previous line's
    int16_t* bg = bg_q4_.data();
    const int n = params_.bg_track_shift;
    // Held cells: those near a run of the three lines, from the cell masks the runs set (the cell-level form of
    // background_hold_mask).
    std::array<uint64_t, kCellWords> held;
    uint64_t any = 0;
    const uint64_t older = n_runs_older_ != 0 ? ~0ull : 0;  // the older copy is stale when its line had no run
    for (size_t w = 0; w < static_cast<size_t>(kCellWords); ++w) {
        held[w] = hold_cells_[0][w] | hold_cells_[1][w] | (hold_cells_older_[w] & older);
        any |= held[w];
    }
    if (bg_all_seeded_ && any == 0) {  // most lines: every cell steps
        bg_step_(bg, sums, n);
        return;
    }
#if defined(EYESIM_FPGA_AVX2)
    if (bg_all_seeded_ && scan_isa_ == ScanIsa::kAvx512) {  // every cell steps but the held ones, by lane mask
        static_assert(kCellWords == 2 && 64 % 16 == 0);
        bg_step_held_avx512(bg, sums, n, held.data());
        return;
    }
    if (bg_all_seeded_ && scan_isa_ == ScanIsa::kAvx2) {  // the same by a blend
        bg_step_held_avx2(bg, sums, n, held.data());
        return;
    }
#endif
    auto is_held = [&](int j) { return ((held[static_cast<size_t>(j >> 6)] >> (j & 63)) & 1) != 0; };
    auto step_cell = [&](int j) { bg_step_cell(bg, sums, j, n); };
    if (!bg_all_seeded_) {  // the field's first lines: cell by cell
        for (int j = 0; j < kBgCells; ++j) {
            if (is_held(j)) continue;
            uint64_t& seeded = bg_seeded_[static_cast<size_t>(j >> 6)];
            const uint64_t bit = 1ull << (j & 63);
            if (seeded & bit) {
                step_cell(j);
                continue;
            }
            seeded |= bit;
            bg[2 * j] = static_cast<int16_t>((sums[j] & 0xFFFFu) << (4 - kBgCellLog2));
            bg[2 * j + 1] = static_cast<int16_t>((sums[j] >> 16) << (4 - kBgCellLog2));
        }
        bool all = true;
        for (int w = 0; w < kBgCells / 64; ++w) all = all && bg_seeded_[static_cast<size_t>(w)] == ~0ull;
        bg_all_seeded_ = all && (bg_seeded_[kBgCells / 64] | ~((1ull << (kBgCells % 64)) - 1)) == ~0ull;
        return;
    }
    // Held cells' values, restored after the vector step.
    int n_held = 0;
    std::array<uint16_t, kBgCells> held_j;
    std::array<uint32_t, kBgCells> held_v;
    for (int w = 0; w < kCellWords; ++w)
        for (uint64_t v = held[static_cast<size_t>(w)]; v != 0; v &= v - 1) {
            const int j = 64 * w + __builtin_ctzll(v);
            held_j[static_cast<size_t>(n_held)] = static_cast<uint16_t>(j);
            std::memcpy(&held_v[static_cast<size_t>(n_held++)], bg + 2 * j, 4);
        }
    bg_step_(bg, sums, n);
    for (int h = 0; h < n_held; ++h)
        std::memcpy(bg + 2 * held_j[static_cast<size_t>(h)], &held_v[static_cast<size_t>(h)], 4);
}

// Tracks the background chroma per 8-pixel cell from line y (called once line y + 1 is labelled): a cell with a
// pixel within kBgHoldColumns of a classified pixel on line y - 1, y or y + 1 holds its value; the others move
// towards the mean chroma of their four pairs by 2^-n of the difference (the first sample of a field seeds the
// cell). Only cells wholly inside a processed span (ROI) learn.
void Pipeline::update_background(const uint8_t* line, int y) {
    uint16_t sx0[kNumRoiWindows + 1], sx1[kNumRoiWindows + 1];
    const int n_spans = processed_spans(y, sx0, sx1);
    if (n_spans == 0) return;  // outside every ROI window
    std::array<uint64_t, kMaskWords> near;
    uint64_t any = 0;
    background_hold_mask(near, any);
    const int n = params_.bg_track_shift;
    const int half = 1 << (n - 1);
    const double gain = 1.0 / static_cast<double>(1 << n);
    constexpr int kCellPx = 2 * kBgCellPairs;
    constexpr uint64_t kCellBits = (1ull << kCellPx) - 1;
    auto update_cell = [&](int j) {
        const int x = kCellPx * j;
        if ((near[static_cast<size_t>(x >> 6)] >> (x & 63)) & kCellBits) return;
        int scb = 0, scr = 0;
        for (int k = kBgCellPairs * j; k < kBgCellPairs * (j + 1); ++k) {
            scb += line[4 * k];
            scr += line[4 * k + 2];
        }
        const size_t i = static_cast<size_t>(2 * j);
        const int mcb = scb << (4 - kBgCellLog2), mcr = scr << (4 - kBgCellLog2);  // cell mean ×16
        const double rcb = scb / static_cast<double>(kBgCellPairs), rcr = scr / static_cast<double>(kBgCellPairs);
        uint64_t& seeded = bg_seeded_[static_cast<size_t>(j >> 6)];
        const uint64_t bit = 1ull << (j & 63);
        if (!(seeded & bit)) {  // first sample of the field: taken as it is
            seeded |= bit;
            bg_q4_[i] = static_cast<int16_t>(mcb);
            bg_q4_[i + 1] = static_cast<int16_t>(mcr);
            bg_ref_[i] = rcb;
            bg_ref_[i + 1] = rcr;
            return;
        }
        bg_q4_[i] = static_cast<int16_t>(bg_q4_[i] + ((mcb - bg_q4_[i] + half) >> n));
        bg_q4_[i + 1] = static_cast<int16_t>(bg_q4_[i + 1] + ((mcr - bg_q4_[i + 1] + half) >> n));
        if (config_.float_reference) {
            bg_ref_[i] += (rcb - bg_ref_[i]) * gain;
            bg_ref_[i + 1] += (rcr - bg_ref_[i + 1]) * gain;
        }
    };
#if defined(__SSE2__)
    // Four cells (32 pixels, 64 bytes) at once when none is held or unseeded: the same integer arithmetic in
    // 16-bit lanes (Cb, Cr of four cells), bit-identical to update_cell.
    const __m128i low_bytes = _mm_set1_epi16(0x00FF);
    const __m128i v_half = _mm_set1_epi16(static_cast<short>(half));
    const __m128i v_shift = _mm_cvtsi32_si128(n);
    auto update_group = [&](int j) {
        const __m128i* p = reinterpret_cast<const __m128i*>(line + 4 * kBgCellPairs * j);
        const __m128i a0 = _mm_and_si128(_mm_loadu_si128(p), low_bytes);  // Cb, Cr of cell j's four pairs
        const __m128i a1 = _mm_and_si128(_mm_loadu_si128(p + 1), low_bytes);
        const __m128i a2 = _mm_and_si128(_mm_loadu_si128(p + 2), low_bytes);
        const __m128i a3 = _mm_and_si128(_mm_loadu_si128(p + 3), low_bytes);
        // Halves added: per cell two (Cb, Cr) partial sums, then the partials of the four cells added pairwise.
        const __m128i u = _mm_add_epi16(_mm_unpacklo_epi64(a0, a1), _mm_unpackhi_epi64(a0, a1));
        const __m128i v = _mm_add_epi16(_mm_unpacklo_epi64(a2, a3), _mm_unpackhi_epi64(a2, a3));
        const __m128 uf = _mm_castsi128_ps(u), vf = _mm_castsi128_ps(v);
        const __m128i sums = _mm_add_epi16(_mm_castps_si128(_mm_shuffle_ps(uf, vf, _MM_SHUFFLE(2, 0, 2, 0))),
                                           _mm_castps_si128(_mm_shuffle_ps(uf, vf, _MM_SHUFFLE(3, 1, 3, 1))));
        const __m128i mean16 = _mm_slli_epi16(sums, 4 - kBgCellLog2);
        __m128i* bgp = reinterpret_cast<__m128i*>(bg_q4_.data() + 2 * j);
        const __m128i bgv = _mm_loadu_si128(bgp);
        const __m128i step = _mm_sra_epi16(_mm_add_epi16(_mm_sub_epi16(mean16, bgv), v_half), v_shift);
        _mm_storeu_si128(bgp, _mm_add_epi16(bgv, step));
    };
#endif
#if defined(__SSE2__)
    // The common line: no classified pixel on the three lines, no ROI, every cell seeded.
    if (any == 0 && params_.roi_enable == 0 && !config_.float_reference && bg_all_seeded_) {
        int j = 0;
        for (; j + 4 <= kBgCells; j += 4) update_group(j);
        for (; j < kBgCells; ++j) update_cell(j);
        return;
    }
#endif
    for (int s = 0; s < n_spans; ++s) {
        // Cells wholly inside the span.
        int j = (sx0[s] + kCellPx - 1) / kCellPx;
        const int j_end = (sx1[s] + 1) / kCellPx;  // exclusive
        while (j < j_end) {
#if defined(__SSE2__)
            if ((j & 3) == 0 && j + 4 <= j_end && !config_.float_reference) {
                const int x = kCellPx * j;
                const bool free = ((near[static_cast<size_t>(x >> 6)] >> (x & 63)) & 0xFFFFFFFFull) == 0;
                const bool seeded = ((bg_seeded_[static_cast<size_t>(j >> 6)] >> (j & 63)) & 0xFull) == 0xFull;
                if (free && seeded) {
                    update_group(j);
                    j += 4;
                    continue;
                }
            }
#endif
            update_cell(j++);
        }
    }
    bool all = true;
    for (int w = 0; w < kBgCells / 64; ++w) all = all && bg_seeded_[static_cast<size_t>(w)] == ~0ull;
    bg_all_seeded_ = all && (bg_seeded_[kBgCells / 64] | ~((1ull << (kBgCells % 64)) - 1)) == ~0ull;
}

bool Pipeline::in_roi(int x, int y) const {
    if (params_.roi_enable == 0) return true;
    for (int w = 0; w < kNumRoiWindows; ++w)
        if ((params_.roi_enable & (1u << w)) && x >= params_.roi_x0[w] && x <= params_.roi_x1[w] &&
            y >= params_.roi_y0[w] && y <= params_.roi_y1[w])
            return true;
    return false;
}

// Chroma ×2 of pixel x from its pair q: twice the pair's own, or an odd pixel's sum with the next pair's (the line's
// last pixel: twice its own); no branch on the parity, which has no pattern on ring pixels.
static inline void chroma2_at(const uint8_t* q, int x, int& cb2, int& cr2) {
    const size_t next = ((x & 1) != 0 && (x >> 1) < kPairs - 1) ? 4 : 0;
    cb2 = q[0] + q[next];
    cr2 = q[2] + q[2 + next];
}

// Adds background pixel (x, y) of `line` to blob `root` unless it is classified, already claimed or outside the
// ROI. Uses the line masks of buffer cur_buf_ (the caller selects the line).
void Pipeline::add_ring_pixel(uint16_t root, const uint8_t* line, int x, int y) {
    const uint64_t bit = 1ull << (x & 63);
    uint64_t& claimed = claimed_[cur_buf_][static_cast<size_t>(x >> 6)];
    if ((occupied_[cur_buf_][static_cast<size_t>(x >> 6)] & bit) || (claimed & bit) || !in_roi(x, y)) return;
    claimed |= bit;
    claimed_dirty_[cur_buf_] = true;
    Slot& s = slots_[root];
    const int k = x >> 1;
    const uint8_t* q = line + 4 * k;
    int cb2, cr2;
    chroma2_at(q, x, cb2, cr2);
    const int luma = q[1 + 2 * (x & 1)];
    const uint64_t w = weight_at(s.cls, luma, cb2, cr2, x);
    const uint64_t ux = static_cast<uint64_t>(x), uy = static_cast<uint64_t>(y);
    s.sw += w;
    s.swx += w * ux;
    s.swy += w * uy;
    s.swxx += w * ux * ux;
    s.swyy += w * uy * uy;
    s.swxy += w * ux * uy;
    if (w != 0) {
        ++s.pn;
        s.psx += ux;
    }
    if (config_.float_reference) {
        const double wr = weight_reference_at(s.cls, luma, 0.5 * cb2, 0.5 * cr2, x);
        s.rw += wr;
        s.rwx += wr * x;
        s.rwy += wr * y;
    }
    ++stats_.ring_pixels;
}

// add_ring_pixel for every pixel of [xa, xb] on the fast line path (no ROI, no floating reference): the free
// pixels (neither classified nor claimed) are found word by word from the line masks, their weights summed and
// added to the blob once (integer sums: the same totals).
__attribute__((always_inline)) inline void Pipeline::add_ring_span(uint16_t root, const uint8_t* line, int xa, int xb,
                                                                  int y) {
    uint64_t* occ = occupied_[cur_buf_].data();
    uint64_t* clm = claimed_[cur_buf_].data();
    uint64_t sw = 0, swx = 0, swxx = 0, psx = 0;
    uint32_t count = 0, pn = 0;
    const uint8_t cls = slots_[root].cls;
    auto add_pixel = [&](int x) {
        const int k = x >> 1;
        const uint8_t* q = line + 4 * k;
        int cb2, cr2;
        chroma2_at(q, x, cb2, cr2);
        const int luma = q[1 + 2 * (x & 1)];
        const uint64_t wt = weight_at(cls, luma, cb2, cr2, x);
        const uint64_t ux = static_cast<uint64_t>(x);
        sw += wt;
        swx += wt * ux;
        swxx += wt * ux * ux;
        pn += wt != 0;
        psx += wt != 0 ? ux : 0;
        ++count;
    };
    if (xb - xa < 64) {
        // A span within 64 pixels (all but very wide runs): its free pixels from a two-word window, claimed
        // without a branch per word; a span with none (most spans of a blob's inner lines) ends there.
        const size_t w0 = static_cast<size_t>(xa >> 6);
        const int sh = xa & 63;
        const uint64_t lo = occ[w0] | clm[w0], hi = occ[w0 + 1] | clm[w0 + 1];
        const uint64_t taken = lo >> sh | (hi << 1) << (63 - sh);  // bit i: pixel xa + i
        const uint64_t free = ~taken & (~0ull >> (63 - (xb - xa)));
        clm[w0] |= free << sh;
        clm[w0 + 1] |= (free >> 1) >> (63 - sh);
        if (free == 0) return;
        if (simd_weights_ && xb <= kSimdRingMaxX && xb - xa < 63) {
            RingSums r;
            if (simd16_)
                ring_weights_simd(line, cls, xa, free, r);
            else
                ring_weights_avx2(line, cls, xa, free, r);
            sw = r.sw, swx = r.swx, swxx = r.swxx, psx = r.psx, count = r.count, pn = r.pn;
        } else {
            for (uint64_t f = free; f != 0; f &= f - 1) add_pixel(xa + __builtin_ctzll(f));
        }
    } else {
        for (int w = xa >> 6; w <= xb >> 6; ++w) {
            uint64_t range = ~0ull;
            if (w == xa >> 6) range &= ~0ull << (xa & 63);
            if (w == xb >> 6 && (xb & 63) != 63) range &= (1ull << ((xb & 63) + 1)) - 1;
            uint64_t free = range & ~occ[static_cast<size_t>(w)] & ~clm[static_cast<size_t>(w)];
            if (free == 0) continue;
            clm[static_cast<size_t>(w)] |= free;
            for (; free != 0; free &= free - 1) add_pixel(64 * w + __builtin_ctzll(free));
        }
        if (count == 0) return;
    }
    claimed_dirty_[cur_buf_] = true;
    Slot& s = slots_[root];
    const uint64_t uy = static_cast<uint64_t>(y);
    s.sw += sw;
    s.swx += swx;
    s.swy += sw * uy;
    s.swxx += swxx;
    s.swyy += sw * uy * uy;
    s.swxy += swx * uy;
    s.pn += pn;
    s.psx += psx;
    stats_.ring_pixels += count;
}

// BG_OFFSET: adds the background residual of every chroma sample (even pixel) of [xa, xb] on line y that is not
// classified and inside the ROI to blob `root`'s band sums; the same state of the background as the line's weights.
void Pipeline::add_band_span(uint16_t root, const uint8_t* line, int xa, int xb, int y) {
    Slot& s = slots_[root];
    const uint64_t* occ = occupied_[cur_buf_].data();
    for (int x = xa + (xa & 1); x <= xb; x += 2) {
        if (((occ[static_cast<size_t>(x >> 6)] >> (x & 63)) & 1) || !in_roi(x, y)) continue;
        const uint8_t* q = line + 2 * x;
        s.band_r += background_residual_at(s.cls, 2 * q[0], 2 * q[2], x);
        ++s.band_n;
    }
}

uint16_t Pipeline::find_root(uint16_t s) {
    while (slots_[s].parent != s) {
        slots_[s].parent = slots_[slots_[s].parent].parent;  // path halving
        s = slots_[s].parent;
    }
    return s;
}

uint16_t Pipeline::alloc_slot() {
    if (n_free_ == 0) return kNoLabel;
    const uint16_t s = free_list_[--n_free_];
    ++n_live_;
    stats_.max_table_occupancy = std::max(stats_.max_table_occupancy, static_cast<uint32_t>(n_live_));
    return s;
}

void Pipeline::merge_into(uint16_t dst, uint16_t src) {
    Slot& d = slots_[dst];
    Slot& s = slots_[src];
    d.flags |= s.flags;
    d.x_min = std::min(d.x_min, s.x_min);
    d.x_max = std::max(d.x_max, s.x_max);
    d.y_min = std::min(d.y_min, s.y_min);
    d.y_max = std::max(d.y_max, s.y_max);
    if (s.seen_this_line && !d.seen_this_line) {
        d.seen_this_line = true;
        d.last_y = s.last_y;
        d.last_line_x_max = s.last_line_x_max;
    } else if (s.seen_this_line == d.seen_this_line) {
        if (s.last_y > d.last_y) {
            d.last_y = s.last_y;
            d.last_line_x_max = s.last_line_x_max;
        } else if (s.last_y == d.last_y) {
            d.last_line_x_max = std::max(d.last_line_x_max, s.last_line_x_max);
        }
    }
    d.area += s.area;
    d.sw += s.sw;
    d.swx += s.swx;
    d.swy += s.swy;
    d.swxx += s.swxx;
    d.swyy += s.swyy;
    d.swxy += s.swxy;
    d.pn += s.pn;
    d.psx += s.psx;
    d.band_r += s.band_r;
    d.band_n += s.band_n;
    d.rw += s.rw;
    d.rwx += s.rwx;
    d.rwy += s.rwy;
    d.flags |= kBlobMerged;
    s.parent = dst;
    to_free_[n_to_free_++] = src;
}

// Connects the current line's runs (line y) to the previous line's, then completes every blob of the previous
// line that no run continued. With end_of_field the current line is empty and y is the field's last line.
void Pipeline::label_line(int y, bool end_of_field, const uint8_t* line) {
    Run* cur = runs_[cur_buf_].data();
    const int n_cur = n_runs_[cur_buf_];
    Run* prev = runs_[cur_buf_ ^ 1].data();
    const int n_prev = n_runs_[cur_buf_ ^ 1];
    const uint16_t yy = static_cast<uint16_t>(y);

    int j = 0;
    for (int i = 0; i < n_cur; ++i) {
        Run& r = cur[i];
        while (j < n_prev && prev[j].x1 + 1 < r.x0) ++j;
        uint16_t label = kNoLabel;
        bool touched_dropped = false;
        for (int k = j; k < n_prev && prev[k].x0 <= r.x1 + 1; ++k) {  // 8-connected overlap
            if (prev[k].cls != r.cls) continue;
            if (prev[k].label == kNoLabel) {
                touched_dropped = true;
                continue;
            }
            const uint16_t root = find_root(prev[k].label);
            if (label == kNoLabel) {
                label = root;
            } else if (root != label) {
                merge_into(label, root);
                ++stats_.merges;
            }
        }
        if (label == kNoLabel) {
            if (touched_dropped) continue;  // the rest of a dropped blob stays dropped
            label = alloc_slot();
            if (label == kNoLabel) {
                ++stats_.table_overflows;
                continue;
            }
            Slot& s = slots_[label];
            s = Slot{};
            s.parent = label;
            s.cls = r.cls;
            s.live = true;
            s.x_min = r.x0;
            s.x_max = r.x1;
            s.y_min = s.y_max = yy;
        } else if (touched_dropped) {
            slots_[label].flags |= kBlobIncomplete;
        }
        Slot& s = slots_[label];
        const uint64_t area = static_cast<uint64_t>(r.x1 - r.x0 + 1);
        s.area += static_cast<uint32_t>(area);
        s.x_min = std::min(s.x_min, r.x0);
        s.x_max = std::max(s.x_max, r.x1);
        s.y_max = yy;
        s.sw += r.sum_w;
        s.swx += r.sum_wx;
        s.swy += static_cast<uint64_t>(r.sum_w) * yy;
        s.swxx += r.sum_wxx;
        s.swyy += static_cast<uint64_t>(r.sum_w) * yy * yy;
        s.swxy += static_cast<uint64_t>(r.sum_wx) * yy;
        s.pn += r.pos_n;
        s.psx += r.pos_sx;
        s.rw += r.ref_w;
        s.rwx += r.ref_wx;
        s.rwy += r.ref_w * y;
        if (!s.seen_this_line) {
            s.seen_this_line = true;
            s.last_y = yy;
            s.last_line_x_max = r.x1;
        } else {
            s.last_line_x_max = std::max(s.last_line_x_max, r.x1);
        }
        r.label = label;
    }

    // Edge ring: background pixels within 2 columns and 1 line of a blob add their weights to its moments (first
    // claim wins). Two columns because 4:2:2 chroma, [1 2 1]-filtered and interpolated, spreads a marker's weight
    // two pixels sideways; the linear weights of those pixels are what makes the weighted x centroid exact. The
    // ring is collected on this line below the previous line's runs and beside this line's runs, and on the
    // previous line above this line's runs, so a blob's ring is complete when the blob is.
    if (params_.edge_ring && params_.weight_mode != 0 && line != nullptr && cells_path_) {
        // The same claims span by span (whole field: no ROI test): only the free pixels of each span are visited.
        const int xmax = static_cast<int>(kActivePixelsPerLine) - 1;
        for (int k = 0; k < n_prev; ++k) {
            if (prev[k].label == kNoLabel) continue;
            add_ring_span(find_root(prev[k].label), line, std::max(0, prev[k].x0 - kRingColumns),
                          std::min(xmax, prev[k].x1 + kRingColumns), y);
        }
        // Beside this line's runs: one span over the run and both sides (the run's own pixels are occupied, so the
        // span's free pixels are the two sides', claimed by the same blob in the same order).
        for (int i = 0; i < n_cur; ++i) {
            if (cur[i].label == kNoLabel) continue;
            add_ring_span(find_root(cur[i].label), line, std::max(0, cur[i].x0 - kRingColumns),
                          std::min(xmax, cur[i].x1 + kRingColumns), y);
        }
        if (prev_line_ != nullptr && y > 0) {
            cur_buf_ ^= 1;  // the previous line's masks
            for (int i = 0; i < n_cur; ++i) {
                if (cur[i].label == kNoLabel) continue;
                add_ring_span(find_root(cur[i].label), prev_line_, std::max(0, cur[i].x0 - kRingColumns),
                              std::min(xmax, cur[i].x1 + kRingColumns), y - 1);
            }
            cur_buf_ ^= 1;
        }
    } else if (params_.edge_ring && params_.weight_mode != 0 && line != nullptr) {
        const int xmax = static_cast<int>(kActivePixelsPerLine) - 1;
        for (int k = 0; k < n_prev; ++k) {
            if (prev[k].label == kNoLabel) continue;
            const uint16_t root = find_root(prev[k].label);
            for (int x = std::max(0, prev[k].x0 - kRingColumns); x <= std::min(xmax, prev[k].x1 + kRingColumns); ++x)
                add_ring_pixel(root, line, x, y);
        }
        for (int i = 0; i < n_cur; ++i) {
            if (cur[i].label == kNoLabel) continue;
            const uint16_t root = find_root(cur[i].label);
            for (int d = 1; d <= kRingColumns; ++d) {
                if (cur[i].x0 - d >= 0) add_ring_pixel(root, line, cur[i].x0 - d, y);
                if (cur[i].x1 + d <= xmax) add_ring_pixel(root, line, cur[i].x1 + d, y);
            }
        }
        if (prev_line_ != nullptr && y > 0) {
            cur_buf_ ^= 1;  // the previous line's masks
            for (int i = 0; i < n_cur; ++i) {
                if (cur[i].label == kNoLabel) continue;
                const uint16_t root = find_root(cur[i].label);
                for (int x = std::max(0, cur[i].x0 - kRingColumns); x <= std::min(xmax, cur[i].x1 + kRingColumns); ++x)
                    add_ring_pixel(root, prev_line_, x, y - 1);
            }
            cur_buf_ ^= 1;
        }
    }

    // BG_OFFSET: the chroma samples kBandNearColumns..kBandFarColumns columns beside each run of this line (not
    // classified on this line) give the blob's band: the mean of their residuals against the tracked background
    // estimates what the background under the blob is off by, on its own lines (emit corrects x with it).
    if (params_.bg_offset && params_.weight_mode == 1 && line != nullptr) {
        const int xmax = static_cast<int>(kActivePixelsPerLine) - 1;
        for (int i = 0; i < n_cur; ++i) {
            if (cur[i].label == kNoLabel) continue;
            const uint16_t root = find_root(cur[i].label);
            if (cur[i].x0 >= kBandNearColumns)
                add_band_span(root, line, std::max(0, cur[i].x0 - kBandFarColumns), cur[i].x0 - kBandNearColumns, y);
            if (cur[i].x1 + kBandNearColumns <= xmax)
                add_band_span(root, line, cur[i].x1 + kBandNearColumns, std::min(xmax, cur[i].x1 + kBandFarColumns), y);
        }
    }

    // Blobs of the previous line that got no run on this line are complete.
    int n_done = 0;
    for (int k = 0; k < n_prev; ++k) {
        if (prev[k].label == kNoLabel) continue;
        const uint16_t root = find_root(prev[k].label);
        Slot& s = slots_[root];
        if (s.seen_this_line || !s.live) continue;
        s.live = false;  // marks it done (once)
        // Decided when the scan of the next line has passed the blob's rightmost pixel on its last line by one.
        const uint32_t decision =
            end_of_field ? active_line_end_cycle(static_cast<uint32_t>(y)) + kPipelineDepthClocks
                         : pixel_cycle(std::min<uint32_t>(s.last_line_x_max + 2u, kActivePixelsPerLine),
                                       static_cast<uint32_t>(y)) +
                               kPipelineDepthClocks;
        int i = n_done++;  // insertion sort by decision cycle
        while (i > 0 && done_cycle_[i - 1] > decision) {
            done_[i] = done_[i - 1];
            done_cycle_[i] = done_cycle_[i - 1];
            --i;
        }
        done_[i] = root;
        done_cycle_[i] = decision;
    }
    for (int i = 0; i < n_cur; ++i) {
        if (cur[i].label == kNoLabel) continue;
        cur[i].label = find_root(cur[i].label);
    }
    for (int i = 0; i < n_to_free_; ++i) {
        slots_[to_free_[i]].live = false;
        free_list_[n_free_++] = to_free_[i];
        --n_live_;
    }
    n_to_free_ = 0;
    for (int i = 0; i < n_done; ++i) {
        emit(done_[i], done_cycle_[i], end_of_field);
        free_list_[n_free_++] = done_[i];
        --n_live_;
    }
    for (int i = 0; i < n_cur; ++i)
        if (cur[i].label != kNoLabel) slots_[cur[i].label].seen_this_line = false;
}

void Pipeline::emit(uint16_t slot, uint32_t decision_cycle, bool end_of_field) {
    const Slot& s = slots_[slot];
    const PipelineParams& p = params_;
    const uint32_t bw = static_cast<uint32_t>(s.x_max - s.x_min + 1), bh = static_cast<uint32_t>(s.y_max - s.y_min + 1);
    bool pass = s.area >= p.min_area_px && s.area <= p.max_area_px;
    if (p.min_fill_q8 != 0) pass = pass && s.area * 256u >= p.min_fill_q8 * bw * bh;
    if (p.max_aspect_q4 != 0) pass = pass && std::max(bw, bh) * 16u <= p.max_aspect_q4 * std::min(bw, bh);
    if (!pass) {
        ++stats_.blobs_filtered;
        return;
    }
    Blob b;
    b.field_counter = field_counter_;
    b.index = next_index_++;
    b.camera = config_.camera;
    b.class_id = s.cls;
    b.parity = parity_;
    b.flags = s.flags;
    if (s.x_min == 0) b.flags |= kBlobTouchesLeft;
    if (s.x_max == kActivePixelsPerLine - 1) b.flags |= kBlobTouchesRight;
    if (s.y_min == 0) b.flags |= kBlobTouchesTop;
    if (s.y_max == kActiveLinesPerField - 1 || end_of_field) b.flags |= kBlobTouchesBottom;
    for (int w = 0; w < kNumRoiWindows; ++w) {
        if (!(p.roi_enable & (1u << w))) continue;
        const bool inside = s.x_min >= p.roi_x0[w] && s.x_max <= p.roi_x1[w] && s.y_min >= p.roi_y0[w] &&
                            s.y_max <= p.roi_y1[w];
        if (inside && ((s.x_min == p.roi_x0[w] && p.roi_x0[w] > 0) ||
                       (s.x_max == p.roi_x1[w] && p.roi_x1[w] < kActivePixelsPerLine - 1) ||
                       (s.y_min == p.roi_y0[w] && p.roi_y0[w] > 0) ||
                       (s.y_max == p.roi_y1[w] && static_cast<int>(p.roi_y1[w]) < last_line_)))
            b.flags |= kBlobClippedByRoi;
    }
    b.area_px = s.area;
    b.x_min = s.x_min;
    b.x_max = s.x_max;
    b.y_min = s.y_min;
    b.y_max = s.y_max;
    b.sum_w = s.sw;
    b.sum_wx = s.swx;
    b.sum_wy = s.swy;
    b.sum_wxx = s.swxx;
    b.sum_wyy = s.swyy;
    b.sum_wxy = s.swxy;
    b.pos_count = s.pn;
    b.pos_sum_x = s.psx;
    b.band_sum_r = static_cast<int32_t>(s.band_r);
    b.band_count = s.band_n;
    // BG_OFFSET: x from the weights less the band's mean residual on every pixel of positive weight (the same
    // divider, operands scaled by the band count): (Σwx·n − Σr·Σx₊) / (Σw·n − Σr·n₊). Kept uncorrected where that
    // would leave no positive weight.
    __extension__ using i128 = __int128;
    const i128 num = static_cast<i128>(s.swx) * s.band_n - static_cast<i128>(s.band_r) * static_cast<i128>(s.psx);
    const i128 den = static_cast<i128>(s.sw) * s.band_n - static_cast<i128>(s.band_r) * s.pn;
    const bool offset = p.bg_offset && p.weight_mode == 1 && s.band_n != 0 && den > 0 && num >= 0;
    if (s.sw != 0) {
        b.cx_q16 = offset ? static_cast<uint32_t>(((num << kCentroidFracBits) + den / 2) / den)
                          : static_cast<uint32_t>(((s.swx << kCentroidFracBits) + s.sw / 2) / s.sw);
        b.cy_q16 = static_cast<uint32_t>(((s.swy << kCentroidFracBits) + s.sw / 2) / s.sw);
    } else {
        b.flags |= kBlobZeroWeight;
        b.cx_q16 = static_cast<uint32_t>(s.x_min + s.x_max) << (kCentroidFracBits - 1);
        b.cy_q16 = static_cast<uint32_t>(s.y_min + s.y_max) << (kCentroidFracBits - 1);
    }
    if (config_.float_reference && s.rw > 0) {
        b.ref_sum_w = s.rw;
        b.ref_cx_px = s.rwx / s.rw;
        b.ref_cy_px = s.rwy / s.rw;
    }
    b.last_pixel_cycle = pixel_cycle(s.last_line_x_max, s.last_y);
    const uint32_t start = std::max(decision_cycle, next_emit_free_cycle_);
    next_emit_free_cycle_ = start + kEmitIntervalClocks;
    b.emit_cycle = start + kDividerLatencyClocks;
    b.latency_cycles = b.emit_cycle - b.last_pixel_cycle;
    stats_.last_emit_cycle = b.emit_cycle;
    deliver(b);
}

void Pipeline::deliver(const Blob& b) {
    if (sink_ != nullptr) {
        sink_(sink_ctx_, b);
        ++stats_.blobs_emitted;
        return;
    }
    if (ring_count_ == kOutputRingCapacity) {
        ++stats_.dropped_blobs;
        return;
    }
    ring_[static_cast<size_t>((ring_head_ + ring_count_) % kOutputRingCapacity)] = b;
    ++ring_count_;
    ++stats_.blobs_emitted;
}

bool Pipeline::pop_blob(Blob& out) {
    if (ring_count_ == 0) return false;
    out = ring_[static_cast<size_t>(ring_head_)];
    ring_head_ = (ring_head_ + 1) % kOutputRingCapacity;
    --ring_count_;
    return true;
}

StorageBits Pipeline::storage_bits() const {
    StorageBits s;
    const uint64_t cap = static_cast<uint64_t>(config_.blob_table_capacity);
    const uint64_t label_bits = bits_for(cap);  // slot index plus "dropped"
    const uint64_t x_bits = bits_for(kActivePixelsPerLine - 1), y_bits = bits_for(kMaxFieldLines - 1);
    s.chroma_lut = (1ull << (2 * kLutChromaBits)) * 3;
    // Per run: x0, x1, class, label (moment sums go straight into the blob table, not into the line buffer).
    s.run_buffers = 2ull * kMaxRunsPerLine * (2 * x_bits + 3 + label_bits);
    // Edge ring: the previous line's 4:2:2 pixels (Y + alternating Cb/Cr = 16 bits) and, for two lines, one
    // occupied and one claimed bit per pixel.
    s.line_buffer = kActivePixelsPerLine * 16ull + 2ull * 2ull * kActivePixelsPerLine;
    // Background tracking: per 8-px cell Cb and Cr in 8.4 fixed point and a seeded bit, and a third line of
    // occupied bits (the hold mask looks at the lines above and below the one it learns from).
    s.line_buffer += static_cast<uint64_t>(kBgCells) * (2 * (8 + kBgFracBits) + 1) + kActivePixelsPerLine;
    // Per slot: parent, class, flags, live, seen, bbox, last line + its rightmost x, area, six moment sums.
    uint64_t slot_bits = label_bits + 3 + 6 + 2 + 2 * x_bits + 2 * y_bits + y_bits + x_bits +
                               bits_for(kActivePixelsPerLine * kMaxFieldLines) + kSumWBits + kSumWxBits +
                               kSumWyBits + kSumWxxBits + kSumWyyBits + kSumWxyBits;
    // BG_OFFSET: positive-weight pixel count and their Σx; band residual sum (signed) and sample count.
    const uint64_t px_count_bits = bits_for(kActivePixelsPerLine * kMaxFieldLines);
    const uint64_t band_n_bits = bits_for(kActivePixelsPerLine / 2 * kMaxFieldLines);
    slot_bits += px_count_bits + kSumWxBits + (band_n_bits + 9) + band_n_bits;
    s.blob_table = cap * slot_bits;
    // Output FIFO entry: class, flags, area, bbox, centroid (26-bit Q10.16 each), Σw, three second moments, cycle.
    const uint64_t fifo_bits = 3 + 6 + bits_for(kActivePixelsPerLine * kMaxFieldLines) + 2 * x_bits + 2 * y_bits + 2 * 26 + kSumWBits + kSumWxxBits +
                               kSumWyyBits + kSumWxyBits + bits_for(kClocksPerField);
    s.output_fifo = kOutputRingCapacity * fifo_bits;
    for (const RegisterInfo& r : register_table()) s.registers += r.width_bits;
    return s;
}

}  // namespace eyesim::fpga
