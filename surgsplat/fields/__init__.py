"""surgsplat.fields"""
