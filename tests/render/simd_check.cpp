// Checks every operation of csrc/simd.h against plain scalar arithmetic, for the one ISA this
// file is compiled for (tests/render/test_simd_primitives.py compiles it with each variant's
// flags from CMakeLists.txt and runs it, the NEON build under qemu-aarch64 on an x86-64 host).
// simd.h holds all of the kernels' ISA-specific code; everything else in csrc/ is the same source
// for every variant, and the Python tests run it on each variant the CPU executes.
//
// Prints one line per failed check and a summary; exits 1 if any check failed.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <random>

#include "simd.h"

using namespace surgsplat;

namespace {

int checks = 0, failures = 0;

void check(bool ok, const char* what, double got, double expected, int detail = -1) {
    ++checks;
    if (ok) return;
    if (++failures <= 20)
        std::printf("FAIL %s (lane/case %d): got %.9g, expected %.9g\n", what, detail, got,
                    expected);
}

double relative_error(double got, double expected) {
    return std::fabs(got - expected) / std::fabs(expected);
}

Vec16 random_vec(std::mt19937& rng, float low, float high) {
    std::uniform_real_distribution<float> uniform(low, high);
    Vec16 v;
    for (int i = 0; i < kVecLanes; ++i) v[i] = uniform(rng);
    return v;
}

void check_load_store_and_arithmetic(std::mt19937& rng) {
    float source[kVecLanes + 3], target[kVecLanes + 3] = {};
    for (int i = 0; i < kVecLanes + 3; ++i) source[i] = 0.25f * i - 1.0f;
    const Vec16 a = Vec16::load(source + 3);  // unaligned on purpose
    a.store(target + 1);
    for (int i = 0; i < kVecLanes; ++i)
        check(target[i + 1] == source[i + 3], "load/store", target[i + 1], source[i + 3], i);

    const Vec16 x = random_vec(rng, -4.0f, 4.0f), y = random_vec(rng, -4.0f, 4.0f);
    const Vec16 sum = x + y, difference = x - 2.0f, product = 3.0f * y, negated = -x;
    const Vec16 magnitude = abs(x);
    for (int i = 0; i < kVecLanes; ++i) {
        check(sum[i] == x[i] + y[i], "add", sum[i], x[i] + y[i], i);
        check(difference[i] == x[i] - 2.0f, "subtract scalar", difference[i], x[i] - 2.0f, i);
        check(product[i] == 3.0f * y[i], "scalar times", product[i], 3.0f * y[i], i);
        check(negated[i] == -x[i], "negate", negated[i], -x[i], i);
        check(magnitude[i] == std::fabs(x[i]), "abs", magnitude[i], std::fabs(x[i]), i);
    }

    Vec16i bits;
    for (int i = 0; i < kVecLanes; ++i) bits[i] = (i * 0x01010101) ^ 0x5a5a5a5a;
    const Vec16i anded = bits & 0x0f0f0f0f, ored = bits | 1, inverted = ~bits, shifted = bits << 3;
    for (int i = 0; i < kVecLanes; ++i) {
        check(anded[i] == (bits[i] & 0x0f0f0f0f), "and", anded[i], bits[i] & 0x0f0f0f0f, i);
        check(ored[i] == (bits[i] | 1), "or", ored[i], bits[i] | 1, i);
        check(inverted[i] == ~bits[i], "not", inverted[i], ~bits[i], i);
        check(shifted[i] == static_cast<int32_t>(static_cast<uint32_t>(bits[i]) << 3), "shift",
              shifted[i], static_cast<int32_t>(static_cast<uint32_t>(bits[i]) << 3), i);
    }
}

void check_comparisons_and_select(std::mt19937& rng) {
    const Vec16 x = random_vec(rng, -1.0f, 1.0f), y = random_vec(rng, -1.0f, 1.0f);
    const Vec16i less = x < y, less_equal = x <= 0.0f, greater = x > y, greater_equal = 0.5f >= y;
    const Vec16 chosen = select(less, x, y);
    for (int i = 0; i < kVecLanes; ++i) {
        check(less[i] == (x[i] < y[i] ? -1 : 0), "<", less[i], x[i] < y[i] ? -1 : 0, i);
        check(less_equal[i] == (x[i] <= 0.0f ? -1 : 0), "<=", less_equal[i],
              x[i] <= 0.0f ? -1 : 0, i);
        check(greater[i] == (x[i] > y[i] ? -1 : 0), ">", greater[i], x[i] > y[i] ? -1 : 0, i);
        check(greater_equal[i] == (0.5f >= y[i] ? -1 : 0), ">=", greater_equal[i],
              0.5f >= y[i] ? -1 : 0, i);
        check(chosen[i] == (x[i] < y[i] ? x[i] : y[i]), "select", chosen[i],
              x[i] < y[i] ? x[i] : y[i], i);
    }
}

void check_conversions() {
    Vec16 x;
    for (int i = 0; i < kVecLanes; ++i) x[i] = (i - 8) * 1.75f + (i % 3 == 0 ? 1e6f : 0.0f);
    const Vec16i truncated = to_int(x);
    const Vec16 back = to_float(truncated), same = bits_as_float(float_bits(x));
    for (int i = 0; i < kVecLanes; ++i) {
        const int32_t expected = static_cast<int32_t>(x[i]);  // toward zero
        check(truncated[i] == expected, "to_int", truncated[i], expected, i);
        check(back[i] == static_cast<float>(expected), "to_float", back[i], expected, i);
        check(same[i] == x[i], "float_bits/bits_as_float", same[i], x[i], i);
    }
}

// 2^y to within 3e-7 relative for -125 <= y <= 127, and 2^-125 below, as simd.h promises.
void check_pow2() {
    double worst = 0.0;
    int case_index = 0;
    for (double y = -140.0; y <= 127.0; y += 1.0 / 1024.0 + 1e-7, ++case_index) {
        Vec16 v;
        for (int i = 0; i < kVecLanes; ++i) v[i] = static_cast<float>(y + i * 1e-3);
        const Vec16 p = pow2(v);
        for (int i = 0; i < kVecLanes; ++i) {
            if (v[i] > 127.0f) continue;
            const double expected = std::exp2(std::max(static_cast<double>(v[i]), -125.0));
            const double error = relative_error(p[i], expected);
            worst = std::max(worst, error);
            check(error <= 3e-7, "pow2", p[i], expected, case_index);
        }
    }
    std::printf("pow2: worst relative error %.3g\n", worst);
}

// 1 / x to within about 2 ulp for normal positive x.
void check_reciprocal(std::mt19937& rng) {
    std::uniform_real_distribution<float> exponent(-125.0f, 125.0f);
    double worst = 0.0;
    for (int round = 0; round < 4096; ++round) {
        Vec16 x;
        for (int i = 0; i < kVecLanes; ++i) x[i] = std::exp2(exponent(rng));
        if (round == 0) x[0] = 1.0f, x[1] = 3.0f, x[2] = 0.1f;
        const Vec16 r = reciprocal(x);
        for (int i = 0; i < kVecLanes; ++i) {
            const double error = relative_error(r[i], 1.0 / static_cast<double>(x[i]));
            worst = std::max(worst, error);
            check(error <= 2.5e-7, "reciprocal", r[i], 1.0 / x[i], round);
        }
    }
    std::printf("reciprocal: worst relative error %.3g\n", worst);
}

// lane_sum and any_lane of a whole vector and of every register range part<R0, N> picks out.
void check_reductions_and_register_ranges(std::mt19937& rng) {
    const Vec16 x = random_vec(rng, -1.0f, 1.0f);
    for (int first = 0; first < kVecLanes; ++first) {
        for (int last = first; last < kVecLanes; ++last) {
            int calls = 0;
            with_registers<kRegs>(first / kRegLanes, last / kRegLanes,
                                  [&](auto first_register, auto registers) {
                constexpr int R0 = decltype(first_register)::value;
                constexpr int N = decltype(registers)::value;
                ++calls;
                check(R0 == first / kRegLanes && R0 + N - 1 == last / kRegLanes,
                      "with_registers range", R0 * 100 + N, first / kRegLanes, first * 100 + last);
                double expected = 0.0;
                for (int i = R0 * kRegLanes; i < (R0 + N) * kRegLanes; ++i) expected += x[i];
                const float got = lane_sum(part<R0, N>(x));
                check(std::fabs(got - expected) <= 1e-6, "lane_sum of part", got, expected,
                      first * 100 + last);
                Vec16i mask = Vec16i::all(0);
                check(!any_lane(part<R0, N>(mask)), "any_lane of zeros", 1, 0, R0);
                for (int lane = R0 * kRegLanes; lane < (R0 + N) * kRegLanes; ++lane) {
                    Vec16i one = Vec16i::all(0);
                    one[lane] = -1;
                    check(any_lane(part<R0, N>(one)), "any_lane of one lane", 0, 1, lane);
                }
                Vec16 y = x;
                set_part<R0, N>(y, part<R0, N>(x) * 2.0f);
                for (int i = 0; i < kVecLanes; ++i) {
                    const bool inside = i >= R0 * kRegLanes && i < (R0 + N) * kRegLanes;
                    check(y[i] == (inside ? 2.0f * x[i] : x[i]), "set_part", y[i], x[i], i);
                }
            });
            check(calls == 1, "with_registers calls f once", calls, 1, first * 100 + last);
        }
    }
    double whole = 0.0;
    for (int i = 0; i < kVecLanes; ++i) whole += x[i];
    check(std::fabs(lane_sum(x) - whole) <= 1e-6, "lane_sum", lane_sum(x), whole);
}

template <int N>
void check_lane_sums8(std::mt19937& rng) {
    Pack<float, N> v[8];
    std::uniform_real_distribution<float> uniform(-1.0f, 1.0f);
    for (auto& pack : v)
        for (int i = 0; i < N * kRegLanes; ++i) pack[i] = uniform(rng);
    float sums[8];
    lane_sums8(v, sums);
    for (int j = 0; j < 8; ++j) {
        double expected = 0.0;
        for (int i = 0; i < N * kRegLanes; ++i) expected += v[j][i];
        check(std::fabs(sums[j] - expected) <= 1e-6, "lane_sums8", sums[j], expected, j);
    }
}

}  // namespace

int main() {
    std::mt19937 rng(7);
    float line[16] = {};
    prefetch(line);
    check_load_store_and_arithmetic(rng);
    check_comparisons_and_select(rng);
    check_conversions();
    check_pow2();
    check_reciprocal(rng);
    check_reductions_and_register_ranges(rng);
    check_lane_sums8<kRegs>(rng);
    check_lane_sums8<1>(rng);
    std::printf("%s: %d registers of %d lanes, %d checks, %d failed\n", SIMD_CHECK_ISA, kRegs,
                kRegLanes, checks, failures);
    return failures == 0 ? EXIT_SUCCESS : EXIT_FAILURE;
}
