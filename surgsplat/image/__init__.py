"""surgsplat.image: image operations below both losses and evaluation (SSIM, blur, gradients, depth validity)."""
