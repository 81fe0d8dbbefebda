"""Deform3DGS, the baseline: per-Gaussian Gaussian-basis deformation (the core's
`fields.gaussian_basis`), L1 + D-SSIM and depth L1, motion-aware point fusion. Its preset is
`preset.PRESET`; its page is docs/methods/deform3dgs.md."""
