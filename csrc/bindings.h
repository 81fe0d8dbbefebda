// Shared helpers of the Python bindings, and one bind function per native op. Arrays are
// C-contiguous CPU float32/int32 ndarrays; outputs are allocated by the caller.
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <stdexcept>
#include <string>
#include <vector>

template <typename T>
using In = nanobind::ndarray<const T, nanobind::c_contig, nanobind::device::cpu>;
template <typename T>
using Out = nanobind::ndarray<T, nanobind::c_contig, nanobind::device::cpu>;

// std::invalid_argument (ValueError in Python) unless `array` has `size` elements.
template <typename A>
void expect_size(const A& array, size_t size, const char* name) {
    if (array.size() != size)
        throw std::invalid_argument(std::string(name) + ": expected " + std::to_string(size) +
                                    " elements, got " + std::to_string(array.size()));
}

// Each op folder binds its functions through one OpBinding object at namespace scope
// (`static const OpBinding binding(&bind_my_op);` in its bindings.cpp), in csrc/ or in a method
// package's csrc/ (surgsplat/methods/<name>/csrc/): the module binds every op compiled into it
// (CMakeLists.txt) without naming any.
using BindFunction = void (*)(nanobind::module_&);

// The bind functions registered so far, in the order their objects were initialised.
std::vector<BindFunction>& op_bindings();

struct OpBinding {
    explicit OpBinding(BindFunction bind) { op_bindings().push_back(bind); }
};
