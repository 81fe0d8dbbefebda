"""surgsplat.export"""
