// One ISA variant of the native Python module, `_native_<isa>`: each op folder (of csrc/ and of
// the method packages' csrc/) registers its bind function (bindings.h, OpBinding), called here.
// CMakeLists.txt compiles all of those sources once per target ISA and defines SURGSPLAT_ISA (the
// variant's name) and SURGSPLAT_MODULE (its module name); which variant runs is chosen in
// surgsplat/render/native.py from cpu_isas() of the portable variant.
#include <omp.h>

#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <cstdint>
#include <string>
#include <vector>

#if defined(__x86_64__) || defined(_M_X64)
#include <immintrin.h>
#endif

#include "bindings.h"

#if !defined(SURGSPLAT_ISA) || !defined(SURGSPLAT_MODULE)
#error "CMakeLists.txt defines SURGSPLAT_ISA and SURGSPLAT_MODULE for each ISA variant"
#endif

namespace nb = nanobind;

std::vector<BindFunction>& op_bindings() {
    static std::vector<BindFunction> bindings;  // built on first use: safe from any initialiser
    return bindings;
}

namespace {

// The ISA variants this CPU (and its operating system) can run, fastest first. Only ever run by
// the portable variant, compiled for the architecture's baseline.
std::vector<std::string> cpu_isas() {
#if defined(__x86_64__) || defined(_M_X64)
    __builtin_cpu_init();
    std::vector<std::string> isas;
    if (__builtin_cpu_supports("x86-64-v4")) isas.push_back("avx512");
    if (__builtin_cpu_supports("x86-64-v3")) isas.push_back("avx2");
    isas.push_back("baseline");
    return isas;
#else
    return {"neon"};
#endif
}

// Subnormal floats read and written as zero in the calling thread (x86: MXCSR's DAZ and FTZ;
// AArch64: FPCR's FZ). An operation on a subnormal costs tens to a hundred times a normal one on
// x86 (a microcode assist); products of tiny gradients land there: the Gaussian-basis backward
// of flat (planar) discs, whose gradients are near zero, took 67 ms a step against 12 ms with
// them flushed (full phantom, one thread, Zen 5).
void flush_subnormals_in_this_thread() {
#if defined(__x86_64__) || defined(_M_X64)
    _mm_setcsr(_mm_getcsr() | 0x8040);
#elif defined(__aarch64__)
    uint64_t fpcr;
    __asm__ volatile("mrs %0, fpcr" : "=r"(fpcr));
    __asm__ volatile("msr fpcr, %0" : : "r"(fpcr | (uint64_t{1} << 24)));
#endif
}

// In every thread of the OpenMP team of the calling thread, the calling thread included.
void flush_subnormals() {
#pragma omp parallel
    flush_subnormals_in_this_thread();
}

// The team grows new threads with a larger count, so they are set again.
void set_threads(int threads) {
    if (threads < 1) throw std::invalid_argument("threads: expected at least 1");
    omp_set_num_threads(threads);
    flush_subnormals();
}

}  // namespace

#define SURGSPLAT_NB_MODULE(name, m) NB_MODULE(name, m)
SURGSPLAT_NB_MODULE(SURGSPLAT_MODULE, m) {
    m.doc() = "surgsplat native CPU kernels (C++17, OpenMP), variant " SURGSPLAT_ISA;
    // Autograd graphs alive at interpreter exit may still hold kernel state; that is no leak.
    nb::set_leak_warnings(false);
    m.attr("isa") = SURGSPLAT_ISA;
    m.def("cpu_isas", &cpu_isas, "ISA variants this CPU can run, fastest first.");
    m.def("max_threads", [] { return omp_get_max_threads(); }, "OpenMP threads the kernels use.");
    m.def("set_threads", &set_threads, nb::arg("threads"),
          "Threads of the kernels' parallel regions started from the calling thread (each "
          "flushing subnormals to zero).");
    m.def("flush_subnormals", &flush_subnormals,
          "Flush subnormal floats to zero in the calling thread and its OpenMP team, for good.");
    for (BindFunction bind : op_bindings()) bind(m);
}
