// Vec16 / Vec16i: the 16-lane float and int32 vectors the kernels compute with (one 16x16 tile
// row, 16 features, 16 points), made of the target's own registers: one AVX-512 register, two AVX
// registers or four SSE / NEON registers. Each ISA variant of the native module (CMakeLists.txt)
// compiles this header with its own target flags, so exactly one register width is chosen:
//   avx512   (x86-64-v4)  1 x 16 lanes
//   avx2     (x86-64-v3)  2 x 8 lanes, AVX2 + FMA
//   baseline (x86-64)     4 x 4 lanes, SSE2 only
//   neon     (aarch64)    4 x 4 lanes
//
// Why not one 64-byte GCC vector type: without AVX-512, GCC expands arithmetic on it into
// register-sized pieces, but lowers comparisons, lane selections (?:, or and/andnot of a
// comparison's mask) and conversions to one scalar branch or insert per lane. Holding the
// registers explicitly keeps every operation below one instruction per register on every target,
// and no target falls back to scalar reductions or divisions (reciprocal() refines the hardware
// estimate instead of dividing).
#pragma once

#include <cstdint>
#include <type_traits>

#if defined(__x86_64__) || defined(_M_X64)
#include <immintrin.h>
#elif defined(__aarch64__)
#include <arm_neon.h>
#else
#error "surgsplat's native kernels target x86-64 and aarch64"
#endif

namespace surgsplat {

// Every vector helper is forced inline: a call passes its 64-byte operands through memory.
#define SURGSPLAT_INLINE inline __attribute__((always_inline))

// Requests the cache line holding `address`. Two ways GCC drops a plain __builtin_prefetch
// without a word: a write prefetch (rw = 1) unless the target has PRFCHW, which x86-64-v3 and v4
// do not include, and any loop whose only effect is prefetching, which it deletes as dead code.
// So this is a read prefetch, also for lines about to be written (a line read into a core's
// cache is written there without a further miss), followed by an empty volatile asm that uses
// the address and keeps it, and its loop, in the program.
SURGSPLAT_INLINE void prefetch(const void* address) {
    __builtin_prefetch(address);
    asm volatile("" : : "r"(address));
}

constexpr int kVecLanes = 16;
#if defined(__AVX512F__)
constexpr int kRegLanes = 16;
#elif defined(__AVX__)
constexpr int kRegLanes = 8;
#else
constexpr int kRegLanes = 4;
#endif
constexpr int kRegs = kVecLanes / kRegLanes;

// N registers of T lanes: a full 16-lane vector (N = kRegs), or the registers R0 .. R0 + N - 1
// of one (part() / set_part(), for work that touches only some of a row's lanes). Arithmetic
// with a scalar broadcasts it; comparisons give a mask, all ones in the lanes where they hold.
template <class T, int N = kRegs>
struct Pack {
    typedef T Reg __attribute__((vector_size(sizeof(T) * kRegLanes)));
    Reg r[N];

    // Register-wise loads and stores of N * kRegLanes values at any alignment. (A memcpy of the
    // whole Pack goes through the stack in pieces narrower than a register: a stalled load.)
    typedef T Unaligned __attribute__((vector_size(sizeof(T) * kRegLanes), aligned(alignof(T)),
                                       may_alias));
    SURGSPLAT_INLINE static Pack load(const T* source) {
        Pack out;
        for (int i = 0; i < N; ++i)
            out.r[i] = *reinterpret_cast<const Unaligned*>(source + i * kRegLanes);
        return out;
    }
    SURGSPLAT_INLINE void store(T* target) const {
        for (int i = 0; i < N; ++i) *reinterpret_cast<Unaligned*>(target + i * kRegLanes) = r[i];
    }

    SURGSPLAT_INLINE T& operator[](int i) { return reinterpret_cast<T*>(r)[i]; }
    SURGSPLAT_INLINE T operator[](int i) const { return reinterpret_cast<const T*>(r)[i]; }

