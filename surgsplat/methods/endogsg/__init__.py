"""Endo-GSG: a canonical neural SDF giving each Gaussian its opacity, with its SDA, projection,
orientation and Eikonal terms (`sdf`), and the occlusion importance map of the core's
photometric and depth losses, over a HexPlane field. Its preset is `preset.PRESET`; its page is
docs/methods/endogsg.md."""
