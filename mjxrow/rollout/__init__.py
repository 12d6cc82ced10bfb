"""Batched closed-loop episodes: `episode` (the one jitted batch of episodes), `metrics`
(per-episode navigation metrics and their aggregation)."""
