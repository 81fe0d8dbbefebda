// Python bindings of the separable blur and the SSIM kernels built on it.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>

#include <optional>
#include <string>

#include "bindings.h"
#include "blur/blur.h"

namespace nb = nanobind;

namespace {

// The radius of `taps`; std::invalid_argument unless they are an odd, symmetric kernel.
int check_taps(const In<float>& taps) {
    const size_t size = taps.size();
    if (size % 2 != 1) throw std::invalid_argument("taps: expected an odd number of weights");
    for (size_t i = 0; i < size / 2; ++i)
        if (taps.data()[i] != taps.data()[size - 1 - i])
            throw std::invalid_argument("taps: expected a symmetric kernel, taps[" +
                                        std::to_string(i) + "] != taps[" +
                                        std::to_string(size - 1 - i) + "]");
    return static_cast<int>(size / 2);
}

struct Image {
    size_t height, width, channels;
};

Image check_images(const In<float>& pred, const In<float>& gt) {
    if (pred.ndim() != 3) throw std::invalid_argument("pred: expected shape [H, W, C]");
    const Image image{pred.shape(0), pred.shape(1), pred.shape(2)};
    if (gt.ndim() != 3 || gt.shape(0) != image.height || gt.shape(1) != image.width ||
        gt.shape(2) != image.channels)
        throw std::invalid_argument("gt: expected the shape of pred");
    return image;
}

void blur(In<float> planes, In<float> taps, Out<float> out) {
    if (planes.ndim() != 3) throw std::invalid_argument("planes: expected shape [P, H, W]");
    const int radius = check_taps(taps);
    expect_size(out, planes.size(), "out");
    if (planes.size() > 0 && out.data() == planes.data())
        throw std::invalid_argument("out: must not be the input array");
    nb::gil_scoped_release unlocked;
    surgsplat::blur_planes(planes.data(), planes.shape(0), planes.shape(1), planes.shape(2),
                           taps.data(), radius, out.data());
}

// The data of an optional per-pixel map [H, W] named `name`, or null.
const float* pixel_map(const std::optional<In<float>>& values, const Image& s, const char* name) {
    if (!values) return nullptr;
    expect_size(*values, s.height * s.width, name);
    return values->data();
}

double ssim_forward(In<float> pred, In<float> gt, In<float> taps, float c1, float c2,
                    std::optional<In<float>> weights, std::optional<In<float>> image_mask,
                    Out<float> moments, std::optional<Out<float>> map) {
    const Image s = check_images(pred, gt);
    const int radius = check_taps(taps);
    const float* w = pixel_map(weights, s, "weights");
    const float* mask = pixel_map(image_mask, s, "image_mask");
    expect_size(moments, 4 * pred.size(), "moments");
    if (map) expect_size(*map, pred.size(), "map");
    nb::gil_scoped_release unlocked;
    return surgsplat::ssim_forward(pred.data(), gt.data(), s.height, s.width, s.channels,
                                   taps.data(), radius, c1, c2, w, mask, moments.data(),
                                   map ? map->data() : nullptr);
}

void ssim_backward(In<float> pred, In<float> gt, In<float> moments, In<float> taps, float c1,
                   float c2, std::optional<In<float>> grad_map, std::optional<In<float>> weights,
                   float grad_score, std::optional<In<float>> image_mask,
                   std::optional<Out<float>> grad_pred, std::optional<Out<float>> grad_gt) {
    const Image s = check_images(pred, gt);
    const int radius = check_taps(taps);
    expect_size(moments, 4 * pred.size(), "moments");
    if (grad_map) expect_size(*grad_map, pred.size(), "grad_map");
    const surgsplat::SsimUpstream upstream{grad_map ? grad_map->data() : nullptr,
                                           pixel_map(weights, s, "weights"), grad_score};
    if (grad_pred) expect_size(*grad_pred, pred.size(), "grad_pred");
    if (grad_gt) expect_size(*grad_gt, pred.size(), "grad_gt");
    nb::gil_scoped_release unlocked;
    surgsplat::ssim_backward(pred.data(), gt.data(), moments.data(), s.height, s.width,
                             s.channels, taps.data(), radius, c1, c2, upstream,
                             pixel_map(image_mask, s, "image_mask"),
                             grad_pred ? grad_pred->data() : nullptr,
                             grad_gt ? grad_gt->data() : nullptr);
}

}  // namespace

static void bind_blur(nb::module_& m) {
    m.def("blur", &blur, nb::arg("planes"), nb::arg("taps"), nb::arg("out"),
          "Blur each plane [P, H, W] with the symmetric 1D kernel `taps` along rows then "
          "columns, zero padding, into `out` [P, H, W]. Self-adjoint: also its own backward.");
    m.def("ssim_forward", &ssim_forward, nb::arg("pred"), nb::arg("gt"), nb::arg("taps"),
          nb::arg("c1"), nb::arg("c2"), nb::arg("weights").none(), nb::arg("image_mask").none(),
          nb::arg("moments"), nb::arg("map").none(),
          "SSIM of two images [H, W, C] with the window `taps` (zero padding): writes the "
          "blurred moments [4, C, H, W] that ssim_backward reads and, unless None, the map "
          "[H, W, C]; returns the score, the sum over pixels and channels of weights [H, W] "
          "(None: ones) times the map. Unless None, image_mask [H, W] multiplies both images "
          "before filtering.");
    m.def("ssim_backward", &ssim_backward, nb::arg("pred"), nb::arg("gt"), nb::arg("moments"),
          nb::arg("taps"), nb::arg("c1"), nb::arg("c2"), nb::arg("grad_map").none(),
          nb::arg("weights").none(), nb::arg("grad_score"), nb::arg("image_mask").none(),
          nb::arg("grad_pred").none(), nb::arg("grad_gt").none(),
          "Gradients [H, W, C] with respect to pred and gt (each skipped when None) of a loss "
          "whose gradient with respect to the map is grad_map [H, W, C], or if None "
          "grad_score * weights (the backward of the score), with the forward's image_mask.");
}

static const OpBinding binding(&bind_blur);
