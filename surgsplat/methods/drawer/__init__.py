"""DRAWER: tissue Gaussians anchored on the faces of the SDF's marching-cubes mesh
(`mesh_anchor`), with Endo-GSG's SDF and PhysioSplat's tool field; the tool's articulation and
the simulation export. Its preset is `preset.PRESET`; its page is docs/methods/drawer.md."""
