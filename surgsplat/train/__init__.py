"""surgsplat.train"""
