"""A method package outside surgsplat, as a user would write one: a component of its own and a
preset, joined to surgsplat through the entry-point group `surgsplat.methods` (declared in
../toy_splat_method-0.1.dist-info/entry_points.txt, as `pip install` would write it). Nothing
under surgsplat/ names it."""
