"""surgsplat.model"""
