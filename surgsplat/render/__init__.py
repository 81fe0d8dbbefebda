"""surgsplat.render"""
