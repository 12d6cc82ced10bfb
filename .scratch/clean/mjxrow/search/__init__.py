"""Failure search: find the fields where a controller fails, instead of a grid.

`config` (YAML → SearchConfig: the scenario as a sweep's, the box of traced keys, the method,
budget and objective), `box` (normalised coordinates, the candidates' run configs, validity,
the static field shape), `methods` (CMA-ES from evosax, random and Sobol streams), `evaluate`
(one compiled program for every generation), `objective` (failure, margin, distinct failures),
`run` (generations, resume, the CLI), `report` and `figures` (the outputs).
CLI: `python -m mjxrow.search SEARCH.yaml` (parsed by `cli` before the heavy imports).

From a notebook, on any registered controller:

    cfg = mjxrow.search.load("searches/segzeros_variety.yaml", ["budget.episodes=2000"])
    res = mjxrow.search.run_search(cfg, "runs/my_search")  # = mjxrow.run_search
    res["failures"]                                      # the distinct failures, ranked

The names below load on first use, so that the command parses its flags before JAX starts.
"""

import importlib as _importlib

_API = {"run_search": ("mjxrow.search.run", "run"), "load": ("mjxrow.search.config", "load"),
        "from_dict": ("mjxrow.search.config", "from_dict"),
        "SearchConfig": ("mjxrow.search.config", "SearchConfig")}

__all__ = sorted(_API)


def __getattr__(name: str):
    if name not in _API:
        raise AttributeError(f"module 'mjxrow.search' has no attribute {name!r}")
    module, attr = _API[name]
    value = getattr(_importlib.import_module(module), attr)
    globals()[name] = value
    return value
