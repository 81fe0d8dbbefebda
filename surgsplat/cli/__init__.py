"""surgsplat.cli"""
