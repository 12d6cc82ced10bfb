"""Crops: each crop's plant as ellipsoids and capsules (`prims`), shared by the renderer, the
exports and the collision check."""
