"""LumiState: reflectance x illumination (`decomposition`), an illumination UNet and its
embedding (`illumination`), the Retinex, bright-channel and illumination-transfer losses of its
Stage 2 (`retinex`). Its preset is `preset.PRESET`; its page is docs/methods/lumistate.md."""