    template <class F>
    SURGSPLAT_INLINE static Pack map(F f, const Pack& a, const Pack& b) {
        Pack out;
        for (int i = 0; i < N; ++i) out.r[i] = f(a.r[i], b.r[i]);
        return out;
    }
    SURGSPLAT_INLINE static Pack all(T value) {
        Pack out;
        for (int i = 0; i < N; ++i) out.r[i] = Reg{} + value;
        return out;
    }

#define SURGSPLAT_PACK_ARITHMETIC(op)                                                      \
    SURGSPLAT_INLINE friend Pack operator op(const Pack& a, const Pack& b) {               \
        return map([](Reg x, Reg y) { return x op y; }, a, b);                            \
    }                                                                                      \
    SURGSPLAT_INLINE friend Pack operator op(const Pack& a, T b) { return a op all(b); }   \
    SURGSPLAT_INLINE friend Pack operator op(T a, const Pack& b) { return all(a) op b; }   \
    SURGSPLAT_INLINE Pack& operator op##=(const Pack& b) { return *this = *this op b; }    \
    SURGSPLAT_INLINE Pack& operator op##=(T b) { return *this = *this op all(b); }
    SURGSPLAT_PACK_ARITHMETIC(+)
    SURGSPLAT_PACK_ARITHMETIC(-)
    SURGSPLAT_PACK_ARITHMETIC(*)
    SURGSPLAT_PACK_ARITHMETIC(&)
    SURGSPLAT_PACK_ARITHMETIC(|)
#undef SURGSPLAT_PACK_ARITHMETIC
    SURGSPLAT_INLINE friend Pack operator-(const Pack& a) { return T(0) - a; }
    SURGSPLAT_INLINE friend Pack operator~(const Pack& a) {
        Pack out;
        for (int i = 0; i < N; ++i) out.r[i] = ~a.r[i];
        return out;
    }
    SURGSPLAT_INLINE friend Pack operator<<(const Pack& a, int bits) {
        Pack out;
        for (int i = 0; i < N; ++i) out.r[i] = a.r[i] << bits;
        return out;
    }

#define SURGSPLAT_PACK_COMPARISON(op)                                                      \
    SURGSPLAT_INLINE friend Pack<int32_t, N> operator op(const Pack& a, const Pack& b) {   \
        Pack<int32_t, N> out;                                                              \
        for (int i = 0; i < N; ++i) out.r[i] = a.r[i] op b.r[i];                           \
        return out;                                                                        \
    }                                                                                      \
    SURGSPLAT_INLINE friend Pack<int32_t, N> operator op(const Pack& a, T b) {             \
        return a op all(b);                                                                \
    }                                                                                      \
    SURGSPLAT_INLINE friend Pack<int32_t, N> operator op(T a, const Pack& b) {             \
        return all(a) op b;                                                                \
    }
    SURGSPLAT_PACK_COMPARISON(<)
    SURGSPLAT_PACK_COMPARISON(<=)
    SURGSPLAT_PACK_COMPARISON(>)
    SURGSPLAT_PACK_COMPARISON(>=)
#undef SURGSPLAT_PACK_COMPARISON
};

typedef Pack<float> Vec16;
typedef Pack<int32_t> Vec16i;

// Registers R0 .. R0 + N - 1 of a vector of M registers, and writing them back.
template <int R0, int N, class T, int M>
SURGSPLAT_INLINE Pack<T, N> part(const Pack<T, M>& x) {
    static_assert(R0 >= 0 && N >= 1 && R0 + N <= M, "registers out of range");
    Pack<T, N> out;
    for (int i = 0; i < N; ++i) out.r[i] = x.r[R0 + i];
    return out;
}
template <int R0, int N, class T, int M>
SURGSPLAT_INLINE void set_part(Pack<T, M>& x, const Pack<T, N>& value) {
    static_assert(R0 >= 0 && N >= 1 && R0 + N <= M, "registers out of range");
    for (int i = 0; i < N; ++i) x.r[R0 + i] = value.r[i];
}

// f(std::integral_constant<int, R0>, std::integral_constant<int, N>) for the registers R0 ..
// R0 + N - 1 = first .. last (0 <= first <= last < M) of a vector of M registers: a run-time
// register range to a compile-time one.
template <int M, int R0 = 0, int N = 1, class F>
SURGSPLAT_INLINE void with_registers(int first, int last, F&& f) {
    if constexpr (R0 + N <= M) {
        if (first == R0 && last == R0 + N - 1)
            f(std::integral_constant<int, R0>{}, std::integral_constant<int, N>{});
        else if constexpr (R0 + N < M)
            with_registers<M, R0, N + 1>(first, last, f);
        else
            with_registers<M, R0 + 1, 1>(first, last, f);
    }
}

// yes where mask (lanes all ones or all zeros) is set, else no.
template <class T, int N>
SURGSPLAT_INLINE Pack<T, N> select(const Pack<int32_t, N>& mask, const Pack<T, N>& yes,
                                   const Pack<T, N>& no) {
    Pack<T, N> out;
    for (int i = 0; i < N; ++i) out.r[i] = mask.r[i] ? yes.r[i] : no.r[i];
    return out;
}

// Lane-wise conversion to int32, rounding toward zero, and back; and the same bits seen as the
// other type.
template <int N>
SURGSPLAT_INLINE Pack<int32_t, N> to_int(const Pack<float, N>& x) {
    Pack<int32_t, N> out;
    for (int i = 0; i < N; ++i) out.r[i] = __builtin_convertvector(x.r[i], Vec16i::Reg);
    return out;
}
template <int N>
SURGSPLAT_INLINE Pack<float, N> to_float(const Pack<int32_t, N>& x) {
    Pack<float, N> out;
    for (int i = 0; i < N; ++i) out.r[i] = __builtin_convertvector(x.r[i], Vec16::Reg);
    return out;
}
template <int N>
SURGSPLAT_INLINE Pack<float, N> bits_as_float(const Pack<int32_t, N>& x) {
    Pack<float, N> out;
    for (int i = 0; i < N; ++i) out.r[i] = reinterpret_cast<Vec16::Reg>(x.r[i]);
    return out;
}

template <int N>
SURGSPLAT_INLINE Pack<int32_t, N> float_bits(const Pack<float, N>& x) {
    Pack<int32_t, N> out;
    for (int i = 0; i < N; ++i) out.r[i] = reinterpret_cast<Vec16i::Reg>(x.r[i]);
    return out;
}

// 2^y lane-wise for y <= 127 (below -125 it gives 2^-125, the smallest power whose products stay
// normal numbers), to within 3e-7 relative: y = n + f with n an integer and |f| <= 1/2,
// 2^f = exp(f ln 2) by its degree-6 Taylor polynomial, n added to the result's exponent bits.
// The rasterizer's compositing loops are bound by the latency of this chain, not by its
// operations, so the polynomial is evaluated in Estrin's scheme (three dependent multiply-adds,
// against Horner's six) and n is read from the rounding sum's bits instead of converted.
// Measured on the imported real clip's Gaussians against exp(x) evaluated the usual way
// (x = -q/2, Horner, times the opacity), one thread, AVX2: forward 16 % and backward 24 %
// faster. The Gaussian-basis kernel (basis/) uses it for both of its exps.
template <int N>
SURGSPLAT_INLINE Pack<float, N> pow2(Pack<float, N> y) {
    y = select(y < -125.0f, Pack<float, N>::all(-125.0f), y);
    const float round_magic = 12582912.0f;  // 1.5 * 2^23: adding it rounds to an integer
    const Pack<float, N> rounded = y + round_magic;  // n in the low bits of the mantissa
    const Pack<float, N> f = y - (rounded - round_magic);
    // c_k = ln(2)^k / k!
    const float c1 = 0.693147180559945f, c2 = 0.240226506959101f, c3 = 0.0555041086648216f,
                c4 = 0.00961812910762848f, c5 = 0.00133335581464284f, c6 = 0.000154035303933816f;
    const Pack<float, N> f2 = f * f;
    const Pack<float, N> low = (1.0f + c1 * f) + f2 * (c2 + c3 * f);
    const Pack<float, N> high = (c4 + c5 * f) + f2 * c6;
    const Pack<float, N> p = low + (f2 * f2) * high;
    const Pack<int32_t, N> n =
        float_bits(rounded) - float_bits(Pack<float, N>::all(round_magic));
    return bits_as_float(float_bits(p) + (n << 23));
}

// The sum of the lanes: registers added, then one register's lanes pairwise.
template <int N>
SURGSPLAT_INLINE float lane_sum(const Pack<float, N>& x) {
    Vec16::Reg s = x.r[0];
    for (int i = 1; i < N; ++i) s += x.r[i];
#if defined(__AVX512F__)
    return _mm512_reduce_add_ps(reinterpret_cast<__m512>(s));
#elif defined(__x86_64__) || defined(_M_X64)
#if defined(__AVX__)
    const __m128 q = _mm_add_ps(_mm256_castps256_ps128(reinterpret_cast<__m256>(s)),
                                _mm256_extractf128_ps(reinterpret_cast<__m256>(s), 1));
#else
    const __m128 q = reinterpret_cast<__m128>(s);
#endif
    const __m128 pairs = _mm_add_ps(q, _mm_movehl_ps(q, q));
    return _mm_cvtss_f32(_mm_add_ss(pairs, _mm_shuffle_ps(pairs, pairs, 1)));
#else
    return vaddvq_f32(reinterpret_cast<float32x4_t>(s));
#endif
}

// sums[j] = the sum of the lanes of v[j], j < 8: each vector's registers added, then the eight
// registers reduced together by a transposing tree of pairwise additions (on AVX2 nine
// instructions, against about fifty for eight lane_sum calls).
template <int N>
SURGSPLAT_INLINE void lane_sums8(const Pack<float, N> (&v)[8], float* sums) {
    Vec16::Reg s[8];
    for (int j = 0; j < 8; ++j) {
        s[j] = v[j].r[0];
        for (int i = 1; i < N; ++i) s[j] += v[j].r[i];
    }
#if defined(__AVX__)
    __m256 h[8];
    for (int j = 0; j < 8; ++j) {
#if defined(__AVX512F__)
        const __m512 x = reinterpret_cast<__m512>(s[j]);
        h[j] = _mm256_add_ps(_mm512_castps512_ps256(x), _mm256_castpd_ps(
                                 _mm512_extractf64x4_pd(_mm512_castps_pd(x), 1)));
#else
        h[j] = reinterpret_cast<__m256>(s[j]);
#endif
    }
    // hadd(a, b) = [a0+a1, a2+a3, b0+b1, b2+b3 | a4+a5, a6+a7, b4+b5, b6+b7]
    const __m256 halves_0123 =
        _mm256_hadd_ps(_mm256_hadd_ps(h[0], h[1]), _mm256_hadd_ps(h[2], h[3]));
    const __m256 halves_4567 =
        _mm256_hadd_ps(_mm256_hadd_ps(h[4], h[5]), _mm256_hadd_ps(h[6], h[7]));
    _mm256_storeu_ps(sums, _mm256_add_ps(_mm256_permute2f128_ps(halves_0123, halves_4567, 0x20),
                                         _mm256_permute2f128_ps(halves_0123, halves_4567, 0x31)));
#else
    for (int group = 0; group < 8; group += 4) {
#if defined(__x86_64__) || defined(_M_X64)
        const __m128 a = reinterpret_cast<__m128>(s[group]);
        const __m128 b = reinterpret_cast<__m128>(s[group + 1]);
        const __m128 c = reinterpret_cast<__m128>(s[group + 2]);
        const __m128 d = reinterpret_cast<__m128>(s[group + 3]);
        // [a0+a2, b0+b2, a1+a3, b1+b3] and the same of c, d; then the halves of both added
        const __m128 ab = _mm_add_ps(_mm_unpacklo_ps(a, b), _mm_unpackhi_ps(a, b));
        const __m128 cd = _mm_add_ps(_mm_unpacklo_ps(c, d), _mm_unpackhi_ps(c, d));
        _mm_storeu_ps(sums + group, _mm_add_ps(_mm_movelh_ps(ab, cd), _mm_movehl_ps(cd, ab)));
#else
        const float32x4_t ab = vpaddq_f32(reinterpret_cast<float32x4_t>(s[group]),
                                          reinterpret_cast<float32x4_t>(s[group + 1]));
        const float32x4_t cd = vpaddq_f32(reinterpret_cast<float32x4_t>(s[group + 2]),
                                          reinterpret_cast<float32x4_t>(s[group + 3]));
        vst1q_f32(sums + group, vpaddq_f32(ab, cd));
#endif
    }
#endif
}

// |x| lane-wise (the sign bit cleared).
template <int N>
SURGSPLAT_INLINE Pack<float, N> abs(const Pack<float, N>& x) {
    Pack<float, N> out;
    for (int i = 0; i < N; ++i)
        out.r[i] = reinterpret_cast<typename Pack<float, N>::Reg>(
            reinterpret_cast<typename Pack<int32_t, N>::Reg>(x.r[i]) & 0x7fffffff);
    return out;
}

// Whether any lane of `mask` (lanes all ones or all zeros) is set.
template <int N>
SURGSPLAT_INLINE bool any_lane(const Pack<int32_t, N>& mask) {
    Vec16i::Reg m = mask.r[0];
    for (int i = 1; i < N; ++i) m |= mask.r[i];
#if defined(__AVX512F__)
    return _mm512_test_epi32_mask(reinterpret_cast<__m512i>(m), reinterpret_cast<__m512i>(m)) != 0;
#elif defined(__AVX__)
    return !_mm256_testz_si256(reinterpret_cast<__m256i>(m), reinterpret_cast<__m256i>(m));
#elif defined(__x86_64__) || defined(_M_X64)
    return _mm_movemask_ps(reinterpret_cast<__m128>(m)) != 0;
#else
    return vmaxvq_u32(reinterpret_cast<uint32x4_t>(m)) != 0;
#endif
}

// 1 / x lane-wise for normal, positive x, to within about 2 ulp: the hardware's reciprocal
// estimate refined by a Newton step r' = r (2 - x r), several times cheaper than a division.
// The AVX-512 estimate has 14 bits, SSE/AVX ones 12; NEON's 8 bits take one more step (vrecps).
template <int N>
SURGSPLAT_INLINE Pack<float, N> reciprocal(const Pack<float, N>& x) {
    Pack<float, N> r;
    for (int i = 0; i < N; ++i) {
#if defined(__AVX512F__)
        r.r[i] = reinterpret_cast<Vec16::Reg>(_mm512_rcp14_ps(reinterpret_cast<__m512>(x.r[i])));
#elif defined(__AVX__)
        r.r[i] = reinterpret_cast<Vec16::Reg>(_mm256_rcp_ps(reinterpret_cast<__m256>(x.r[i])));
#elif defined(__x86_64__) || defined(_M_X64)
        r.r[i] = reinterpret_cast<Vec16::Reg>(_mm_rcp_ps(reinterpret_cast<__m128>(x.r[i])));
#else
        const float32x4_t v = reinterpret_cast<float32x4_t>(x.r[i]);
        const float32x4_t e = vrecpeq_f32(v);
        r.r[i] = reinterpret_cast<Vec16::Reg>(vmulq_f32(e, vrecpsq_f32(v, e)));
#endif
    }
    return r * (2.0f - x * r);
}

}  // namespace surgsplat
