"""EndoPlanar: flattened planar Gaussians with unbiased plane depth (`planar`, `plane_depth`),
the edge-aware depth-normal consistency (`normal_consistency`, with its native kernels in this
package's csrc/), MOG2 point fusion. Its preset is `preset.PRESET`; its page is
docs/methods/endoplanar.md."""
