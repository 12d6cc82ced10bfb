"""Sweeps: `config` (YAML schema), `run` (grid → groups → batches, resume, signals), `report`
(tables, report.md, output files), `figures` (the PNGs).
CLI: `python -m mjxrow.sweep SWEEP.yaml`."""
