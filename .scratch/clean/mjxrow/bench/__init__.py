"""Benchmarks: `python -m mjxrow.bench STAGE [...]`. Each stage module has `add_args(parser)` and
`run(args) -> list[dict]`; every row lands in `benchmarks.jsonl` (machine) and is printed as a
table; BENCHMARKS.md's current figures are generated from the rows
(`experiments/benchmarks_table.py --write BENCHMARKS.md`). The shared timing and recording
helpers are `timing`'s; the command is `cli` (light: the stage list, read from the stage
modules' docstrings) handing over to `run` (the stage's own flags, the measurement)."""

STAGES = ("fields", "physics", "render", "render_mjwarp", "segmenter", "closed_loop", "dataset",
          "train")
