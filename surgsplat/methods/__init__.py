"""surgsplat.methods"""
