"""surgsplat.losses"""
