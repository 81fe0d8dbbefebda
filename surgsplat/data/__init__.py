"""surgsplat.data"""
