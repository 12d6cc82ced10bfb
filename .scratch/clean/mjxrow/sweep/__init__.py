"""Sweeps: `config` (YAML schema), `grid` (grid → cells, the checks on every cell), `groups`
(cells → groups → batches, the evaluation of a group), `run` (resume, signals, the CLI),
`cells` (the finished cell files), `report` (tables, report.md, output files), `figures` (the
PNGs).
CLI: `python -m mjxrow.sweep SWEEP.yaml` (parsed by `cli` before the heavy imports, then run by
`run`); `reference` (the key table of docs/sweep.md, `python -m mjxrow.sweep.docs`)."""
