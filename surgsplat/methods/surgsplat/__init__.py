"""surgsplat's own method: EndoGaussian's HexPlane deformation, EndoPlanar's discs and
depth-normal loss, LumiState's reflectance x illumination, composed from those packages. Its
preset is `preset.PRESET`; its page is docs/methods/surgsplat.md."""
