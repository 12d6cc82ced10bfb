"""Batched closed-loop episodes: `episode` (the one jit(vmap(scan))), `metrics` (per-episode
navigation metrics and their aggregation)."""
