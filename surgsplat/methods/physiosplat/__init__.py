"""PhysioSplat: tool Gaussians with per-frame rigid motion and semantic logits (`tool_field`),
ARAP strain, tool-collision and volume losses (`biomechanics`), a co-located specular lobe
(`specular`), over a HexPlane tissue field. Its preset is `preset.PRESET`; its page is
docs/methods/physiosplat.md."""
