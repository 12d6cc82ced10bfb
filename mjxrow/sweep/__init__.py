"""Sweeps: `config` (YAML schema), `run` (grid → groups → batches, resume, signals), `report`
(tables, heatmaps, report.md). CLI: `python -m mjxrow.sweep SWEEP.yaml`."""
