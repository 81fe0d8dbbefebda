"""surgsplat.eval"""
