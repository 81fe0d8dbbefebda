"""EndoGaussian, the HexPlane baseline: a HexPlane deformation field (the core's
`fields.hexplane`) with its plane TV and time smoothness. Its preset is `preset.PRESET`; its
page is docs/methods/endogaussian.md."""
