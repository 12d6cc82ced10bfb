"""Batched closed-loop episodes: `step` (THE control step: command → physics → end events → log
row, shared with the training environment), `episode` (the loop: the one jitted batch of
episodes), `build` (config → model, fields, policy, keys, shardings), `config` (the config
vocabulary), `metrics` (per-episode navigation metrics and their aggregation), `cli` (the
`python -m mjxrow.episode` command's work)."""
