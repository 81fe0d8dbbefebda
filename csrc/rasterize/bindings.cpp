// Python bindings of the tile rasterizer.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include "bindings.h"
#include "rasterize/common.h"

namespace nb = nanobind;
using surgsplat::TileBins;

namespace {

struct Screen {
    size_t n, channels;
};

Screen check_inputs(const In<float>& means2d, const In<float>& conics,
                    const In<float>& opacities, const In<float>& features) {
    const size_t n = opacities.size();
    if (features.ndim() != 2 || features.shape(0) != n)
        throw std::invalid_argument("features: expected shape [N, C] with N = len(opacities)");
    expect_size(means2d, 2 * n, "means2d");
    expect_size(conics, 3 * n, "conics");
    return {n, features.shape(1)};
}

TileBins forward(In<float> means2d, In<float> conics, In<float> opacities, In<float> features,
                 In<float> depths, In<int32_t> radii, In<float> background, int width,
                 int height, Out<float> image, Out<float> transmittance,
                 Out<int32_t> last_entry) {
    const Screen s = check_inputs(means2d, conics, opacities, features);
    const size_t pixels = static_cast<size_t>(width) * height;
    expect_size(depths, s.n, "depths");
    expect_size(radii, s.n, "radii");
    expect_size(background, s.channels, "background");
    expect_size(image, pixels * s.channels, "image");
    expect_size(transmittance, pixels, "transmittance");
    expect_size(last_entry, pixels, "last_entry");
    nb::gil_scoped_release unlocked;
    TileBins bins = surgsplat::bin_gaussians(means2d.data(), conics.data(), opacities.data(),
                                             features.data(), s.channels, depths.data(),
                                             radii.data(), s.n, width, height);
    bins.background.assign(background.data(), background.data() + s.channels);
    surgsplat::rasterize_forward(bins, width, height, image.data(), transmittance.data(),
                                 last_entry.data());
    return bins;
}

void backward(const TileBins& bins, In<float> means2d, In<float> conics, In<float> opacities,
              In<float> features, int width, int height, In<float> transmittance,
              In<int32_t> last_entry, In<float> grad_image, In<float> grad_alpha,
              Out<float> grad_means2d, Out<float> grad_conics, Out<float> grad_opacities,
              Out<float> grad_features, Out<float> abs_grad_means2d, In<float> pixel_weights,
              In<uint8_t> weighted_members) {
    const Screen s = check_inputs(means2d, conics, opacities, features);
    const size_t pixels = static_cast<size_t>(width) * height;
    if (static_cast<size_t>(bins.num_gaussians) != s.n ||
        static_cast<size_t>(bins.channels) != s.channels)
        throw std::invalid_argument("bins were made for another scene");
    expect_size(transmittance, pixels, "transmittance");
    expect_size(last_entry, pixels, "last_entry");
    expect_size(grad_image, pixels * s.channels, "grad_image");
    expect_size(grad_alpha, pixels, "grad_alpha");
    expect_size(grad_means2d, 2 * s.n, "grad_means2d");
    expect_size(grad_conics, 3 * s.n, "grad_conics");
    expect_size(grad_opacities, s.n, "grad_opacities");
    expect_size(grad_features, s.n * s.channels, "grad_features");
    expect_size(abs_grad_means2d, 2 * s.n, "abs_grad_means2d");
    const bool weighted = weighted_members.size() > 0;  // no weights: both empty
    expect_size(pixel_weights, weighted ? pixels : 0, "pixel_weights");
    expect_size(weighted_members, weighted ? s.n : 0, "weighted_members");
    nb::gil_scoped_release unlocked;
    surgsplat::rasterize_backward(
        bins, width, height, transmittance.data(), last_entry.data(), grad_image.data(),
        grad_alpha.data(), grad_means2d.data(), grad_conics.data(), grad_opacities.data(),
        grad_features.data(), abs_grad_means2d.data(),
        weighted ? pixel_weights.data() : nullptr, weighted ? weighted_members.data() : nullptr);
}

}  // namespace

static void bind_rasterize(nb::module_& m) {
    nb::class_<TileBins>(m, "TileBins", "Depth-sorted Gaussian lists of the 16x16 tiles.")
        .def_prop_ro("num_overlaps", [](const TileBins& b) { return b.ranks.size(); },
                     "Total (tile, Gaussian) pairs: the tiles each Gaussian's alpha >= 1/255 "
                     "ellipse reaches.")
        .def_prop_ro("box_overlaps", [](const TileBins& b) { return b.box_overlaps; },
                     "(tile, Gaussian) pairs of the Gaussians' alpha >= 1/255 boxes, a superset.")
        .def_prop_ro("tiles", [](const TileBins& b) { return b.tiles_x * b.tiles_y; });
    m.def("rasterize_forward", &forward, "Bin, sort and composite; returns the tile bins.");
    m.def("rasterize_backward", &backward,
          "Gradients of the compositing, given its tile bins; pixel_weights [H, W] float32 "
          "scale, per pixel, the gradients of the Gaussians with weighted_members [N] uint8 != 0 "
          "(both empty: no weights).");
}

static const OpBinding binding(&bind_rasterize);
