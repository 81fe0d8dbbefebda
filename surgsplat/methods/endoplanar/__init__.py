"""EndoPlanar: flattened planar Gaussians with unbiased plane depth (`planar`, `plane_depth`),
the edge-aware depth-normal consistency (`normal_consistency`, with native kernels in
csrc/normals), MOG2 point fusion. Its preset is `preset.PRESET`; its page is
docs/methods/endoplanar.md."""
