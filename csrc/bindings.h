// Shared helpers of the Python bindings, and one bind function per native op. Arrays are
// C-contiguous CPU float32/int32 ndarrays; outputs are allocated by the caller.
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <stdexcept>
#include <string>

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

void bind_rasterize(nanobind::module_& m);
void bind_hexplane(nanobind::module_& m);
void bind_blur(nanobind::module_& m);
void bind_project(nanobind::module_& m);
void bind_probe(nanobind::module_& m);
void bind_gaussian_basis(nanobind::module_& m);
void bind_sh(nanobind::module_& m);
void bind_normals(nanobind::module_& m);
